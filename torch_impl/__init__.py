"""diffblur's PyTorch backend: batched, differentiable motion blur ops.

Mirrors `jax_impl` name by name; conventions in `diffblur.conventions`.
"""

from torch_impl._gather import gather_blur
from torch_impl._module import MotionBlur
from torch_impl._motion_ids import velocity_from_motion_ids
from torch_impl._scatter import bezier_scatter
from torch_impl._reconstruct import reconstruct
from torch_impl._warp import accumulate_warps, warp_blend
from torch_impl._primitives import (
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
gather_blur = _lists_options(gather_blur)
reconstruct = _lists_options(reconstruct)
bezier_scatter = _lists_options(bezier_scatter)
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
