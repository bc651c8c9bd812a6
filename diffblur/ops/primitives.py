"""The building blocks of seed 000: soft depth compare, cone, cylinder, a safe length, TileMax and
NeighborMax, the velocity buffer, interleaved gradient noise. Each mirrors a function of
`diffblur.reference` (the oracle).

The math functions (`soft_depth_compare`, `cone`, ...) take a `Backend` and arrays already checked;
the other ops call them. The `*_op` functions are the public ops, with their argument checks.
Clamps are written with `where`, so the gradient at a clamp's boundary is the inside's in both
frameworks (jnp.clip would halve it at a tie).
"""

from __future__ import annotations

from typing import Any

from diffblur import checks
from diffblur.conventions import (
    CYLINDER_INNER,
    CYLINDER_OUTER,
    DEFAULT_MAX_RADIUS,
    DEFAULT_MIN_RADIUS,
    EPSILON,
    IGN_A,
    IGN_B,
    IGN_C,
    VECTOR_CHANNELS,
)

__all__ = [
    "at_least",
    "clamp01",
    "cone",
    "cylinder",
    "floor_speed",
    "interleaved_gradient_noise",
    "neighbor_max",
    "safe_length",
    "soft_depth_compare",
    "squared_length",
    "tile_max",
    "velocity_from_motion",
]


def clamp01(be: Any, x: Any) -> Any:
    xp = be.xp
    return be.astype(xp.where(x < 0, 0.0, xp.where(x > 1, 1.0, x)), x.dtype)


def at_least(be: Any, x: Any, floor: float) -> Any:
    """x, with values below `floor` replaced by it (gradient 0 there)."""
    return be.astype(be.xp.where(x < floor, floor, x), x.dtype)


def floor_speed(be: Any, speed: Any) -> Any:
    return at_least(be, speed, EPSILON)


def floor_extent(be: Any, extent: float | Any) -> float | Any:
    """Array extents below sqrt(smallest normal) of their dtype count as that value: below it the
    gradient (z_b - z_a) / extent**2 would overflow to inf and turn into NaN at the clamps. The
    output is a step there either way."""
    if isinstance(extent, float):
        return extent
    floor = float(be.xp.finfo(extent.dtype).tiny) ** 0.5  # a Python float: no promotion of bfloat16
    return at_least(be, extent, floor)


def soft_depth_compare(be: Any, z_a: Any, z_b: Any, extent: float | Any) -> Any:
    """clamp(1 - (z_b - z_a) / extent, 0, 1), with the division only inside the soft band (double
    where): outside it a tiny extent would give an infinite derivative times a zero cotangent."""
    xp = be.xp
    extent = floor_extent(be, extent)
    behind = z_b - z_a
    in_band = (behind >= 0) & (behind <= extent)
    ramp = 1.0 - xp.where(in_band, behind, 0.0) / extent
    return be.astype(xp.where(behind < 0, 1.0, xp.where(behind > extent, 0.0, ramp)), z_a.dtype)


def _widen(be: Any, x: Any) -> Any:
    """float32 for the half types. The classifiers' ratio distance / speed reaches 1e7 (1e4 px over
    the 1e-3 px floor), past float16's 65504: the clamp hides it forward, but the backward's
    0 * inf would be NaN."""
    return be.astype(x, be.xp.float32) if x.dtype in be.half else x


def cone(be: Any, distance: Any, speed: Any) -> Any:
    dtype = distance.dtype
    distance, speed = _widen(be, distance), _widen(be, speed)
    return be.astype(clamp01(be, 1.0 - distance / floor_speed(be, speed)), dtype)


def cylinder(be: Any, distance: Any, speed: Any) -> Any:
    dtype = distance.dtype
    distance, speed = _widen(be, distance), floor_speed(be, _widen(be, speed))
    t = clamp01(be, (distance - CYLINDER_INNER * speed) / ((CYLINDER_OUTER - CYLINDER_INNER) * speed))
    return be.astype(1.0 - t * t * (3.0 - 2.0 * t), dtype)


