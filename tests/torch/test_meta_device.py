"""Every public op runs on PyTorch's meta device (shapes and dtypes, no values): what a GPU-ready op
needs, since it must not read values back to the host to decide what to compute. Data checks have
nothing to check there; what needs values (bezier_scatter's automatic point count) says so."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

import torch_impl  # noqa: E402

B, H, W = 2, 16, 20


def _inputs(device: str) -> dict:
    generator = torch.Generator().manual_seed(0)
    make = lambda *shape: torch.rand(*shape, generator=generator).to(device)  # noqa: E731
    return {
        "color": make(B, 3, H, W),
        "velocity": 3.0 * make(B, 2, H, W) - 1.5,
        "depth": make(B, 1, H, W) + 1.0,
        "ids": torch.zeros(B, 1, H, W, dtype=torch.int64).to(device),
        "palette": make(B, 3, 2),
    }


CALLS = {
    "gather_blur": lambda x: torch_impl.gather_blur(x["color"], x["velocity"], samples=5),
    "gather_blur adaptive": lambda x: torch_impl.gather_blur(x["color"], x["velocity"], samples=5, adaptive=True),
    "gather_blur pyramid": lambda x: torch_impl.gather_blur(x["color"], x["velocity"], samples=5, sampling="pyramid"),
    "reconstruct": lambda x: torch_impl.reconstruct(x["color"], x["velocity"], x["depth"], samples=5, max_radius=4.0),
    "reconstruct adaptive": lambda x: torch_impl.reconstruct(x["color"], x["velocity"], x["depth"], samples=5, max_radius=4.0, adaptive=True),
    "bezier_scatter": lambda x: torch_impl.bezier_scatter(x["color"], x["depth"], -x["velocity"], x["velocity"], samples=4),
    "warp_blend": lambda x: torch_impl.warp_blend(x["color"], x["velocity"]),
    "accumulate_warps": lambda x: torch_impl.accumulate_warps(x["color"], x["velocity"]),
    "velocity_from_motion": lambda x: torch_impl.velocity_from_motion(x["velocity"]),
    "velocity_from_motion_ids": lambda x: torch_impl.velocity_from_motion_ids(x["ids"], x["palette"]),
    "tile_max": lambda x: torch_impl.tile_max(x["velocity"], 4),
    "neighbor_max": lambda x: torch_impl.neighbor_max(torch_impl.tile_max(x["velocity"], 4)),
    "safe_length": lambda x: torch_impl.safe_length(x["velocity"]),
    "soft_depth_compare": lambda x: torch_impl.soft_depth_compare(x["depth"], x["depth"] * 1.1, 0.3),
    "cone": lambda x: torch_impl.cone(x["depth"], x["depth"]),
    "cylinder": lambda x: torch_impl.cylinder(x["depth"], x["depth"]),
    "interleaved_gradient_noise": lambda x: torch_impl.interleaved_gradient_noise(H, W, device=x["color"].device),
    "MotionBlur": lambda x: torch_impl.MotionBlur("reconstruct", samples=5, max_radius=4.0).to(x["color"].device)(x["color"], x["velocity"], x["depth"]),
}


def test_every_public_op_is_covered():
    covered = {name.split()[0] for name in CALLS}
    assert covered == set(torch_impl.__all__)


@pytest.mark.parametrize("name", list(CALLS))
def test_op_on_meta_tensors_has_the_shape_and_device_it_has_on_the_cpu(name):
    expected = CALLS[name](_inputs("cpu"))
    out = CALLS[name](_inputs("meta"))
    assert out.device.type == "meta"
    assert out.shape == expected.shape and out.dtype == expected.dtype


def test_automatic_point_count_on_meta_tensors_says_it_needs_values():
    x = _inputs("meta")
    with pytest.raises(ValueError, match=r"samples=None measures the curves .* on meta arrays pass samples=<int>"):
        torch_impl.bezier_scatter(x["color"], x["depth"], -x["velocity"], x["velocity"])
