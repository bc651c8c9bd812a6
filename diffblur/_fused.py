"""Fused CPU kernels (numba) behind the PyTorch and JAX ops' custom gradient rules.

A tensor framework runs `reconstruct` as ~200 full-resolution elementwise ops per tap; on a 2-core
CPU that cannot reach the 100 ms target at 1280x720 (BENCHMARKS.md), and JAX's backward is
dominated by the scatter-add that transposes the bilinear reads. These kernels do the whole filter
in one parallel loop over pixels, and its hand-written backward in a second one. They take and
return NumPy arrays, so both backends share them: `torch_impl._fused` wraps them in an
`autograd.Function`, `jax_impl._fused` in a `custom_vjp` over `pure_callback`.

The pure tensor ops stay the reference: tests compare outputs and gradients of both paths. The
kernels repeat the pure ops' arithmetic (the same clamps, floors and `where` branches, so the same
one-sided derivatives at kinks) in float64 scalars, reading and writing the arrays' dtype.

Scope, checked by `reconstruct_unfused_reason`: bilinear sampling, the box shutter, float32 or
float64, no pyramid. The tap count is per tile (`counts`), which is how adaptive sampling and the
early-out run here: a tile with count 0 returns the image and costs one copy.

The backward scatters each tap's gradient to the 4 pixels it read, which may be anywhere in the
image: each thread accumulates into its own full-size buffer, summed at the end, so the backward's
memory is O(pixels x threads) (2 threads here), never O(pixels x taps).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from diffblur.conventions import CYLINDER_INNER, CYLINDER_OUTER, EPSILON

try:  # numba is a dependency; the guard keeps the pure ops usable where it cannot load.
    import numba
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None

__all__ = [
    "available",
    "gather_backward",
    "gather_forward",
    "gather_mass_table",
    "gather_unfused_reason",
    "reconstruct_backward",
    "reconstruct_forward",
    "reconstruct_unfused_reason",
    "tile_counts",
]

_INVERSE_CYLINDER_SPAN = 1.0 / (CYLINDER_OUTER - CYLINDER_INNER)
#: Row interleave of the parallel loops: each thread's static share of the rows is spread over the
#: whole image, so a scene whose motion sits in one band still keeps both cores busy.
_ROW_INTERLEAVE = 16


def available() -> bool:
    """Whether the fused kernels can run (numba imports)."""
    return numba is not None


def reconstruct_unfused_reason(o: Any, dtype_name: str) -> str | None:
    """Why `reconstruct` with options `o` (`diffblur.taps.ReconstructOptions`) cannot take the
    fused path, or None when it can. dtype_name: the image's dtype, as a string."""
    from diffblur.shutters import Box

    if numba is None:
        return "numba is not installed"
    if o.sampling != "bilinear":
        return f"sampling={o.sampling!r} (the fused kernel is bilinear)"
    if type(o.window) is not Box:
        return f"shutter {o.window.name!r} (the fused kernel takes the box shutter)"
    if o.pyramid:
        return "pyramid=True"
    if dtype_name not in ("float32", "float64"):
        return f"dtype {dtype_name} (the fused kernel takes float32 and float64)"
    return None


def tile_counts(speed: Any, o: Any, xp: Any) -> Any:
    """The kernel's taps per tile from the tiles' |NeighborMax| (any shape, numpy/torch/jax.numpy):
    the adaptive classes, else the full rate, 0 where the early-out returns the image."""
    from diffblur._adaptive import still_speed, tile_sample_counts

    if o.classes is not None:
        return tile_sample_counts(speed, o.classes, still_speed(o.early_out), xp)
    # Without the early-out no tile is skipped: the full-rate filter runs on still tiles too.
    return tile_sample_counts(speed, (o.samples,), still_speed(True) if o.early_out else -1.0, xp)


def row_order(rows: int) -> np.ndarray:
    """Rows 0, 16, 32, ..., 1, 17, ...: the order the parallel loops visit the B * H rows in."""
    return np.argsort(np.arange(rows) % _ROW_INTERLEAVE, kind="stable").astype(np.int64)


def _jit(function):
    if numba is None:  # pragma: no cover
        return function
    return numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy", fastmath=True)(function)


def _inline(function):
    if numba is None:  # pragma: no cover
        return function
    return numba.njit(inline="always", cache=True, error_model="numpy", fastmath=True)(function)


