"""diffblur's JAX backend: batched, differentiable motion blur ops.

Mirrors `torch_impl` name by name; conventions in `diffblur.conventions`.
"""

from jax.scipy.special import erf as _erf

from diffblur import shutters as _shutters

# The Gaussian window's erf for JAX arrays is JAX's own (one differentiable op, not a 160-term
# series): registered here, as the core (`diffblur.shutters`) imports no framework.
_shutters.register_erf("jax.numpy", _erf)

from jax_impl._gather import gather_blur
from jax_impl._module import MotionBlur
from jax_impl._motion_ids import velocity_from_motion_ids
from jax_impl._scatter import bezier_scatter
from jax_impl._reconstruct import reconstruct
from jax_impl._warp import accumulate_warps, warp_blend
from jax_impl._primitives import (
    cone,
    cylinder,
    interleaved_gradient_noise,
    neighbor_max,
    safe_length,
    soft_depth_compare,
    tile_max,
    velocity_from_motion,
)

from diffblur.checks import lists_options as _lists_options

# An unknown keyword names the op's valid options (the layer's options are checked by MotionBlur).


def _forward_mode_hint(op: str):
    """JAX's error for forward mode (jvp, jacfwd, linearize) through the fused kernels' custom_vjp,
    with what to do about it: the tensor ops (fused=False) have both modes."""

    def explain(error: TypeError, kwargs: dict):
        if "forward-mode" not in str(error) or kwargs.get("fused") is False:
            return None
        return TypeError(
            f"{op} ran on its fused CPU kernel, which has a reverse-mode gradient only (a custom_vjp): for jax.jvp, "
            f"jax.jacfwd or jax.linearize pass {op}(..., fused=False) (or MotionBlur(..., fused=False)). JAX: {error}"
        )

    return explain


gather_blur = _lists_options(gather_blur, explain=_forward_mode_hint("gather_blur"))
reconstruct = _lists_options(reconstruct, explain=_forward_mode_hint("reconstruct"))
bezier_scatter = _lists_options(bezier_scatter, explain=_forward_mode_hint("bezier_scatter"))
warp_blend = _lists_options(warp_blend)
accumulate_warps = _lists_options(accumulate_warps)
velocity_from_motion = _lists_options(velocity_from_motion)
velocity_from_motion_ids = _lists_options(velocity_from_motion_ids)
safe_length = _lists_options(safe_length)
interleaved_gradient_noise = _lists_options(interleaved_gradient_noise)

__all__ = [
    "MotionBlur",
    "accumulate_warps",
    "bezier_scatter",
    "cone",
    "cylinder",
    "gather_blur",
    "interleaved_gradient_noise",
    "neighbor_max",
    "reconstruct",
    "safe_length",
    "soft_depth_compare",
    "tile_max",
    "velocity_from_motion",
    "velocity_from_motion_ids",
    "warp_blend",
]
