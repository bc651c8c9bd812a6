"""NumPy reference implementations: the oracle the backends are tested against.

Written for clarity, not speed: loops follow the equations of seed 000 one to one, and every
comparison is spelled out. They compute forward values only; the equivalence tests take
finite differences of these functions to check the backends' gradients.

Conventions (see `diffblur.conventions`): arrays are NCHW, velocity channel 0 is x, depth is
positive (larger = farther).

This module holds the primitives, `gather_blur` and `reconstruct`; `_scatter` holds
`bezier_scatter`, `_warp` `warp_blend` and `accumulate_warps`, `_motion_ids`
`velocity_from_motion_ids`, all exported here.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from diffblur import checks
from diffblur.ops.pyramid import level_of_detail, numpy_levels, numpy_sample_levels
from diffblur.ops.adaptive import ADAPTIVE_TILE, STILL_SPEED, select_by_tile, still_speed, tile_sample_counts
from diffblur.conventions import (
    CYLINDER_INNER,
    CYLINDER_OUTER,
    DEFAULT_MAX_RADIUS,
    DEFAULT_MIN_RADIUS,
    DEFAULT_RELATIVE_Z_EXTENT,
    DEFAULT_SAMPLES,
    DEFAULT_SHUTTER,
    EARLY_OUT_SPEED,
    EPSILON,
    IGN_A,
    IGN_B,
    IGN_C,
    JITTER_MODES,
    SAMPLING_MODES,
    VECTOR_CHANNELS,
)
from diffblur.shutters import ShutterWindow, get_shutter
from diffblur.ops.taps import gather_tap_times, reconstruct_tap_time, shutter_factor, stratum_weights

__all__ = [
    "clamp01",
    "cone",
    "cylinder",
    "gather_blur",
    "interleaved_gradient_noise",
    "neighbor_max",
    "reconstruct",
    "safe_length",
    "sample_bilinear",
    "sample_nearest",
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


@lru_cache(maxsize=4)
def noise_jitter(height: int, width: int) -> np.ndarray:
    """The "noise" jitter j = interleaved_gradient_noise - 0.5, (height, width) float64, read-only.
    Kept per size for the next call (~8 ms to compute at 720p): all three backends cast this one
    array, so they jitter by the same bits."""
    noise = interleaved_gradient_noise(height, width) - 0.5
    noise.setflags(write=False)
    return noise


def sample_bilinear(image: np.ndarray, x: float, y: float) -> np.ndarray:
    """image (C, H, W) at the point (x, y), bilinear, positions clamped to the border pixel centres."""
    _, height, width = image.shape
    x = min(max(x, 0.0), width - 1.0)
    y = min(max(y, 0.0), height - 1.0)
    x0, y0 = math.floor(x), math.floor(y)
    x1, y1 = min(x0 + 1, width - 1), min(y0 + 1, height - 1)
    fx, fy = x - x0, y - y0
    top = image[:, y0, x0] + fx * (image[:, y0, x1] - image[:, y0, x0])
    bottom = image[:, y1, x0] + fx * (image[:, y1, x1] - image[:, y1, x0])
    return top + fy * (bottom - top)


def sample_nearest(image: np.ndarray, x: float, y: float) -> np.ndarray:
    """image (C, H, W) at the pixel nearest (x, y) (halves round up, as seed 000's [p + 0.5]),
    clamped to the border."""
    _, height, width = image.shape
    column = min(max(math.floor(x + 0.5), 0), width - 1)
    row = min(max(math.floor(y + 0.5), 0), height - 1)
    return image[:, row, column]


def gather_blur(
    color: np.ndarray,
    velocity: np.ndarray,
    *,
    samples: int = DEFAULT_SAMPLES,
    shutter: str | ShutterWindow = DEFAULT_SHUTTER,
    sampling: str = "bilinear",
    adaptive: bool | tuple[int, ...] = False,
) -> np.ndarray:
    """The per-pixel gather of seed 001 (Rosado): each pixel averages the sharp image along its own
    velocity over the exposure, weighted by the shutter.

    The exposure is cut into `samples` equal strata with midpoints tau_k; what pixel X shows at
    time tau is taken to be what sat at X - tau V[X] in the sharp frame, so

        out[X] = sum_k m_k C[X - tau_k V[X]] / sum_k m_k,  m_k = shutter mass of stratum k.
    """
    from diffblur.ops.gather import GatherOptions

    o = GatherOptions(samples=samples, shutter=shutter, sampling=sampling, adaptive=adaptive)
    window, classes, pyramid = o.window, o.classes, o.sampling == "pyramid"
    if classes is not None:  # each tile: its class's filter, or the image where still
        speeds = np.hypot(*np.moveaxis(tile_max(velocity, ADAPTIVE_TILE), 1, 0))
        counts = tile_sample_counts(speeds, classes, STILL_SPEED, np)
        by_count = {c: gather_blur(color, velocity, samples=c, shutter=shutter, sampling=sampling) for c in classes}
        return select_by_tile(color, by_count, counts, ADAPTIVE_TILE)
    times = np.array(gather_tap_times(samples))
    masses = stratum_weights(window, times, 1.0 / samples, np)
    masses = masses / masses.sum()
    sample = sample_nearest if sampling == "nearest" else sample_bilinear
    batch, _, height, width = color.shape
    levels = [numpy_levels(color[b]) for b in range(batch)] if pyramid else None
    out = np.zeros_like(color)
    for b in range(batch):
        for i in range(height):
            for j in range(width):
                vx, vy = velocity[b, 0, i, j], velocity[b, 1, i, j]
                if pyramid:  # taps 2 |V| / S apart read the level averaged over that spacing
                    lod = float(level_of_detail(np.array(2.0 * math.hypot(vx, vy) / samples), len(levels[b]), np))
                for tau, mass in zip(times, masses):
                    if pyramid:
                        out[b, :, i, j] += mass * numpy_sample_levels(levels[b], j - tau * vx, i - tau * vy, lod)
                    else:
                        out[b, :, i, j] += mass * sample(color[b], j - tau * vx, i - tau * vy)
    return out


def reconstruct(
    color: np.ndarray,
    velocity: np.ndarray,
    depth: np.ndarray,
    *,
    max_radius: float = DEFAULT_MAX_RADIUS,
    samples: int = DEFAULT_SAMPLES,
    soft_z_extent: float | None = None,
    relative_z_extent: float = DEFAULT_RELATIVE_Z_EXTENT,
    jitter: str | np.ndarray = "noise",
    sampling: str = "bilinear",
    shutter: str | ShutterWindow = DEFAULT_SHUTTER,
    early_out: bool | None = None,
    directions: str = "neighbor",
    min_radius: float = DEFAULT_MIN_RADIUS,
    adaptive: bool | tuple[int, ...] = False,
) -> np.ndarray:
    """Seed 000 Listing 1, the reconstruction filter, pixel by pixel.

    TileMax and NeighborMax with tile = ceil(max_radius); per pixel X the dominant neighbourhood
    velocity v_N; the early-out where |v_N| <= EARLY_OUT_SPEED (0.501 px) (on by default for "nearest" only,
    so the differentiable default hides no parameter); the centre weight 1 / |V[X]|; S - 1 taps
    Y = X + v_N t at t = mix(-1, 1, (i + j + 1) / (S + 1)) with the whole filter jittered by j;
    the three cases from soft_depth_compare, cone and cylinder; each tap also weighted by the
    shutter at exposure time -t (1 for the box); normalised accumulation.

    With sampling="nearest" taps are rounded to the nearest pixel and distances are between pixel
    centres, as in the paper; with "bilinear" C, V and Z are read between pixels and the distance
    is |t| |v_N|. directions="neighbor_and_own" takes the odd taps along V[X] instead (sec. 4.3).
    jitter: "noise" (interleaved gradient noise - 0.5), "none", or an array (B, 1, H, W) in [-0.5, 0.5].
    Speeds |V| below min_radius count as min_radius (the paper's buffer is clamped to >= 0.5 px).
    """
    from diffblur.ops.reconstruct import ReconstructOptions

    o = ReconstructOptions(
        max_radius=max_radius,
        samples=samples,
        soft_z_extent=soft_z_extent,
        relative_z_extent=relative_z_extent,
        jitter=jitter,
        sampling=sampling,
        shutter=shutter,
        early_out=early_out,
        directions=directions,
        min_radius=min_radius,
        adaptive=adaptive,
    )
    if o.classes is not None:  # each tile: its class's filter, or the image where still
        options = dict(max_radius=max_radius, soft_z_extent=soft_z_extent, relative_z_extent=relative_z_extent, jitter=jitter, sampling=sampling, shutter=shutter)
        options.update(early_out=o.early_out, directions=directions, min_radius=min_radius)
        speeds = np.hypot(*np.moveaxis(neighbor_max(tile_max(velocity, o.tile)), 1, 0))
        counts = tile_sample_counts(speeds, o.classes, still_speed(o.early_out), np)
        by_count = {c: reconstruct(color, velocity, depth, samples=c, **options) for c in o.classes}
        return select_by_tile(color, by_count, counts, o.tile)
    samples, tile, window, early_out, sampling = o.samples, o.tile, o.window, o.early_out, o.sampling
    if o.log_depth:  # the band relative to depth: compare log depths (`diffblur.checks.depth_band`)
        depth = np.log(depth)
    batch, _, height, width = color.shape
    if isinstance(jitter, str):
        noise = noise_jitter(height, width) if jitter == "noise" else np.zeros((height, width))
        jitter = np.broadcast_to(noise, (batch, 1, height, width))
    neighbors = neighbor_max(tile_max(velocity, tile))
    sample = sample_nearest if sampling == "nearest" else sample_bilinear
    # Read C, V and Z at a tap in one go.
    buffers = np.concatenate([color, velocity, depth], axis=1)
    channels = color.shape[1]
    center_factor = float(shutter_factor(window, np.array(0.0), samples, np))
    levels = [numpy_levels(color[b]) for b in range(batch)] if sampling == "pyramid" else None
    out = np.zeros_like(color)
    for b in range(batch):
        for i in range(height):
            for j in range(width):
                v_n = neighbors[b, :, i // tile, j // tile]
                if early_out and math.hypot(*v_n) <= EARLY_OUT_SPEED:
                    out[b, :, i, j] = color[b, :, i, j]
                    continue
                v_x = velocity[b, :, i, j]
                speed_x = max(math.hypot(*v_x), min_radius)
                z_x = depth[b, 0, i, j]
                weight = center_factor / speed_x
                total = weight * color[b, :, i, j]
                for k in range(samples):
                    if k == (samples - 1) // 2:
                        continue
                    t = reconstruct_tap_time(k, jitter[b, 0, i, j], samples)
                    direction = v_x if directions == "neighbor_and_own" and k % 2 == 1 else v_n
                    x, y = j + direction[0] * t, i + direction[1] * t
                    if sampling == "nearest":
                        distance = math.hypot(math.floor(x + 0.5) - j, math.floor(y + 0.5) - i)
                    else:
                        distance = abs(t) * math.hypot(*direction)
                    read = sample(buffers[b], x, y)
                    c_y, v_y, z_y = read[:channels], read[channels : channels + 2], read[channels + 2]
                    if levels is not None:  # the colour from the level that matches the tap spacing
                        lod = float(level_of_detail(np.array(2.0 * math.hypot(*direction) / (samples + 1)), len(levels[b]), np))
                        c_y = numpy_sample_levels(levels[b], x, y, lod)
                    speed_y = max(math.hypot(*v_y), min_radius)
                    front = soft_depth_compare(z_x, z_y, o.band)  # Y in front of X
                    back = soft_depth_compare(z_y, z_x, o.band)  # Y behind X
                    speeds_y, speeds_x, distances = np.array(speed_y), np.array(speed_x), np.array(distance)
                    alpha = (
                        front * cone(distances, speeds_y)  # case 1: blurry Y in front of any X
                        + back * cone(distances, speeds_x)  # case 2: any Y behind blurry X
                        + cylinder(distances, speeds_y) * cylinder(distances, speeds_x) * 2.0  # case 3
                    )
                    alpha = alpha * float(shutter_factor(window, np.array(-t), samples, np))
                    weight += alpha
                    total += alpha * c_y
                out[b, :, i, j] = total / weight
    return out


from diffblur.reference._scatter import bezier_control_points, bezier_scatter  # noqa: E402

__all__ += ["bezier_control_points", "bezier_scatter"]

from diffblur.reference._warp import accumulate_warps, warp_blend  # noqa: E402

__all__ += ["accumulate_warps", "warp_blend"]

from diffblur.reference._motion_ids import velocity_from_motion_ids  # noqa: E402

__all__ += ["velocity_from_motion_ids"]
