"""Every public op runs on PyTorch's meta device (shapes and dtypes, no values): what a GPU-ready op
needs, since it must not read values back to the host to decide what to compute. Data checks have
nothing to check there; what needs values (bezier_scatter's automatic point count) says so.

Inside `diffblur.without_host_reads` every op's tensor path reads no value back to the host at all
(no sync on a GPU): checked on CPU tensors whose every way to the host raises."""

from __future__ import annotations

import contextlib

import pytest

torch = pytest.importorskip("torch")

import diffblur  # noqa: E402
import torch_impl  # noqa: E402

B, H, W = 2, 16, 20


def _inputs(device: str, impl: str = "auto") -> dict:
    """The ops' inputs on `device`; impl for the ops with a fused CPU kernel."""
    generator = torch.Generator().manual_seed(0)
    make = lambda *shape: torch.rand(*shape, generator=generator).to(device)  # noqa: E731
    x = {
        "color": make(B, 3, H, W),
        "velocity": 3.0 * make(B, 2, H, W) - 1.5,  # still on its left third (below)
        "depth": make(B, 1, H, W) + 1.0,
        "ids": torch.zeros(B, 1, H, W, dtype=torch.int64).to(device),
        "palette": make(B, 3, 2),
        "impl": impl,
    }
    x["velocity"][..., : W // 3] = 0.0  # still pixels: bezier_scatter's fill="still" has some
    return x


CALLS = {
    "gather_blur": lambda x: torch_impl.gather_blur(x["color"], x["velocity"], samples=5, impl=x["impl"]),
    "gather_blur adaptive": lambda x: torch_impl.gather_blur(x["color"], x["velocity"], samples=5, adaptive=True, impl=x["impl"]),
    "gather_blur pyramid": lambda x: torch_impl.gather_blur(x["color"], x["velocity"], samples=5, sampling="pyramid"),
    "reconstruct": lambda x: torch_impl.reconstruct(x["color"], x["velocity"], x["depth"], samples=5, max_radius=4.0, impl=x["impl"]),
    "reconstruct adaptive": lambda x: torch_impl.reconstruct(x["color"], x["velocity"], x["depth"], samples=5, max_radius=4.0, adaptive=True, impl=x["impl"]),
    "bezier_scatter": lambda x: torch_impl.bezier_scatter(x["color"], x["depth"], -x["velocity"], x["velocity"], samples=4, impl=x["impl"]),
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
    "MotionBlur": lambda x: torch_impl.MotionBlur("reconstruct", samples=5, max_radius=4.0, impl=x["impl"]).to(x["color"].device)(x["color"], x["velocity"], x["depth"]),
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


#: Every way a tensor's values reach Python: on a GPU each one waits for the device.
HOST_READS = ("__bool__", "__float__", "__int__", "__index__", "item", "tolist", "numpy", "cpu", "__array__")


@contextlib.contextmanager
def reads_refused():
    """Within the block, reading a tensor's values on the host raises AssertionError."""

    def refuse(name):
        def read(self, *args, **kwargs):
            raise AssertionError(f"Tensor.{name} read values on the host")

        return read

    saved = {name: getattr(torch.Tensor, name) for name in HOST_READS}
    try:
        for name in HOST_READS:
            setattr(torch.Tensor, name, refuse(name))
        yield
    finally:
        for name, method in saved.items():
            setattr(torch.Tensor, name, method)


@pytest.mark.parametrize("name", list(CALLS))
def test_op_reads_no_values_inside_without_host_reads_and_gives_the_same_result(name):
    x = _inputs("cpu", impl="tensor")
    expected = CALLS[name](x)
    with reads_refused(), diffblur.without_host_reads():
        out = CALLS[name](x)
    torch.testing.assert_close(out, expected, rtol=1e-6, atol=1e-6)


def test_gradients_read_no_values_inside_without_host_reads():
    x = _inputs("cpu", impl="tensor")
    for key in ("color", "velocity", "depth"):
        x[key].requires_grad_()
    with reads_refused(), diffblur.without_host_reads():
        out = CALLS["reconstruct"](x) + CALLS["bezier_scatter"](x) + CALLS["gather_blur adaptive"](x)
        out.sum().backward()
    assert all(torch.isfinite(x[key].grad).all() for key in ("color", "velocity", "depth"))


def test_without_host_reads_skips_the_data_checks_and_ends_with_its_block():
    x = _inputs("cpu", impl="tensor")
    x["color"][0, 0, 3, 4] = float("nan")
    with diffblur.without_host_reads():
        assert torch.isnan(CALLS["reconstruct"](x)).any()
    with pytest.raises(ValueError, match="color must be finite everywhere"):
        CALLS["reconstruct"](x)


def test_automatic_point_count_inside_without_host_reads_says_it_needs_values():
    x = _inputs("cpu")
    with diffblur.without_host_reads(), pytest.raises(ValueError, match=r"inside diffblur.without_host_reads\(\) pass samples=<int>"):
        torch_impl.bezier_scatter(x["color"], x["depth"], -x["velocity"], x["velocity"])
