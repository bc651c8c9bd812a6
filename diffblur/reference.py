"""NumPy reference implementations: the oracle the backends are tested against.

Written for clarity, not speed: loops follow the equations of seed 000 one to one, and every
comparison is spelled out. They compute forward values only; the equivalence tests take
finite differences of these functions to check the backends' gradients.

Conventions (see `diffblur.conventions`): arrays are NCHW, velocity channel 0 is x, depth is
positive (larger = farther).
"""

from __future__ import annotations

import math

import numpy as np

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
    "clamp01",
    "cone",
    "cylinder",
    "interleaved_gradient_noise",
    "neighbor_max",
    "safe_length",
    "soft_depth_compare",
    "tile_max",
    "velocity_from_motion",
]


def clamp01(x: np.ndarray) -> np.ndarray:
    """clamp(x, 0, 1). The backends spell it with `where` so that the gradient at 0 and 1 is that of
    the inside (1), the same in PyTorch and JAX (JAX's own clip splits it in half at a tie)."""
    return np.where(x < 0, 0.0, np.where(x > 1, 1.0, x)).astype(np.result_type(x))


def soft_depth_compare(z_a: np.ndarray, z_b: np.ndarray, extent: float | np.ndarray) -> np.ndarray:
    """Seed 000 Figure 4, softDepthCompare, for positive depth: is z_b in front of z_a?

    1 where z_b <= z_a (z_b in front or tied), falling linearly to 0 at z_b = z_a + extent.
    Seed 000 writes clamp(1 - (z_a - z_b) / extent) for negative camera-space z; with depth = -z
    the numerator becomes z_b - z_a.
    """
    return clamp01(1.0 - (z_b - z_a) / extent)


def _floor_speed(speed: np.ndarray) -> np.ndarray:
    return np.where(speed < EPSILON, EPSILON, speed)


def cone(distance: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """Seed 000 Figure 4, cone: clamp(1 - distance / speed, 0, 1). Speeds below EPSILON count as
    EPSILON, so a still point covers only its own pixel."""
    return clamp01(1.0 - distance / _floor_speed(speed))


def cylinder(distance: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """Seed 000 Figure 4, cylinder: 1 - smoothstep(0.95 speed, 1.05 speed, distance)."""
    speed = _floor_speed(speed)
    low = CYLINDER_INNER * speed
    width = (CYLINDER_OUTER - CYLINDER_INNER) * speed
    t = clamp01((distance - low) / width)
    return 1.0 - t * t * (3.0 - 2.0 * t)


def safe_length(vector: np.ndarray, *, axis: int = 1) -> np.ndarray:
    """Euclidean length along `axis`, keeping that axis (size 1). The backends give it the gradient
    0 at the zero vector (a subgradient) instead of NaN."""
    return np.sqrt(np.sum(vector * vector, axis=axis, keepdims=True))


def velocity_from_motion(
    displacement: np.ndarray,
    *,
    exposure: float | np.ndarray = 1.0,
    max_radius: float = DEFAULT_MAX_RADIUS,
    min_radius: float = DEFAULT_MIN_RADIUS,
) -> np.ndarray:
    """Seed 000 sec. 2.2: the half-spread velocity buffer from the per-frame displacement X - X'.

    q = displacement * exposure / 2, where exposure = exposure time * frame rate (1 = the shutter is
    open the whole frame); V = q / |q| * clamp(|q|, min_radius, max_radius). Seed 000 divides by
    |q| + eps; this divides by max(|q|, EPSILON), which is the same guard but leaves lengths inside
    [min_radius, max_radius] exact. A scalar exposure applies to the whole batch; an array of shape
    (B,) gives one per image.
    """
    exposure = np.asarray(exposure, dtype=displacement.dtype)
    if exposure.ndim == 1:
        exposure = exposure.reshape(-1, 1, 1, 1)
    q = 0.5 * displacement * exposure
    out = np.zeros_like(q)
    batch, _, height, width = q.shape
    for b in range(batch):
        for i in range(height):
            for j in range(width):
                qx, qy = q[b, 0, i, j], q[b, 1, i, j]
                length = math.hypot(qx, qy)
                radius = min(max(length, min_radius), max_radius)
                scale = radius / max(length, EPSILON)
                out[b, 0, i, j] = qx * scale
                out[b, 1, i, j] = qy * scale
    return out


def _vmax(vectors: list[np.ndarray]) -> np.ndarray:
    """Seed 000's vmax: the vector of largest magnitude; ties go to the first in the list."""
    best = vectors[0]
    best_sq = float(np.dot(best, best))
    for v in vectors[1:]:
        sq = float(np.dot(v, v))
        if sq > best_sq:
            best, best_sq = v, sq
    return best


def tile_max(velocity: np.ndarray, tile: int) -> np.ndarray:
    """Seed 000 eq. 1: per tile of tile x tile pixels, the largest-magnitude velocity.

    Output (B, 2, ceil(H / tile), ceil(W / tile)); the last row and column of tiles are partial when
    H or W is not a multiple of `tile`. Ties go to the first pixel in row-major order.
    """
    checks.require_positive_int("tile", tile)
    batch, channels, height, width = checks.require_image("velocity", velocity.shape, channels=VECTOR_CHANNELS)
    tiles_y, tiles_x = -(-height // tile), -(-width // tile)
    out = np.zeros((batch, channels, tiles_y, tiles_x), dtype=velocity.dtype)
    for b in range(batch):
        for ty in range(tiles_y):
            for tx in range(tiles_x):
                members = [
                    velocity[b, :, i, j]
                    for i in range(ty * tile, min((ty + 1) * tile, height))
                    for j in range(tx * tile, min((tx + 1) * tile, width))
                ]
                out[b, :, ty, tx] = _vmax(members)
    return out


def neighbor_max(tile_velocity: np.ndarray) -> np.ndarray:
    """Seed 000 eq. 2: per tile, the largest-magnitude vector of its 3 x 3 tile neighbourhood.

    Tiles beyond the border do not take part. Ties go to the first in row-major order of the
    neighbourhood (top-left first).
    """
    batch, channels, tiles_y, tiles_x = tile_velocity.shape
    out = np.zeros_like(tile_velocity)
    for b in range(batch):
        for ty in range(tiles_y):
            for tx in range(tiles_x):
                members = [
                    tile_velocity[b, :, ty + dy, tx + dx]
                    for dy in (-1, 0, 1)
                    for dx in (-1, 0, 1)
                    if 0 <= ty + dy < tiles_y and 0 <= tx + dx < tiles_x
                ]
                out[b, :, ty, tx] = _vmax(members)
    return out


def interleaved_gradient_noise(height: int, width: int) -> np.ndarray:
    """Jimenez's interleaved gradient noise at integer pixel coordinates, float64, in [0, 1).

    noise[i, j] = fract(IGN_C * fract(IGN_A * j + IGN_B * i)) with j the column (x) and i the row (y).
    Seed 000 Listing 1 jitters the whole filter by j = noise - 0.5.
    """
    checks.require_positive_int("height", height)
    checks.require_positive_int("width", width)
    y = np.arange(height, dtype=np.float64)[:, None]
    x = np.arange(width, dtype=np.float64)[None, :]
    inner = IGN_A * x + IGN_B * y
    inner = inner - np.floor(inner)
    outer = IGN_C * inner
    return outer - np.floor(outer)
