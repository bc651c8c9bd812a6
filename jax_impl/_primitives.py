"""The building blocks of seed 000 as batched, differentiable JAX ops.

Each mirrors a function of `diffblur.reference` (the oracle) and of `torch_impl._primitives`.
Clamps are written with `jnp.where` because `jnp.clip` splits the gradient in half at a tie; this
way the gradient at a clamp boundary is that of the inside, as in the PyTorch backend.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from diffblur import checks, reference
from diffblur.conventions import (
    CYLINDER_INNER,
    CYLINDER_OUTER,
    DEFAULT_MAX_RADIUS,
    DEFAULT_MIN_RADIUS,
    EPSILON,
    VECTOR_CHANNELS,
)
from jax_impl import _checks

__all__ = [
    "cone",
    "cylinder",
    "interleaved_gradient_noise",
    "neighbor_max",
    "safe_length",
    "soft_depth_compare",
    "tile_max",
    "velocity_from_motion",
]


def _clamp01(x: Array) -> Array:
    return jnp.where(x < 0, 0.0, jnp.where(x > 1, 1.0, x)).astype(x.dtype)


def _floor_speed(speed: Array) -> Array:
    return jnp.where(speed < EPSILON, EPSILON, speed).astype(speed.dtype)


def _floor_extent(extent: float | Array) -> float | Array:
    """Array extents below sqrt(smallest normal) of their dtype count as that value: below it the
    gradient (z_b - z_a) / extent**2 would overflow to inf and turn into NaN at the clamps.
    The output is a step there either way."""
    if isinstance(extent, float):
        return extent
    floor = float(jnp.finfo(extent.dtype).tiny) ** 0.5  # a Python float: no promotion of bfloat16
    return jnp.where(extent < floor, floor, extent).astype(extent.dtype)


def _soft_depth_compare(z_a: Array, z_b: Array, extent: float | Array) -> Array:
    # clamp(1 - (z_b - z_a) / extent, 0, 1), with the division only inside the soft band (double
    # where): outside it a tiny extent would give an infinite derivative times a zero cotangent.
    extent = _floor_extent(extent)
    behind = z_b - z_a
    in_band = (behind >= 0) & (behind <= extent)
    ramp = 1.0 - jnp.where(in_band, behind, 0.0) / extent
    return jnp.where(behind < 0, 1.0, jnp.where(behind > extent, 0.0, ramp)).astype(z_a.dtype)


def _widen(x: Array) -> Array:
    """float32 for the half types. The classifiers' ratio distance / speed reaches 1e7 (1e4 px over
    the 1e-3 px floor), past float16's 65504: the clamp hides it forward, but the backward's
    0 * inf would be NaN."""
    return x.astype(jnp.float32) if x.dtype in (jnp.float16, jnp.bfloat16) else x


def _cone(distance: Array, speed: Array) -> Array:
    dtype = distance.dtype
    distance, speed = _widen(distance), _widen(speed)
    return _clamp01(1.0 - distance / _floor_speed(speed)).astype(dtype)


def _cylinder(distance: Array, speed: Array) -> Array:
    dtype = distance.dtype
    distance, speed = _widen(distance), _floor_speed(_widen(speed))
    t = _clamp01((distance - CYLINDER_INNER * speed) / ((CYLINDER_OUTER - CYLINDER_INNER) * speed))
    return (1.0 - t * t * (3.0 - 2.0 * t)).astype(dtype)


def _squared_length(vector: Array, axis: int) -> Array:
    """Sum of squares along `axis` (kept), in float32 for the half types: in float16 a vector
    longer than 256 px would square to infinity."""
    if vector.dtype in (jnp.float16, jnp.bfloat16):
        vector = vector.astype(jnp.float32)
    # Component by component: XLA:CPU's reduce over a leading axis of size 2 took 10 ms at 1280x720,
    # these adds 0.2 ms (same sums, same order).
    components = [jax.lax.slice_in_dim(vector, i, i + 1, axis=axis) for i in range(vector.shape[axis])]
    squared = components[0] * components[0]
    for component in components[1:]:
        squared = squared + component * component
    return squared


def _safe_length(vector: Array, axis: int = 1) -> Array:
    squared = _squared_length(vector, axis)
    # Double where: sqrt never sees 0, so its infinite derivative never meets the zero cotangent.
    positive = squared > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, squared, 1.0)), 0.0).astype(vector.dtype)


def soft_depth_compare(z_a: Float[Array, "*shape"], z_b: Float[Array, "*shape"], extent: float | Array) -> Float[Array, "*shape"]:
    """Seed 000's softDepthCompare for positive depth: ~1 where z_b is in front of z_a.

    Args:
        z_a, z_b: depths of the same shape (any), positive, larger = farther.
        extent: the soft band, in depth units, > 0: a number, a 0-d array or an array of z's shape.
            An array extent below sqrt(finfo(dtype).tiny) (1.1e-19 in float32) counts as that value.

    Returns:
        clamp(1 - (z_b - z_a) / extent, 0, 1): 1 where z_b <= z_a, 0 where z_b >= z_a + extent.

    >>> import jax.numpy as jnp
    >>> soft_depth_compare(jnp.array([2.0, 2.0, 2.0]), jnp.array([1.0, 2.5, 4.0]), 1.0).tolist()
    [1.0, 0.5, 0.0]
    """
    z_a, z_b = _checks.floating_array("z_a", z_a), _checks.floating_array("z_b", z_b)
    _checks.same_shape("z_b", z_b, "z_a", z_a)
    extent = _checks.positive_scalar("extent", extent, z_a)
    return _soft_depth_compare(z_a, z_b, extent)


def cone(distance: Float[Array, "*shape"], speed: Float[Array, "*shape"]) -> Float[Array, "*shape"]:
    """Seed 000's cone: is a point `distance` px away inside the blur of a point moving at `speed` px?

    Args:
        distance: distances in pixels, >= 0, any shape.
        speed: lengths of the half-spread velocity in pixels, the shape of `distance`; speeds below
            `diffblur.conventions.EPSILON` count as EPSILON.

    Returns:
        clamp(1 - distance / speed, 0, 1).

    >>> import jax.numpy as jnp
    >>> cone(jnp.array([0.0, 1.0, 3.0]), jnp.array([2.0, 2.0, 2.0])).tolist()
    [1.0, 0.5, 0.0]
    """
    distance, speed = _checks.floating_array("distance", distance), _checks.floating_array("speed", speed)
    _checks.same_shape("speed", speed, "distance", distance)
    return _cone(distance, speed)


def cylinder(distance: Float[Array, "*shape"], speed: Float[Array, "*shape"]) -> Float[Array, "*shape"]:
    """Seed 000's cylinder: 1 - smoothstep(0.95 speed, 1.05 speed, distance).

    Args:
        distance: distances in pixels, any shape.
        speed: speeds in pixels, the shape of `distance`; below EPSILON they count as EPSILON.

    >>> import jax.numpy as jnp
    >>> cylinder(jnp.array([0.0, 2.0, 3.0]), jnp.array([2.0, 2.0, 2.0])).tolist()
    [1.0, 0.5, 0.0]
    """
    distance, speed = _checks.floating_array("distance", distance), _checks.floating_array("speed", speed)
    _checks.same_shape("speed", speed, "distance", distance)
    return _cylinder(distance, speed)


def safe_length(vector: Float[Array, "b c h w"], *, axis: int = 1) -> Float[Array, "b 1 h w"]:
    """Euclidean length along `axis` (kept, size 1) whose gradient at the zero vector is 0, not NaN.

    >>> import jax, jax.numpy as jnp
    >>> jax.grad(lambda v: safe_length(v).sum())(jnp.zeros((1, 2, 1, 1))).ravel().tolist()
    [0.0, 0.0]
    """
    vector = _checks.floating_array("vector", vector)
    if not -vector.ndim <= axis < vector.ndim:
        raise ValueError(f"axis must be in [{-vector.ndim}, {vector.ndim}) for a {vector.ndim}-d vector, got {axis}")
    return _safe_length(vector, axis)


def velocity_from_motion(
    displacement: Float[Array, "b 2 h w"],
    *,
    exposure: float | Array = 1.0,
    max_radius: float = DEFAULT_MAX_RADIUS,
    min_radius: float = DEFAULT_MIN_RADIUS,
) -> Float[Array, "b 2 h w"]:
    """Seed 000 sec. 2.2: the half-spread velocity from the per-frame displacement X - X'.

    Args:
        displacement: (B, 2, H, W) pixels moved over one frame, channel 0 = x, 1 = y.
        exposure: exposure time x frame rate (1 = shutter open all frame): a number, a 0-d array or
            a (B,) array; differentiable.
        max_radius: the clamp k in pixels, > 0 (math.inf for none).
        min_radius: the smallest blur radius in pixels, >= 0 and <= max_radius (seed 000: 0.5).

    Returns:
        (B, 2, H, W) q / |q| * clamp(|q|, min_radius, max_radius) with q = displacement * exposure / 2.
        Exact for |q| in [min_radius, max_radius]; at q = 0 it is 0 with a finite gradient.

    >>> import jax.numpy as jnp
    >>> d = jnp.array([[3.0, 0.2, 60.0], [4.0, 0.0, 80.0]]).reshape(1, 2, 1, 3)
    >>> velocity_from_motion(d, exposure=1.0, max_radius=20.0)[0, :, 0].T.tolist()
    [[1.5, 2.0], [0.5, 0.0], [12.0, 16.0]]
    """
    displacement = _checks.finite_values("displacement", _checks.image("displacement", displacement, channels=VECTOR_CHANNELS))
    max_radius = checks.require_positive_number("max_radius", max_radius)
    min_radius = checks.require_nonnegative_number("min_radius", min_radius)
    if min_radius > max_radius:
        raise ValueError(f"min_radius must be <= max_radius ({max_radius}), got {min_radius}")
    exposure = _checks.per_batch_scalar("exposure", exposure, displacement)
    q = 0.5 * displacement * exposure
    length = _safe_length(q)
    radius = jnp.where(length < min_radius, min_radius, jnp.where(length > max_radius, max_radius, length))
    return q * (radius.astype(q.dtype) / _floor_speed(length))


def _vmax_gather(candidates: Array, squared: Array, axis: int) -> Array:
    """Pick, along `axis` of `candidates` (B, 2, ..., N, ...), the vector whose `squared` length
    (B, ..., N, ...) is largest; argmax returns the first maximum, which is the tie rule."""
    index = jnp.expand_dims(jnp.argmax(squared, axis=axis - 1, keepdims=True), 1)
    return jnp.squeeze(jnp.take_along_axis(candidates, index, axis=axis), axis)


def tile_max(velocity: Float[Array, "b 2 h w"], tile: int) -> Float[Array, "b 2 th tw"]:
    """Seed 000 eq. 1: the largest-magnitude velocity of each tile x tile block.

    Args:
        velocity: (B, 2, H, W) in pixels; H and W need not be multiples of `tile`.
        tile: tile size in pixels (seed 000 uses the max radius k), an integer >= 1.

    Returns:
        (B, 2, ceil(H / tile), ceil(W / tile)). Ties go to the first pixel in row-major order; the
        gradient flows to the chosen pixel.
    """
    velocity = _checks.image("velocity", velocity, channels=VECTOR_CHANNELS)
    tile = checks.require_positive_int("tile", tile)
    batch, _, height, width = velocity.shape
    tiles_y, tiles_x = -(-height // tile), -(-width // tile)
    pad_y, pad_x = tiles_y * tile - height, tiles_x * tile - width
    squared = _squared_length(velocity, 1)[:, 0]
    # Padding gets squared length -1 so it never wins, not even against a zero vector.
    squared = jnp.pad(squared, ((0, 0), (0, pad_y), (0, pad_x)), constant_values=-1.0)
    padded = jnp.pad(velocity, ((0, 0), (0, 0), (0, pad_y), (0, pad_x)))
    squared = squared.reshape(batch, tiles_y, tile, tiles_x, tile).transpose(0, 1, 3, 2, 4)
    padded = padded.reshape(batch, 2, tiles_y, tile, tiles_x, tile).transpose(0, 1, 2, 4, 3, 5)
    squared = squared.reshape(batch, tiles_y, tiles_x, tile * tile)
    padded = padded.reshape(batch, 2, tiles_y, tiles_x, tile * tile)
    return _vmax_gather(padded, squared, axis=4)


def neighbor_max(tile_velocity: Float[Array, "b 2 th tw"]) -> Float[Array, "b 2 th tw"]:
    """Seed 000 eq. 2: the largest-magnitude vector of each tile's 3 x 3 tile neighbourhood.

    Args:
        tile_velocity: (B, 2, TH, TW), usually `tile_max`'s output.

    Returns:
        (B, 2, TH, TW). Tiles beyond the border take no part; ties go to the first in row-major
        order of the neighbourhood (top-left first).
    """
    tile_velocity = _checks.image("tile_velocity", tile_velocity, channels=VECTOR_CHANNELS)
    _, _, tiles_y, tiles_x = tile_velocity.shape
    squared = jnp.pad(_squared_length(tile_velocity, 1)[:, 0], ((0, 0), (1, 1), (1, 1)), constant_values=-1.0)
    padded = jnp.pad(tile_velocity, ((0, 0), (0, 0), (1, 1), (1, 1)))
    offsets = [(dy, dx) for dy in range(3) for dx in range(3)]
    candidates = jnp.stack([padded[:, :, dy : dy + tiles_y, dx : dx + tiles_x] for dy, dx in offsets], axis=2)
    candidate_squared = jnp.stack([squared[:, dy : dy + tiles_y, dx : dx + tiles_x] for dy, dx in offsets], axis=1)
    return _vmax_gather(candidates, candidate_squared, axis=2)


def interleaved_gradient_noise(
    height: int, width: int, *, dtype: jnp.dtype | None = None, device: jax.Device | None = None
) -> Float[Array, "h w"]:
    """Interleaved gradient noise at integer pixel coordinates, in [0, 1), shape (height, width).

    It is `diffblur.reference.interleaved_gradient_noise`, computed in float64 with NumPy at trace
    time (JAX may run without x64), so it is bit-identical to the PyTorch backend's, then cast to
    `dtype` (default: JAX's default float) on `device`.
    """
    noise = reference.interleaved_gradient_noise(height, width).astype(dtype or jnp.zeros(()).dtype)
    return jax.device_put(noise, device)
