"""One policy for NaN and infinity in the colour, the same in both frameworks: every image op
refuses them like a non-finite velocity (ValueError naming the argument; under `jax.jit` at run
time). Before issue 25 they passed through, and PyTorch and JAX spread them to different numbers
of pixels (reconstruct: 25 against 31 of 156 in one case).

The test inputs are otherwise valid (every other test runs the ops on finite colours); the bad
value sits in one pixel of one channel.
"""

from __future__ import annotations

import numpy as np
import pytest

SHAPE = (1, 3, 6, 7)


def inputs(b, bad: float, name: str = "color"):
    rng = np.random.default_rng(0)
    color = rng.random(SHAPE)
    background = rng.random(SHAPE)
    {"color": color, "background": background}[name][0, 1, 2, 3] = bad
    velocity = rng.normal(size=(1, 2, 6, 7))
    depth = rng.uniform(1.0, 2.0, size=(1, 1, 6, 7))
    return {key: b.array(value) for key, value in dict(color=color, velocity=velocity, depth=depth, background=background).items()}


CALLS = {
    "gather_blur": lambda o, a: o.gather_blur(a["color"], a["velocity"], samples=3),
    "reconstruct": lambda o, a: o.reconstruct(a["color"], a["velocity"], a["depth"], samples=3, max_radius=2.0),
    "bezier_scatter": lambda o, a: o.bezier_scatter(a["color"], a["depth"], -a["velocity"], a["velocity"], samples=3, fill="color"),
    "bezier_scatter background": lambda o, a: o.bezier_scatter(a["color"], a["depth"], -a["velocity"], a["velocity"], samples=3, fill=a["background"]),
    "warp_blend": lambda o, a: o.warp_blend(a["color"], a["velocity"], iterations=1),
    "accumulate_warps": lambda o, a: o.accumulate_warps(a["color"], a["velocity"], instants=2),
    "MotionBlur": lambda o, a: o.MotionBlur("gather", samples=3)(a["color"], a["velocity"]),
}


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf], ids=["nan", "inf", "-inf"])
@pytest.mark.parametrize("op", list(CALLS))
def test_nonfinite_color_is_refused_naming_the_argument(backend, op, bad):
    name = "background" if op.endswith("background") else "color"
    shown = "fill" if name == "background" else name  # the scene behind is bezier_scatter's fill
    with pytest.raises(ValueError, match=rf"^{shown} must be finite everywhere, got NaN or infinity$"):
        CALLS[op](backend.ops, inputs(backend, bad, name))


@pytest.mark.parametrize("op", ["gather_blur", "bezier_scatter background", "warp_blend"])
def test_nonfinite_color_is_refused_under_jax_jit(op):
    import jax

    import jax_impl
    from tests.backends import JaxBackend

    name = "background" if op.endswith("background") else "color"
    arrays = inputs(JaxBackend, np.nan, name)
    shown = "fill" if name == "background" else name
    with pytest.raises(Exception, match=rf"{shown} must be finite everywhere, got NaN or infinity"):
        jax.block_until_ready(jax.jit(lambda a: CALLS[op](jax_impl, a))(arrays))


def test_torch_check_screens_by_a_sum_without_refusing_huge_finite_values():
    """The PyTorch check sums first; finite values whose sum overflows still pass, bad ones fail."""
    import torch

    from torch_impl._backend import TORCH

    for dtype in (torch.float32, torch.float64):  # (half sums in float32, which they cannot overflow)
        huge = torch.full((1, 3, 40, 40), torch.finfo(dtype).max / 2, dtype=dtype)
        assert not torch.isfinite(huge.sum(dtype=torch.promote_types(dtype, torch.float32)))  # the screen overflows
        TORCH.check_finite("color", huge)
        for bad in (np.nan, np.inf):
            spoiled = huge.clone()
            spoiled[0, 2, 39, 39] = bad
            with pytest.raises(ValueError, match="color must be finite everywhere"):
                TORCH.check_finite("color", spoiled)
