"""Vector motion IDs (seed 001) in JAX: an ID map and a palette of motions to a velocity field.

The formulas are in `diffblur.motion_ids`, the NumPy reference."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from diffblur import motion_ids
from jax_impl import _checks


def velocity_from_motion_ids(
    ids: Int[Array, "b 1 h w"],
    palette: Float[Array, "b k d"],
    *,
    depth: Float[Array, "b 1 h w"] | None = None,
    focal: float | None = None,
    principal_point: tuple[float, float] | None = None,
) -> Float[Array, "b 2 h w"]:
    """The (B, 2, H, W) image velocity of a per-pixel motion ID map, differentiable w.r.t. the palette.

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
        half-spread (proj(P + V) - proj(P - V)) / 2 (see `diffblur.motion_ids`).

    >>> import jax.numpy as jnp
    >>> ids = jnp.array([[[[0, 1], [1, 0]]]])
    >>> palette = jnp.array([[[0.0, 0.0], [3.0, -1.0]]])
    >>> velocity_from_motion_ids(ids, palette)[0, 0].tolist()
    [[0.0, 3.0], [3.0, 0.0]]
    """
    ids = _checks.array("ids", ids)
    palette = _checks.floating_array("palette", palette)
    if depth is not None:
        depth = _checks.floating_array("depth", depth)
    focal, center = motion_ids.check_motion_id_arguments(
        ids.shape,
        bool(jnp.issubdtype(ids.dtype, jnp.integer)),
        ids.dtype,
        palette.shape,
        None if depth is None else depth.shape,
        focal,
        principal_point,
    )
    batch, _, height, width = ids.shape
    palette_size, dims = palette.shape[1], palette.shape[2]
    ids = _checks.data_check(ids, jnp.logical_not(jnp.all((ids >= 0) & (ids < palette_size))), motion_ids.id_range_message(palette_size))
    entry = jax.vmap(lambda p, i: p[i])(palette, ids.reshape(batch, height * width))  # (B, H W, D)
    entry = jnp.transpose(entry, (0, 2, 1)).reshape(batch, dims, height, width)
    if dims == 2:
        return entry
    _checks.same_dtype("depth", depth, "palette", palette)
    depth = _checks.positive_values("depth", depth)
    vx, vy, vz = entry[:, 0:1], entry[:, 1:2], entry[:, 2:3]
    vz = _checks.data_check(vz, jnp.logical_not(jnp.all(jnp.abs(vz) < depth)), motion_ids.world_velocity_message())
    x = jnp.arange(width, dtype=palette.dtype).reshape(1, 1, 1, width)
    y = jnp.arange(height, dtype=palette.dtype).reshape(1, 1, height, 1)
    denominator = depth * depth - vz * vz
    u = depth * (focal * vx - (x - center[0]) * vz) / denominator
    v = depth * (focal * vy - (y - center[1]) * vz) / denominator
    return jnp.concatenate([u, v], axis=1)
