"""The NumPy reference of `velocity_from_motion_ids` (seed 001's vector motion IDs): the palette read
pixel by pixel; the formulas and checks are in `diffblur.ops.motion_ids`."""

from __future__ import annotations

import numpy as np

from diffblur.ops.motion_ids import check_motion_id_arguments, id_range_message, world_velocity_message

__all__ = ["velocity_from_motion_ids"]


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
