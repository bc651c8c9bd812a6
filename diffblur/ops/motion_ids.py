"""Vector motion IDs (seed 001): a per-pixel integer ID into a small palette of motions.

Seed 001 stores, instead of a velocity per pixel, a small integer per pixel that indexes a palette
of motions (one per object). The image velocity of a pixel is read from its palette entry:

- a palette of 2D vectors, (B, K, 2): the entry *is* the image velocity, in pixels (half-spread,
  channel 0 = x), as in `diffblur.conventions`;
- a palette of 3D world velocities, (B, K, 3): the entry is the point's half-spread in camera
  space over the exposure, (Vx, Vy, Vz) in the units of `depth` (x right, y down, z away from the
  camera). The pixel's point at mid-exposure is P = ((x - cx) Z / f, (y - cy) Z / f, Z) for a pinhole
  camera with focal length f (pixels) and principal point (cx, cy); it sits at P - V at t = -1 and
  P + V at t = +1. The image velocity is the half-spread of its projections,
  (proj(P + V) - proj(P - V)) / 2, which is exactly

      u = Z (f Vx - (x - cx) Vz) / (Z^2 - Vz^2),   v = Z (f Vy - (y - cy) Vz) / (Z^2 - Vz^2),

  defined while the point stays in front of the camera (|Vz| < Z).

This module holds the op for both frameworks, its argument checks and its docstring; the NumPy
oracle is `diffblur.reference.velocity_from_motion_ids`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from diffblur import checks

__all__ = ["DOC", "check_motion_id_arguments", "id_range_message", "velocity_from_motion_ids", "world_velocity_message"]


def id_range_message(palette_size: int) -> str:
    """The message for IDs outside the palette (checked on the data)."""
    return f"ids must index the palette: every value in [0, {palette_size - 1}], got a value outside"


def world_velocity_message() -> str:
    """The message for a world velocity that takes the point behind the camera (checked on the data)."""
    return "palette's z velocity must satisfy |Vz| < depth at every pixel (the point stays in front of the camera), got |Vz| >= depth"


def check_motion_id_arguments(
    ids_shape: Sequence[int],
    ids_is_integer: bool,
    ids_dtype: object,
    palette_shape: Sequence[int],
    depth_shape: Sequence[int] | None,
    focal: object,
    principal_point: object,
) -> tuple[float | None, tuple[float, float] | None]:
    """Check the shapes and options of velocity_from_motion_ids; return (focal, principal point),
    the latter resolved to the image centre ((W - 1) / 2, (H - 1) / 2) when not given."""
    if not ids_is_integer:
        raise TypeError(f"ids must have an integer dtype (an index into the palette), got {ids_dtype}")
    batch, _, height, width = checks.require_image("ids", ids_shape, channels=1)
    palette_shape = tuple(int(s) for s in palette_shape)
    if len(palette_shape) != 3 or palette_shape[2] not in (2, 3) or palette_shape[1] == 0:
        raise ValueError(f"palette must be (B, K, 2) image velocities or (B, K, 3) world velocities with K >= 1, got shape {palette_shape}")
    if palette_shape[0] != batch:
        raise ValueError(f"palette must have the batch size of ids ({batch}), got shape {palette_shape}")
    if palette_shape[2] == 2:
        if depth_shape is not None or focal is not None or principal_point is not None:
            raise ValueError("depth, focal and principal_point apply to a (B, K, 3) palette of world velocities; got them with a (B, K, 2) palette")
        return None, None
    if depth_shape is None:
        raise ValueError("a (B, K, 3) palette of world velocities needs depth (B, 1, H, W); got depth=None")
    checks.require_same_shape("depth", tuple(depth_shape), "ids", (batch, 1, height, width))
    if focal is None:
        raise ValueError("a (B, K, 3) palette of world velocities needs focal (the focal length in pixels); got focal=None")
    focal = checks.require_positive_number("focal", focal)
    if principal_point is None:
        return focal, ((width - 1) / 2.0, (height - 1) / 2.0)
    if not isinstance(principal_point, (tuple, list)) or len(principal_point) != 2:
        raise TypeError(f"principal_point must be a pair (cx, cy) of numbers, got {principal_point!r}")
    cx = checks.require_finite_number("principal_point[0]", principal_point[0])
    cy = checks.require_finite_number("principal_point[1]", principal_point[1])
    return focal, (cx, cy)


DOC = """The (B, 2, H, W) image velocity of a per-pixel motion ID map, differentiable w.r.t. the palette.

    Args:
        ids: (B, 1, H, W) integer IDs, each in [0, K).
        palette: (B, K, 2) image velocities (pixels, half-spread, channel 0 = x), or (B, K, 3)
            world velocities (Vx, Vy, Vz), the half-spread in camera space in depth's units.
        depth: (B, 1, H, W) positive depth; needed for (and only for) a (B, K, 3) palette, with
            |Vz| < depth everywhere.
        focal: the pinhole's focal length in pixels (a (B, K, 3) palette only).
        principal_point: (cx, cy) in pixels; default the image centre ((W - 1) / 2, (H - 1) / 2).

    Returns:
        (B, 2, H, W) velocity in pixels; a world velocity V at depth Z is projected exactly as the
        half-spread (proj(P + V) - proj(P - V)) / 2 (see `diffblur.ops.motion_ids`).
    """


def velocity_from_motion_ids(
    be: Any, ids: Any, palette: Any, *, depth: Any = None, focal: float | None = None, principal_point: tuple[float, float] | None = None
) -> Any:
    """The op, for a backend: its arguments checked, then the palette read per pixel."""
    xp = be.xp
    ids = be.array("ids", ids)
    palette = checks.floating_array(be, "palette", palette)
    if depth is not None:
        depth = checks.floating_array(be, "depth", depth)
    focal, center = check_motion_id_arguments(
        ids.shape, be.is_integer(ids), ids.dtype, palette.shape, None if depth is None else depth.shape, focal, principal_point
    )
    batch, _, height, width = ids.shape
    palette_size, dims = palette.shape[1], palette.shape[2]
    be.require_same_device("ids", ids, "palette", palette)
    ids = be.check_values(ids, xp.all((ids >= 0) & (ids < palette_size)), id_range_message(palette_size))
    entry = be.take_along(palette, be.index(ids.reshape(batch, height * width, 1)), 1)  # (B, H W, D)
    entry = be.permute(entry, (0, 2, 1)).reshape(batch, dims, height, width)
    if dims == 2:
        return entry
    checks.same_dtype_and_device(be, "depth", depth, "palette", palette)
    depth = be.check_positive("depth", depth)
    vx, vy, vz = entry[:, 0:1], entry[:, 1:2], entry[:, 2:3]
    vz = be.check_values(vz, xp.all(xp.abs(vz) < depth), world_velocity_message())
    x = be.arange(width, palette.dtype, palette).reshape(1, 1, 1, width)
    y = be.arange(height, palette.dtype, palette).reshape(1, 1, height, 1)
    denominator = depth * depth - vz * vz
    u = depth * (focal * vx - (x - center[0]) * vz) / denominator
    v = depth * (focal * vy - (y - center[1]) * vz) / denominator
    return be.concat([u, v], 1)