@_inline
def _length(a, b):
    squared = a * a + b * b
    return math.sqrt(squared) if squared > 0.0 else 0.0


@_inline
def _soft_depth_compare(z_a, z_b, extent, inverse_extent):
    behind = z_b - z_a
    if behind < 0.0:
        return 1.0
    if behind > extent:
        return 0.0
    return 1.0 - behind * inverse_extent


@_inline
def _floored_inverse(speed):
    """1 / max(speed, EPSILON): the classifiers divide by the floored speed; one division per speed."""
    return 1.0 / (speed if speed >= EPSILON else EPSILON)


@_inline
def _cone(distance, inverse):
    u = 1.0 - distance * inverse
    return 0.0 if u < 0.0 else (1.0 if u > 1.0 else u)


@_inline
def _cone_grad(distance, speed, inverse, grad):
    """d cone / d distance and d cone / d speed, times grad (the pure op's one-sided rules)."""
    u = 1.0 - distance * inverse
    if u < 0.0 or u > 1.0:
        return 0.0, 0.0
    d_speed = grad * distance * inverse * inverse if speed >= EPSILON else 0.0
    return -grad * inverse, d_speed


@_inline
def _cylinder(distance, inverse):
    q = (distance * inverse - CYLINDER_INNER) * _INVERSE_CYLINDER_SPAN
    q = 0.0 if q < 0.0 else (1.0 if q > 1.0 else q)
    return 1.0 - q * q * (3.0 - 2.0 * q)


@_inline
def _cylinder_grad(distance, speed, inverse, grad):
    q = (distance * inverse - CYLINDER_INNER) * _INVERSE_CYLINDER_SPAN
    if q < 0.0 or q > 1.0:
        return 0.0, 0.0
    d_q = grad * (-6.0 * q * (1.0 - q)) * _INVERSE_CYLINDER_SPAN
    d_speed = -d_q * distance * inverse * inverse if speed >= EPSILON else 0.0
    return d_q * inverse, d_speed


@_inline
def _bilinear_setup(px, py, width, height):
    """Corners, fractions and whether the clamp passes the gradient, as `_sampling.sample`."""
    inside_x = px >= 0.0 and px <= width - 1.0
    inside_y = py >= 0.0 and py <= height - 1.0
    cx = 0.0 if px < 0.0 else (width - 1.0 if px > width - 1.0 else px)
    cy = 0.0 if py < 0.0 else (height - 1.0 if py > height - 1.0 else py)
    x0 = math.floor(cx)
    y0 = math.floor(cy)
    column0 = min(int(x0), width - 1)
    row0 = min(int(y0), height - 1)
    return column0, min(column0 + 1, width - 1), row0, min(row0 + 1, height - 1), cx - x0, cy - y0, inside_x, inside_y


@_inline
def _read(buffers, b, channel, row0, row1, column0, column1, fx, fy):
    """Channel `channel` of the (B, H, W, K) buffers, bilinearly, as `_sampling.sample` (a + f (b - a))."""
    top_left = np.float64(buffers[b, row0, column0, channel])
    bottom_left = np.float64(buffers[b, row1, column0, channel])
    top = top_left + fx * (buffers[b, row0, column1, channel] - top_left)
    bottom = bottom_left + fx * (buffers[b, row1, column1, channel] - bottom_left)
    return top + fy * (bottom - top)


@_inline
def _read_slopes(buffers, b, channel, row0, row1, column0, column1, fx, fy):
    """d read / d fx and d read / d fy of `_read`, and the read itself."""
    top_left = np.float64(buffers[b, row0, column0, channel])
    top_right = np.float64(buffers[b, row0, column1, channel])
    bottom_left = np.float64(buffers[b, row1, column0, channel])
    bottom_right = np.float64(buffers[b, row1, column1, channel])
    top = top_left + fx * (top_right - top_left)
    bottom = bottom_left + fx * (bottom_right - bottom_left)
    return (1.0 - fy) * (top_right - top_left) + fy * (bottom_right - bottom_left), bottom - top, top + fy * (bottom - top)