def squared_length(be: Any, vector: Any, axis: int) -> Any:
    """Sum of squares along `axis` (kept), in float32 for the half types: in float16 a vector longer
    than 256 px would square to infinity. Component by component: XLA:CPU's reduce over a leading
    axis of size 2 was 50x slower than these adds (same sums, same order)."""
    if vector.dtype in be.half:
        vector = be.astype(vector, be.xp.float32)
    axis = axis % vector.ndim
    index = (slice(None),) * axis
    squared = None
    for i in range(vector.shape[axis]):
        component = vector[(*index, slice(i, i + 1))]
        squared = component * component if squared is None else squared + component * component
    return squared


def safe_length(be: Any, vector: Any, axis: int = 1) -> Any:
    """The Euclidean length along `axis` (kept) whose gradient at the zero vector is 0, not NaN."""
    xp = be.xp
    squared = squared_length(be, vector, axis)
    # Double where: sqrt never sees 0, so its infinite derivative never meets the zero cotangent.
    positive = squared > 0
    return be.astype(xp.where(positive, xp.sqrt(xp.where(positive, squared, 1.0)), 0.0), vector.dtype)


def _gathered(be: Any, vectors: Any, y: Any, x: Any) -> Any:
    """vectors (B, 2, H, W) at integer rows y and columns x (B, TY, TX): (B, 2, TY, TX). Indexed on
    the image's own shape, so that under XLA the gradient's scatter adds into another cotangent of
    the vectors (a kernel's) in place, instead of into a full-size zero (through a reshape it did not)."""
    batch = be.arange(vectors.shape[0], y.dtype, vectors).reshape(-1, 1, 1)
    return be.permute(vectors[batch, :, y, x], (0, 3, 1, 2))


