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

This module is the NumPy reference (the oracle of `torch_impl.velocity_from_motion_ids` and
`jax_impl.velocity_from_motion_ids`) and holds the argument checks both backends call.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from diffblur import checks

__all__ = ["check_motion_id_arguments", "velocity_from_motion_ids", "world_velocity_message", "id_range_message"]


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


def velocity_from_motion_ids(
    ids: np.ndarray,
    palette: np.ndarray,
    *,
    depth: np.ndarray | None = None,
    focal: float | None = None,
    principal_point: tuple[float, float] | None = None,
) -> np.ndarray:
    """The (B, 2, H, W) image velocity of an ID map and its palette (module docstring).

    ids: (B, 1, H, W) integers in [0, K). palette: (B, K, 2) image velocities in pixels, or (B, K, 3)
    world velocities with depth (B, 1, H, W) > |Vz| and focal (pixels); principal_point (cx, cy)
    defaults to the image centre.

    >>> ids = np.array([[[[0, 1], [1, 0]]]])
    >>> palette = np.array([[[0.0, 0.0], [3.0, -1.0]]])
    >>> velocity_from_motion_ids(ids, palette)[0, 0]
    array([[0., 3.],
           [3., 0.]])
    """
    ids = np.asarray(ids)
    palette = np.asarray(palette)
    focal, center = check_motion_id_arguments(
        ids.shape, np.issubdtype(ids.dtype, np.integer), ids.dtype, palette.shape, None if depth is None else np.shape(depth), focal, principal_point
    )
    palette_size = palette.shape[1]
    if ids.min() < 0 or ids.max() >= palette_size:
        raise ValueError(id_range_message(palette_size))
    batch, _, height, width = ids.shape
    dims = palette.shape[2]
    entry = np.empty((batch, dims, height, width), dtype=palette.dtype)
    for b in range(batch):
        for i in range(height):
            for j in range(width):
                entry[b, :, i, j] = palette[b, ids[b, 0, i, j]]
    if dims == 2:
        return entry
    z = np.asarray(depth, dtype=palette.dtype)[:, 0]
    vx, vy, vz = entry[:, 0], entry[:, 1], entry[:, 2]
    if not np.all(np.abs(vz) < z):
        raise ValueError(world_velocity_message())
    x = np.arange(width, dtype=palette.dtype)[None, None, :]
    y = np.arange(height, dtype=palette.dtype)[None, :, None]
    denominator = z * z - vz * vz
    u = z * (focal * vx - (x - center[0]) * vz) / denominator
    v = z * (focal * vy - (y - center[1]) * vz) / denominator
    return np.stack([u, v], axis=1).astype(palette.dtype)