@_inline
def _scatter(grads, b, channel, row0, row1, column0, column1, fx, fy, grad):
    grads[b, row0, column0, channel] += grad * (1.0 - fx) * (1.0 - fy)
    grads[b, row0, column1, channel] += grad * fx * (1.0 - fy)
    grads[b, row1, column0, channel] += grad * (1.0 - fx) * fy
    grads[b, row1, column1, channel] += grad * fx * fy


@_jit
def _interleave(color, velocity, depth, buffers):
    """(B, C, H, W), (B, 2, H, W), (B, 1, H, W) -> buffers (B, H, W, C + 3): a tap's reads sit together."""
    batch, channels, height, width = color.shape
    for row in numba.prange(batch * height):
        b = row // height
        y = row % height
        for x in range(width):
            for c in range(channels):
                buffers[b, y, x, c] = color[b, c, y, x]
            buffers[b, y, x, channels] = velocity[b, 0, y, x]
            buffers[b, y, x, channels + 1] = velocity[b, 1, y, x]
            buffers[b, y, x, channels + 2] = depth[b, 0, y, x]


@_jit
def _deinterleave_sum(grads, out):
    """Sum the (chunks, B, H, W, K) per-chunk gradient buffers into out (B, K, H, W)."""
    chunks, batch, height, width, channels = grads.shape
    for row in numba.prange(batch * height):
        b = row // height
        y = row % height
        for x in range(width):
            for c in range(channels):
                total = 0.0
                for chunk in range(chunks):
                    total += grads[chunk, b, y, x, c]
                out[b, c, y, x] = total


