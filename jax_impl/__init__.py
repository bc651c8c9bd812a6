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
from jax_impl._primitives import cone, cylinder, interleaved_gradient_noise, neighbor_max, safe_length, soft_depth_compare, tile_max, velocity_from_motion
from jax_impl._reconstruct import reconstruct
from jax_impl._scatter import bezier_scatter
from jax_impl._warp import accumulate_warps, warp_blend

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
