"""diffblur's PyTorch backend: batched, differentiable motion blur ops.

Mirrors `jax_impl` name by name; conventions in `diffblur.conventions`.
"""

from torch_impl._gather import gather_blur
from torch_impl._module import MotionBlur
from torch_impl._motion_ids import velocity_from_motion_ids
from torch_impl._primitives import cone, cylinder, interleaved_gradient_noise, neighbor_max, safe_length, soft_depth_compare, tile_max, velocity_from_motion
from torch_impl._reconstruct import reconstruct
from torch_impl._scatter import bezier_scatter
from torch_impl._warp import accumulate_warps, warp_blend

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