@_inline
def _pixel(buffers, neighbors, jitter, b, jb, y, x, tile, min_radius):
    """Pixel X's NeighborMax v_N and |v_N|, V[X], |V[X]|, the classifiers' speed (floored) and its
    floored inverse, Z[X] and the jitter j, as float64."""
    channels = buffers.shape[3] - 3
    nx = np.float64(neighbors[b, 0, y // tile, x // tile])
    ny = np.float64(neighbors[b, 1, y // tile, x // tile])
    vx = np.float64(buffers[b, y, x, channels])
    vy = np.float64(buffers[b, y, x, channels + 1])
    length_x = _length(vx, vy)
    speed_x = length_x if length_x >= min_radius else min_radius
    z_x = np.float64(buffers[b, y, x, channels + 2])
    return nx, ny, _length(nx, ny), vx, vy, length_x, speed_x, _floored_inverse(speed_x), z_x, np.float64(jitter[jb, 0, y, x])


@_inline
def _tap(k, j, step, own_odd, nx, ny, speed_n, vx, vy, length_x):
    """Tap k's time t (seed 000 Listing 1), whether it follows V[X], its direction and speed."""
    t = -1.0 + (k + j + 1.0) * step
    own = own_odd and k % 2 == 1
    if own:
        return t, own, vx, vy, length_x
    return t, own, nx, ny, speed_n


@_jit
def _reconstruct_forward(buffers, neighbors, counts, jitter, tile, extent, min_radius, own_odd, order, chunks, out, weight):
    batch, height, width, stored = buffers.shape
    channels = stored - 3
    jitter_batch = jitter.shape[0]
    inverse_extent = 1.0 / extent
    rows = batch * height
    for chunk in numba.prange(chunks):
        total = np.empty(channels)
        for i in range(chunk * rows // chunks, (chunk + 1) * rows // chunks):
            row = order[i]
            b = row // height
            y = row % height
            jb = b if jitter_batch > 1 else 0
            for x in range(width):
                count = counts[b, y // tile, x // tile]
                if count == 0:
                    for c in range(channels):
                        out[b, c, y, x] = buffers[b, y, x, c]
                    weight[b, y, x] = 0.0
                    continue
                nx, ny, speed_n, vx, vy, length_x, speed_x, inverse_x, z_x, j = _pixel(buffers, neighbors, jitter, b, jb, y, x, tile, min_radius)
                w = 1.0 / speed_x
                for c in range(channels):
                    total[c] = w * buffers[b, y, x, c]
                middle = (count - 1) // 2
                step = 2.0 / (count + 1.0)
                for k in range(count):
                    if k == middle:
                        continue
                    t, own, dx, dy, speed = _tap(k, j, step, own_odd, nx, ny, speed_n, vx, vy, length_x)
                    column0, column1, row0, row1, fx, fy, _, _ = _bilinear_setup(x + dx * t, y + dy * t, width, height)
                    v_yx = _read(buffers, b, channels, row0, row1, column0, column1, fx, fy)
                    v_yy = _read(buffers, b, channels + 1, row0, row1, column0, column1, fx, fy)
                    z_y = _read(buffers, b, channels + 2, row0, row1, column0, column1, fx, fy)
                    length_y = _length(v_yx, v_yy)
                    inverse_y = _floored_inverse(length_y if length_y >= min_radius else min_radius)
                    distance = abs(t) * speed
                    alpha = (
                        _soft_depth_compare(z_x, z_y, extent, inverse_extent) * _cone(distance, inverse_y)
                        + _soft_depth_compare(z_y, z_x, extent, inverse_extent) * _cone(distance, inverse_x)
                        + _cylinder(distance, inverse_y) * _cylinder(distance, inverse_x) * 2.0
                    )
                    w += alpha
                    for c in range(channels):
                        total[c] += alpha * _read(buffers, b, c, row0, row1, column0, column1, fx, fy)
                for c in range(channels):
                    out[b, c, y, x] = total[c] / w
                weight[b, y, x] = w


@_jit
def _reconstruct_backward(buffers, neighbors, counts, jitter, tile, extent, min_radius, own_odd, order, out, weight, grad_out, grads, grad_neighbors):
    """grads: (chunks, B, H, W, C + 3) zeros, one buffer per chunk of rows (C, V, Z gradients
    interleaved as the buffers); grad_neighbors: (chunks, B, 2, TH, TW) zeros."""
    batch, height, width, stored = buffers.shape
    channels = stored - 3
    jitter_batch = jitter.shape[0]
    inverse_extent = 1.0 / extent
    chunks = grads.shape[0]
    rows = batch * height
    for chunk in numba.prange(chunks):
        g_total = np.empty(channels)
        mine = grads[chunk]
        for i in range(chunk * rows // chunks, (chunk + 1) * rows // chunks):
            row = order[i]
            b = row // height
            y = row % height
            jb = b if jitter_batch > 1 else 0
            for x in range(width):
                count = counts[b, y // tile, x // tile]
                if count == 0:
                    for c in range(channels):
                        mine[b, y, x, c] += grad_out[b, c, y, x]
                    continue
                tile_y = y // tile
                tile_x = x // tile
                nx, ny, speed_n, vx, vy, length_x, speed_x, inverse_x, z_x, j = _pixel(buffers, neighbors, jitter, b, jb, y, x, tile, min_radius)
                w = np.float64(weight[b, y, x])
                # out = total / w: d total = g / w, d w = -sum(g out) / w; per tap alpha and
                # alpha C[Y] both enter, so d alpha = sum(g (C[Y] - out)) / w.
                g_center = 0.0
                for c in range(channels):
                    g_total[c] = grad_out[b, c, y, x] / w
                    g_center += g_total[c] * (buffers[b, y, x, c] - out[b, c, y, x])
                    mine[b, y, x, c] += g_total[c] / speed_x
                g_speed_x = -g_center / (speed_x * speed_x)
                g_length_x = 0.0
                g_vx = 0.0
                g_vy = 0.0
                g_z_x = 0.0
                g_nx = 0.0
                g_ny = 0.0
                g_speed_n = 0.0
                middle = (count - 1) // 2
                step = 2.0 / (count + 1.0)
                for k in range(count):
                    if k == middle:
                        continue
                    t, own, dx, dy, speed = _tap(k, j, step, own_odd, nx, ny, speed_n, vx, vy, length_x)
                    column0, column1, row0, row1, fx, fy, inside_x, inside_y = _bilinear_setup(x + dx * t, y + dy * t, width, height)
                    slope_vxx, slope_vxy, v_yx = _read_slopes(buffers, b, channels, row0, row1, column0, column1, fx, fy)
                    slope_vyx, slope_vyy, v_yy = _read_slopes(buffers, b, channels + 1, row0, row1, column0, column1, fx, fy)
                    slope_zx, slope_zy, z_y = _read_slopes(buffers, b, channels + 2, row0, row1, column0, column1, fx, fy)
                    length_y = _length(v_yx, v_yy)
                    speed_y = length_y if length_y >= min_radius else min_radius
                    inverse_y = _floored_inverse(speed_y)
                    distance = abs(t) * speed
                    front = _soft_depth_compare(z_x, z_y, extent, inverse_extent)
                    behind = _soft_depth_compare(z_y, z_x, extent, inverse_extent)
                    cone_y = _cone(distance, inverse_y)
                    cone_x = _cone(distance, inverse_x)
                    cylinder_y = _cylinder(distance, inverse_y)
                    cylinder_x = _cylinder(distance, inverse_x)
                    alpha = front * cone_y + behind * cone_x + cylinder_y * cylinder_x * 2.0
                    g_alpha = 0.0
                    g_fx = 0.0
                    g_fy = 0.0
                    for c in range(channels):
                        slope_x, slope_y, c_y = _read_slopes(buffers, b, c, row0, row1, column0, column1, fx, fy)
                        g_alpha += g_total[c] * (c_y - out[b, c, y, x])
                        g_c = alpha * g_total[c]
                        _scatter(mine, b, c, row0, row1, column0, column1, fx, fy, g_c)
                        g_fx += g_c * slope_x
                        g_fy += g_c * slope_y
                    # The classifiers.
                    g_z_y = 0.0
                    g_front = g_alpha * cone_y
                    g_behind = g_alpha * cone_x
                    if z_y - z_x >= 0.0 and z_y - z_x <= extent:
                        g_z_y -= g_front * inverse_extent
                        g_z_x += g_front * inverse_extent
                    if z_x - z_y >= 0.0 and z_x - z_y <= extent:
                        g_z_x -= g_behind * inverse_extent
                        g_z_y += g_behind * inverse_extent
                    g_distance, g_speed_y = _cone_grad(distance, speed_y, inverse_y, g_alpha * front)
                    d_distance, d_speed = _cone_grad(distance, speed_x, inverse_x, g_alpha * behind)
                    g_distance += d_distance
                    g_speed_x += d_speed
                    d_distance, d_speed = _cylinder_grad(distance, speed_y, inverse_y, g_alpha * 2.0 * cylinder_x)
                    g_distance += d_distance
                    g_speed_y += d_speed
                    d_distance, d_speed = _cylinder_grad(distance, speed_x, inverse_x, g_alpha * 2.0 * cylinder_y)
                    g_distance += d_distance
                    g_speed_x += d_speed
                    # V[Y] through speed_y = max(|V[Y]|, min_radius).
                    g_v_yx = 0.0
                    g_v_yy = 0.0
                    if length_y >= min_radius and length_y > 0.0:
                        g_v_yx = g_speed_y * v_yx / length_y
                        g_v_yy = g_speed_y * v_yy / length_y
                    _scatter(mine, b, channels, row0, row1, column0, column1, fx, fy, g_v_yx)
                    _scatter(mine, b, channels + 1, row0, row1, column0, column1, fx, fy, g_v_yy)
                    _scatter(mine, b, channels + 2, row0, row1, column0, column1, fx, fy, g_z_y)
                    g_fx += g_v_yx * slope_vxx + g_v_yy * slope_vyx + g_z_y * slope_zx
                    g_fy += g_v_yx * slope_vxy + g_v_yy * slope_vyy + g_z_y * slope_zy
                    # The tap position X + direction t and the distance |t| speed.
                    g_dx = g_fx * t if inside_x else 0.0
                    g_dy = g_fy * t if inside_y else 0.0
                    if own:
                        g_vx += g_dx
                        g_vy += g_dy
                        g_length_x += g_distance * abs(t)
                    else:
                        g_nx += g_dx
                        g_ny += g_dy
                        g_speed_n += g_distance * abs(t)
                if length_x >= min_radius:
                    g_length_x += g_speed_x
                if length_x > 0.0:
                    g_vx += g_length_x * vx / length_x
                    g_vy += g_length_x * vy / length_x
                if speed_n > 0.0:
                    g_nx += g_speed_n * nx / speed_n
                    g_ny += g_speed_n * ny / speed_n
                mine[b, y, x, channels] += g_vx
                mine[b, y, x, channels + 1] += g_vy
                mine[b, y, x, channels + 2] += g_z_x
                grad_neighbors[chunk, b, 0, tile_y, tile_x] += g_nx
                grad_neighbors[chunk, b, 1, tile_y, tile_x] += g_ny


def _threads() -> int:
    return max(1, numba.get_num_threads())


def _buffers(color: np.ndarray, velocity: np.ndarray, depth: np.ndarray) -> np.ndarray:
    batch, channels, height, width = color.shape
    buffers = np.empty((batch, height, width, channels + 3), dtype=color.dtype)
    _interleave(color, velocity, depth, buffers)
    return buffers


def reconstruct_forward(
    color: np.ndarray,
    velocity: np.ndarray,
    depth: np.ndarray,
    neighbors: np.ndarray,
    counts: np.ndarray,
    jitter: np.ndarray,
    *,
    tile: int,
    soft_z_extent: float,
    min_radius: float,
    own_odd: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """The reconstruction filter, fused. color (B, C, H, W), velocity (B, 2, H, W), depth (B, 1, H,
    W), neighbors (B, 2, TH, TW) NeighborMax, counts (B, TH, TW) taps per tile (0: the image),
    jitter (B or 1, 1, H, W), all C-contiguous in one float dtype (counts int32). Returns the
    image and the per-pixel weight sum (B, H, W) that the backward needs."""
    batch, _, height, width = color.shape
    out = np.empty_like(color)
    weight = np.empty((batch, height, width), dtype=color.dtype)
    settings = (int(tile), float(soft_z_extent), float(min_radius), bool(own_odd), row_order(batch * height))
    # Several chunks per thread: numba hands each thread one static share of the loop.
    chunks = min(batch * height, 4 * _threads())
    _reconstruct_forward(_buffers(color, velocity, depth), neighbors, counts, jitter, *settings, chunks, out, weight)
    return out, weight


def reconstruct_backward(
    color: np.ndarray,
    velocity: np.ndarray,
    depth: np.ndarray,
    neighbors: np.ndarray,
    counts: np.ndarray,
    jitter: np.ndarray,
    out: np.ndarray,
    weight: np.ndarray,
    grad_out: np.ndarray,
    *,
    tile: int,
    soft_z_extent: float,
    min_radius: float,
    own_odd: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Gradients of `reconstruct_forward`'s image w.r.t. color, velocity, depth and neighbors,
    given the forward's out and weight and the output's gradient grad_out."""
    batch, channels, height, width = color.shape
    chunks = min(_threads(), batch * height)
    grads = np.zeros((chunks, batch, height, width, channels + 3), dtype=color.dtype)
    grad_neighbors = np.zeros((chunks, *neighbors.shape), dtype=color.dtype)
    settings = (int(tile), float(soft_z_extent), float(min_radius), bool(own_odd), row_order(batch * height))
    _reconstruct_backward(_buffers(color, velocity, depth), neighbors, counts, jitter, *settings, out, weight, grad_out, grads, grad_neighbors)
    total = np.empty((batch, channels + 3, height, width), dtype=color.dtype)
    _deinterleave_sum(grads, total)
    return total[:, :channels], total[:, channels : channels + 2], total[:, channels + 2 :], grad_neighbors.sum(axis=0)


# -- gather_blur ------------------------------------------------------------------------------------
# out[X] = sum_k m[n, k] C[X - t_k V[X]] with n the pixel's tile count and t_k = (2k + 1) / n - 1
# (`diffblur.taps.gather_tap_times`); the mass table m (S + 1, S) holds row n for each count n in use,
# so adaptive classes and the shutter (any window: its masses are an input with a gradient) come in
# as data. Only colour is read at the taps; the velocity is read at X.


def gather_unfused_reason(sampling: str, pyramid: bool, dtype_name: str) -> str | None:
    """Why `gather_blur` with these options cannot take the fused path, or None when it can."""
    if numba is None:
        return "numba is not installed"
    if sampling != "bilinear":
        return f"sampling={sampling!r} (the fused kernel is bilinear)"
    if pyramid:
        return "pyramid=True"
    if dtype_name not in ("float32", "float64"):
        return f"dtype {dtype_name} (the fused kernel takes float32 and float64)"
    return None


def gather_mass_table(window: Any, samples: int, classes: tuple[int, ...], xp: Any, dtype: Any) -> Any:
    """The kernel's mass table (S + 1, S) as an `xp` array of `dtype`: row n holds the renormalised
    masses of n taps for each count n in `classes`, zeros elsewhere. A window with constant
    parameters gets it from NumPy in float64; one with a parameter being fitted from `xp` ops, which
    carry its gradient."""
    from diffblur._scatter_options import has_constant_parameters
    from diffblur.taps import gather_tap_times, stratum_weights

    if has_constant_parameters(window):
        table = np.zeros((samples + 1, samples))
        for count in classes:
            masses = stratum_weights(window, np.asarray(gather_tap_times(count)), 1.0 / count, np)
            table[count, :count] = masses / masses.sum()
        return xp.asarray(table, dtype=dtype)
    rows = []
    for count in range(samples + 1):
        if count in classes:
            masses = stratum_weights(window, xp.asarray(gather_tap_times(count), dtype=dtype), 1.0 / count, xp)
            rows.append(xp.concatenate([masses / masses.sum(), xp.zeros(samples - count, dtype=dtype)]))
        else:
            rows.append(xp.zeros(samples, dtype=dtype))
    return xp.stack(rows)


@_jit
def _channels_last(color, buffers):
    """(B, C, H, W) -> buffers (B, H, W, C): a tap's reads of every channel sit together."""
    batch, channels, height, width = color.shape
    for row in numba.prange(batch * height):
        b = row // height
        y = row % height
        for x in range(width):
            for c in range(channels):
                buffers[b, y, x, c] = color[b, c, y, x]


@_jit
def _gather_forward(buffers, velocity, counts, masses, tile, order, chunks, out):
    batch, height, width, channels = buffers.shape
    rows = batch * height
    for chunk in numba.prange(chunks):
        total = np.empty(channels)
        for i in range(chunk * rows // chunks, (chunk + 1) * rows // chunks):
            row = order[i]
            b = row // height
            y = row % height
            for x in range(width):
                count = counts[b, y // tile, x // tile]
                if count == 0:
                    for c in range(channels):
                        out[b, c, y, x] = buffers[b, y, x, c]
                    continue
                vx = np.float64(velocity[b, 0, y, x])
                vy = np.float64(velocity[b, 1, y, x])
                for c in range(channels):
                    total[c] = 0.0
                for k in range(count):
                    t = (2.0 * k + 1.0) / count - 1.0
                    mass = np.float64(masses[count, k])
                    column0, column1, row0, row1, fx, fy, _, _ = _bilinear_setup(x - t * vx, y - t * vy, width, height)
                    for c in range(channels):
                        total[c] += mass * _read(buffers, b, c, row0, row1, column0, column1, fx, fy)
                for c in range(channels):
                    out[b, c, y, x] = total[c]


@_jit
def _gather_backward(buffers, velocity, counts, masses, tile, order, grad_out, grads, grad_velocity, grad_masses):
    """grads: (chunks, B, H, W, C) zeros, one per chunk of rows; grad_velocity (B, 2, H, W) (each
    pixel writes its own); grad_masses: (chunks, S + 1, S) zeros."""
    batch, height, width, channels = buffers.shape
    chunks = grads.shape[0]
    rows = batch * height
    for chunk in numba.prange(chunks):
        mine = grads[chunk]
        for i in range(chunk * rows // chunks, (chunk + 1) * rows // chunks):
            row = order[i]
            b = row // height
            y = row % height
            for x in range(width):
                count = counts[b, y // tile, x // tile]
                if count == 0:
                    for c in range(channels):
                        mine[b, y, x, c] += grad_out[b, c, y, x]
                    grad_velocity[b, 0, y, x] = 0.0
                    grad_velocity[b, 1, y, x] = 0.0
                    continue
                vx = np.float64(velocity[b, 0, y, x])
                vy = np.float64(velocity[b, 1, y, x])
                g_vx = 0.0
                g_vy = 0.0
                for k in range(count):
                    t = (2.0 * k + 1.0) / count - 1.0
                    mass = np.float64(masses[count, k])
                    column0, column1, row0, row1, fx, fy, inside_x, inside_y = _bilinear_setup(x - t * vx, y - t * vy, width, height)
                    g_fx = 0.0
                    g_fy = 0.0
                    g_mass = 0.0
                    for c in range(channels):
                        g = np.float64(grad_out[b, c, y, x])
                        slope_x, slope_y, c_y = _read_slopes(buffers, b, c, row0, row1, column0, column1, fx, fy)
                        g_mass += g * c_y
                        _scatter(mine, b, c, row0, row1, column0, column1, fx, fy, g * mass)
                        g_fx += g * slope_x
                        g_fy += g * slope_y
                    grad_masses[chunk, count, k] += g_mass
                    # The tap position is X - t V: the clamp at the border passes no gradient.
                    if inside_x:
                        g_vx -= mass * g_fx * t
                    if inside_y:
                        g_vy -= mass * g_fy * t
                grad_velocity[b, 0, y, x] = g_vx
                grad_velocity[b, 1, y, x] = g_vy


def _channels_last_buffers(color: np.ndarray) -> np.ndarray:
    batch, channels, height, width = color.shape
    buffers = np.empty((batch, height, width, channels), dtype=color.dtype)
    _channels_last(color, buffers)
    return buffers


@_jit
def _gather_tile_counts(velocity, classes, still, tile, counts):
    """counts (B, TH, TW): the taps of each tile's class from its largest |V|, as
    `diffblur._adaptive.tile_sample_counts` (0 at most `still`, else the smallest class c with
    2 |V| <= c, else the last)."""
    batch, _, height, width = velocity.shape
    _, tiles_y, tiles_x = counts.shape
    for index in numba.prange(batch * tiles_y):
        b = index // tiles_y
        tile_y = index % tiles_y
        for tile_x in range(tiles_x):
            largest = 0.0
            for y in range(tile_y * tile, min((tile_y + 1) * tile, height)):
                for x in range(tile_x * tile, min((tile_x + 1) * tile, width)):
                    vx = np.float64(velocity[b, 0, y, x])
                    vy = np.float64(velocity[b, 1, y, x])
                    largest = max(largest, vx * vx + vy * vy)
            speed = math.sqrt(largest)
            count = 0
            if speed > still:
                count = classes[-1]
                for c in classes[::-1]:
                    if 2.0 * speed <= c:
                        count = c
            counts[b, tile_y, tile_x] = count


def _gather_counts(velocity: np.ndarray, samples: int, classes: tuple[int, ...] | None, still: float, tile: int) -> np.ndarray:
    batch, _, height, width = velocity.shape
    if classes is None:  # the full rate everywhere, one tile
        return np.full((batch, 1, 1), samples, dtype=np.int32)
    counts = np.empty((batch, -(-height // tile), -(-width // tile)), dtype=np.int32)
    _gather_tile_counts(velocity, np.asarray(classes, dtype=np.int64), float(still), int(tile), counts)
    return counts


def gather_forward(
    color: np.ndarray, velocity: np.ndarray, masses: np.ndarray, *, samples: int, classes: tuple[int, ...] | None, still: float, tile: int
) -> np.ndarray:
    """gather_blur, fused. color (B, C, H, W), velocity (B, 2, H, W), masses (S + 1, S) with row n
    the masses of n taps, all C-contiguous, one float dtype. classes: the adaptive sample counts
    (each tile of `tile` px takes its class's taps, 0 where its |V| <= still: the image), or None
    for `samples` taps everywhere."""
    batch, _, height, width = color.shape
    out = np.empty_like(color)
    chunks = min(batch * height, 4 * _threads())
    counts = _gather_counts(velocity, samples, classes, still, tile)
    _gather_forward(_channels_last_buffers(color), velocity, counts, masses, max(height, width) if classes is None else int(tile), row_order(batch * height), chunks, out)
    return out


def gather_backward(
    color: np.ndarray,
    velocity: np.ndarray,
    masses: np.ndarray,
    grad_out: np.ndarray,
    *,
    samples: int,
    classes: tuple[int, ...] | None,
    still: float,
    tile: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gradients of `gather_forward`'s image w.r.t. color, velocity and masses."""
    batch, channels, height, width = color.shape
    chunks = min(_threads(), batch * height)
    grads = np.zeros((chunks, batch, height, width, channels), dtype=color.dtype)
    grad_velocity = np.empty_like(velocity)
    grad_masses = np.zeros((chunks, *masses.shape), dtype=masses.dtype)
    counts = _gather_counts(velocity, samples, classes, still, tile)
    tile = max(height, width) if classes is None else int(tile)
    _gather_backward(_channels_last_buffers(color), velocity, counts, masses, tile, row_order(batch * height), grad_out, grads, grad_velocity, grad_masses)
    grad_color = np.empty_like(color)
    _deinterleave_sum(grads, grad_color)
    return grad_color, grad_velocity, grad_masses.sum(axis=0)