def _tile_max_index(be: Any, squared: Any, tile: int) -> tuple[Any, Any]:
    """(B, TY, TX) rows and columns of each tile's largest of squared (B, H, W) lengths."""
    batch, height, width = squared.shape
    tiles_y, tiles_x = -(-height // tile), -(-width // tile)
    pad_y, pad_x = tiles_y * tile - height, tiles_x * tile - width
    # Padding gets squared length -1 so it never wins, not even against a zero vector.
    squared = be.pad(squared, ((0, 0), (0, pad_y), (0, pad_x)), value=-1.0).reshape(batch, tiles_y, tile, tiles_x, tile)
    # In two steps, with no transposed copy of the image: each tile row's first largest, then the
    # first row that holds the tile's largest. That is the first largest in row-major order, the
    # tie rule of an argmax over the tile's pixels.
    column = be.argmax(squared, 4)  # (B, TY, tile, TX, 1)
    row = be.argmax(be.take_along(squared, column, 4), 2)  # (B, TY, 1, TX, 1)
    column = be.take_along(column, row, 2)[:, :, 0, :, 0]
    y = be.arange(tiles_y, row.dtype, squared).reshape(1, -1, 1) * tile + row[:, :, 0, :, 0]
    x = be.arange(tiles_x, column.dtype, squared).reshape(1, 1, -1) * tile + column
    return y, x


def _neighbor_max_index(be: Any, squared: Any) -> tuple[Any, Any]:
    """(B, TY, TX) rows and columns of each tile's 3 x 3 neighbourhood's largest of squared
    (B, TY, TX) lengths, the first in row-major order of the neighbourhood on ties."""
    xp = be.xp
    _, tiles_y, tiles_x = squared.shape
    padded = be.pad(squared, ((0, 0), (1, 1), (1, 1)), value=-1.0)
    offsets = [(dy, dx) for dy in range(3) for dx in range(3)]
    which = be.argmax(xp.stack([padded[:, dy : dy + tiles_y, dx : dx + tiles_x] for dy, dx in offsets], 1), 1)[:, 0]
    y = be.arange(tiles_y, which.dtype, squared).reshape(1, -1, 1) + which // 3 - 1
    x = be.arange(tiles_x, which.dtype, squared).reshape(1, 1, -1) + which % 3 - 1
    return y, x


def tile_max(be: Any, velocity: Any, tile: int) -> Any:
    """Seed 000 eq. 1 on a checked (B, 2, H, W) velocity: (B, 2, ceil(H / tile), ceil(W / tile))."""
    return _gathered(be, velocity, *_tile_max_index(be, be.stop_gradient(squared_length(be, velocity, 1)[:, 0]), tile))


def neighbor_max(be: Any, tile_velocity: Any) -> Any:
    """Seed 000 eq. 2 on checked (B, 2, TH, TW) tile velocities: each tile's 3 x 3 neighbourhood's
    largest vector."""
    return _gathered(be, tile_velocity, *_neighbor_max_index(be, be.stop_gradient(squared_length(be, tile_velocity, 1)[:, 0])))


def neighbor_max_of_velocity(be: Any, velocity: Any, tile: int) -> Any:
    """neighbor_max(tile_max(velocity, tile)), the same values and gradient, as one gather from the
    velocity: each tile's NeighborMax is the velocity of one pixel."""
    squared = be.stop_gradient(squared_length(be, velocity, 1)[:, 0])
    y, x = _tile_max_index(be, squared, tile)
    batch = be.arange(squared.shape[0], y.dtype, squared).reshape(-1, 1, 1)
    tile_y, tile_x = _neighbor_max_index(be, squared[batch, y, x])
    return _gathered(be, velocity, y[batch, tile_y, tile_x], x[batch, tile_y, tile_x])


def velocity_from_motion(be: Any, displacement: Any, exposure: float | Any, max_radius: float, min_radius: float) -> Any:
    """Seed 000 sec. 2.2 on checked arguments (see `velocity_from_motion_op`)."""
    xp = be.xp
    q = 0.5 * displacement * exposure
    length = safe_length(be, q)
    radius = xp.where(length < min_radius, min_radius, xp.where(length > max_radius, max_radius, length))
    return q * (be.astype(radius, q.dtype) / floor_speed(be, length))


def interleaved_gradient_noise(be: Any, height: int, width: int, dtype: Any, like: Any = None) -> Any:
    """Interleaved gradient noise at integer pixel coordinates, (height, width) in [0, 1), computed in
    float64 on like's device (bit-identical to the NumPy oracle's), then cast to `dtype`: for a
    framework that has float64 there (JAX without x64 does not, and takes the oracle's array)."""
    xp = be.xp
    y = be.arange(height, xp.float64, like).reshape(-1, 1)
    x = be.arange(width, xp.float64, like).reshape(1, -1)
    inner = IGN_A * x + IGN_B * y
    inner = inner - xp.floor(inner)
    outer = IGN_C * inner
    return be.astype(outer - xp.floor(outer), dtype)


# -- the public ops, with their argument checks -------------------------------------------------------


def _same_shape_pair(be: Any, name_a: str, a: Any, name_b: str, b: Any) -> tuple[Any, Any]:
    a, b = checks.floating_array(be, name_a, a), checks.floating_array(be, name_b, b)
    checks.same_shape(be, name_b, b, name_a, a)
    return a, b


SOFT_DEPTH_COMPARE_DOC = """Seed 000's softDepthCompare for positive depth: ~1 where z_b is in front of z_a.

    Args:
        z_a, z_b: depths of the same shape (any), positive, larger = farther.
        extent: the soft band, in depth units, > 0: a number, a 0-d array or an array of z's shape
            (differentiable). An array extent below sqrt(finfo(dtype).tiny) (1.1e-19 in float32)
            counts as that value.

    Returns:
        clamp(1 - (z_b - z_a) / extent, 0, 1): 1 where z_b <= z_a, 0 where z_b >= z_a + extent.
    """


def soft_depth_compare_op(be: Any, z_a: Any, z_b: Any, extent: Any) -> Any:
    z_a, z_b = _same_shape_pair(be, "z_a", z_a, "z_b", z_b)
    return soft_depth_compare(be, z_a, z_b, checks.positive_scalar(be, "extent", extent, z_a))


CONE_DOC = """Seed 000's cone: is a point `distance` px away inside the blur of a point moving at `speed` px?

    Args:
        distance: distances in pixels, >= 0, any shape.
        speed: lengths of the half-spread velocity in pixels, the shape of `distance`; speeds below
            `diffblur.conventions.EPSILON` count as EPSILON.

    Returns:
        clamp(1 - distance / speed, 0, 1).
    """


def cone_op(be: Any, distance: Any, speed: Any) -> Any:
    return cone(be, *_same_shape_pair(be, "distance", distance, "speed", speed))


CYLINDER_DOC = """Seed 000's cylinder: 1 - smoothstep(0.95 speed, 1.05 speed, distance).

    Args:
        distance: distances in pixels, any shape.
        speed: speeds in pixels, the shape of `distance`; below EPSILON they count as EPSILON.
    """


def cylinder_op(be: Any, distance: Any, speed: Any) -> Any:
    return cylinder(be, *_same_shape_pair(be, "distance", distance, "speed", speed))


SAFE_LENGTH_DOC = """Euclidean length along `axis` (kept, size 1) whose gradient at the zero vector is 0, not NaN."""


def safe_length_op(be: Any, vector: Any, axis: int) -> Any:
    vector = checks.floating_array(be, "vector", vector)
    if not -vector.ndim <= axis < vector.ndim:
        raise ValueError(f"axis must be in [{-vector.ndim}, {vector.ndim}) for a {vector.ndim}-d vector, got {axis}")
    return safe_length(be, vector, axis)


VELOCITY_FROM_MOTION_DOC = """Seed 000 sec. 2.2: the half-spread velocity from the per-frame displacement X - X'.

    Args:
        displacement: (B, 2, H, W) pixels moved over one frame, channel 0 = x, 1 = y.
        exposure: exposure time x frame rate (1 = shutter open all frame): a number, a 0-d array or
            a (B,) array; differentiable.
        max_radius: the clamp k in pixels, > 0 (math.inf for none).
        min_radius: the smallest blur radius in pixels, >= 0 and <= max_radius (seed 000: 0.5).

    Returns:
        (B, 2, H, W) q / |q| * clamp(|q|, min_radius, max_radius) with q = displacement * exposure / 2.
        Exact for |q| in [min_radius, max_radius]; at q = 0 it is 0 with a finite gradient.
    """


def velocity_from_motion_op(
    be: Any, displacement: Any, *, exposure: float | Any = 1.0, max_radius: float = DEFAULT_MAX_RADIUS, min_radius: float = DEFAULT_MIN_RADIUS
) -> Any:
    displacement = be.check_finite("displacement", checks.image_array(be, "displacement", displacement, channels=VECTOR_CHANNELS))
    max_radius = checks.require_positive_number("max_radius", max_radius)
    min_radius = checks.require_nonnegative_number("min_radius", min_radius)
    if min_radius > max_radius:
        raise ValueError(f"min_radius must be <= max_radius ({max_radius}), got {min_radius}")
    exposure = checks.per_batch_scalar(be, "exposure", exposure, displacement)
    return velocity_from_motion(be, displacement, exposure, max_radius, min_radius)


TILE_MAX_DOC = """Seed 000 eq. 1: the largest-magnitude velocity of each tile x tile block.

    Args:
        velocity: (B, 2, H, W) in pixels; H and W need not be multiples of `tile`.
        tile: tile size in pixels (seed 000 uses the max radius k), an integer >= 1.

    Returns:
        (B, 2, ceil(H / tile), ceil(W / tile)). Ties go to the first pixel in row-major order; the
        gradient flows to the chosen pixel.
    """


def tile_max_op(be: Any, velocity: Any, tile: int) -> Any:
    velocity = checks.image_array(be, "velocity", velocity, channels=VECTOR_CHANNELS)
    return tile_max(be, velocity, checks.require_positive_int("tile", tile))


NEIGHBOR_MAX_DOC = """Seed 000 eq. 2: the largest-magnitude vector of each tile's 3 x 3 tile neighbourhood.

    Args:
        tile_velocity: (B, 2, TH, TW), usually `tile_max`'s output.

    Returns:
        (B, 2, TH, TW). Tiles beyond the border take no part; ties go to the first in row-major
        order of the neighbourhood (top-left first).
    """


def neighbor_max_op(be: Any, tile_velocity: Any) -> Any:
    return neighbor_max(be, checks.image_array(be, "tile_velocity", tile_velocity, channels=VECTOR_CHANNELS))


INTERLEAVED_GRADIENT_NOISE_DOC = """Interleaved gradient noise at integer pixel coordinates, in [0, 1), shape (height, width).

    Computed in float64 (bit-identical to `diffblur.reference.interleaved_gradient_noise` and to the
    other backend), then cast to `dtype` (default: the framework's default float dtype) on `device`.
    """


def interleaved_gradient_noise_op(be: Any, height: int, width: int, *, dtype: Any = None, device: Any = None) -> Any:
    from diffblur import reference

    noise = reference.interleaved_gradient_noise(checks.require_positive_int("height", height), checks.require_positive_int("width", width))
    return be.on_device(be.asarray(noise, be.default_float if dtype is None else dtype), device)
