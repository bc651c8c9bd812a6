"""The fused CPU kernels (numba) of `gather_blur`, behind the PyTorch and JAX ops' custom gradients.

out[X] = sum_k m[n, k] C[X - t_k V[X]] with n the pixel's tile count and t_k = (2k + 1) / n - 1
(`diffblur.ops.taps.gather_tap_times`); the mass table m (S + 1, S) holds row n for each count n in use,
so adaptive classes and the shutter (any window: its masses are an input with a gradient) come in
as data. Only colour is read at the taps; the velocity is read at X. The layout is
`diffblur.kernels.reconstruct`'s (pairs of the colour, blocks of one row as vectors, scratch
arguments; `diffblur.kernels.shared`).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from diffblur.kernels.shared import (
    _BLOCK,
    ChannelFloats,
    Floats,
    Ints,
    _block_end,
    _color_pairs,
    _deinterleave_sum,
    _jit,
    _pair,
    _pair_read,
    _pair_read_slopes,
    _scatter_chunk,
    _take_next,
    _tap_corner,
    _threads,
    check_scratch,
    numba,
    read_only,
    row_order,
    scratch_for,
    work_counter,
    work_pieces,
)

__all__ = [
    "GatherBackwardScratch",
    "GatherForwardScratch",
    "gather_backward",
    "gather_forward",
    "gather_mass_table",
    "gather_unfused_reason",
]


def gather_unfused_reason(sampling: str, dtype_name: str) -> str | None:
    """Why `gather_blur` with these options cannot take the fused path, or None when it can."""
    if numba is None:
        return "numba is not installed"
    if sampling != "bilinear":
        return f"sampling={sampling!r} (the fused kernel reads bilinearly, from the image only)"
    if dtype_name not in ("float32", "float64"):
        return f"dtype {dtype_name} (the fused kernel takes float32 and float64)"
    return None


def gather_mass_table(window: Any, samples: int, classes: tuple[int, ...], xp: Any, dtype: Any) -> Any:
    """The kernel's mass table (S + 1, S) as an `xp` array of `dtype`: row n holds the renormalised
    masses of n taps for each count n in `classes`, zeros elsewhere. A window with constant
    parameters gets it from NumPy in float64; one with a parameter being fitted from `xp` ops, which
    carry its gradient."""
    from diffblur.ops.scatter import has_constant_parameters
    from diffblur.ops.taps import gather_tap_times, stratum_weights

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
def _gather_forward(pairs, velocity, counts, masses, tile, order, pieces, taken, out, vx_s, vy_s, index_s, below_s, fx_s, fy_s, total_s):
    """`_reconstruct_forward`'s layout for the gather: pairs of the colour (`_color_pairs`), blocks
    of one row as vectors (per tap index, one loop places the taps, one per channel reads them), the
    rows (in `order`) in `pieces` pieces taken by the workers in turn (`_take_next` on `taken`), the
    *_s scratch one block per worker: (chunks, >= _BLOCK), total_s (chunks, C, >= _BLOCK)."""
    batch, channels, height, width = out.shape
    chunks = vx_s.shape[0]
    rows = batch * height
    last_x = width - 1.0
    last_y = height - 1.0
    for chunk in numba.prange(chunks):  # one iteration per worker; chunk: its scratch
        while True:
            piece = _take_next(taken)
            if piece >= pieces:
                break
            for i in range(piece * rows // pieces, (piece + 1) * rows // pieces):
                    row = order[i]
                    b = row // height
                    y = row % height
                    image_start = b * height * width * channels
                    start = 0
                    while start < width:
                        end = _block_end(counts, b, y // tile, start, width, tile, _BLOCK)
                        size = end - start
                        count = counts[b, y // tile, start // tile]
                        if count == 0:  # the image
                            for x in range(start, end):
                                for c in range(channels):
                                    out[b, c, y, x] = _pair(pairs, image_start + (y * width + x) * channels + c)[0]
                            start = end
                            continue
                        for p in range(size):
                            # Unsigned column indices: a signed start + p carries numba's negative-index wraparound,
                            # a select in front of each load that blocks the vector loads.
                            vx_s[chunk, p] = velocity[b, 0, y, np.uint64(start + p)]
                            vy_s[chunk, p] = velocity[b, 1, y, np.uint64(start + p)]
                            for c in range(channels):
                                total_s[chunk, c, p] = 0.0
                        for k in range(count):
                            t = (2.0 * k + 1.0) / count - 1.0
                            mass = np.float64(masses[count, k])
                            for p in range(size):  # vectorized: the taps
                                column, row0, fx, fy, _, _ = _tap_corner((start + p) - t * vx_s[chunk, p], y - t * vy_s[chunk, p], last_x, last_y)
                                index_s[chunk, p] = image_start + (row0 * width + column) * channels
                                below_s[chunk, p] = width * channels if row0 < height - 1 else 0
                                fx_s[chunk, p] = fx
                                fy_s[chunk, p] = fy
                            for c in range(channels):
                                for p in range(size):  # vectorized: gathers
                                    read = _pair_read(pairs, index_s[chunk, p] + c, below_s[chunk, p], fx_s[chunk, p], fy_s[chunk, p])
                                    total_s[chunk, c, p] += mass * read
                        for p in range(size):
                            for c in range(channels):
                                out[b, c, y, np.uint64(start + p)] = total_s[chunk, c, p]
                        start = end


@_jit
def _gather_backward(
    pairs, velocity, counts, masses, tile, order, scatter_color, grad_out, grads, grad_velocity, grad_masses,
    vx_s, vy_s, column_s, row_s, fx_s, fy_s, inside_x_s, inside_y_s, g_fx_s, g_fy_s, g_mass_s, g_vx_s, g_vy_s, g_s,
):
    """`_gather_forward`'s layout for its backward: per tap index, one vector loop places the taps,
    one per channel reads them with their slopes, then a scalar loop scatters the colour's gradient
    to the 4 pixels each tap read (lanes may collide), if scatter_color is 1 (an int: see the note
    on aliases above; with 0 grads stays incomplete). grads: (chunks, B, H, W, C) zeros, one per
    chunk of rows; grad_velocity (B, 2, H, W) (each pixel writes its own); grad_masses: (chunks,
    S + 1, S) zeros; *_s scratch (chunks, >= _BLOCK), g_s (chunks, C, >= _BLOCK)."""
    batch, _, height, width = velocity.shape
    chunks, channels = grads.shape[0], grads.shape[4]
    rows = batch * height
    last_x = width - 1.0
    last_y = height - 1.0
    for chunk in numba.prange(chunks):
        # Accumulated in the thread's own memory: written per tap, grad_masses' rows lie side by side.
        g_masses = np.zeros(grad_masses.shape[1:])
        for i in range(chunk * rows // chunks, (chunk + 1) * rows // chunks):
            row = order[i]
            b = row // height
            y = row % height
            image_start = b * height * width * channels
            start = 0
            while start < width:
                end = _block_end(counts, b, y // tile, start, width, tile, _BLOCK)
                size = end - start
                count = counts[b, y // tile, start // tile]
                if count == 0:  # out = C[X]
                    for x in range(np.uint64(start), np.uint64(end)):
                        if scatter_color != 0:
                            for c in range(channels):
                                grads[chunk, b, y, x, c] += grad_out[b, c, y, x]
                        grad_velocity[b, 0, y, x] = 0.0
                        grad_velocity[b, 1, y, x] = 0.0
                    start = end
                    continue
                for p in range(size):
                    vx_s[chunk, p] = velocity[b, 0, y, np.uint64(start + p)]
                    vy_s[chunk, p] = velocity[b, 1, y, np.uint64(start + p)]
                    g_vx_s[chunk, p] = 0.0
                    g_vy_s[chunk, p] = 0.0
                    for c in range(channels):
                        g_s[chunk, c, p] = grad_out[b, c, y, np.uint64(start + p)]
                for k in range(count):
                    t = (2.0 * k + 1.0) / count - 1.0
                    mass = np.float64(masses[count, k])
                    for p in range(size):  # vectorized: the taps
                        # The clamp at the border passes no gradient to the tap position X - t V.
                        column, row0, fx, fy, inside_x, inside_y = _tap_corner((start + p) - t * vx_s[chunk, p], y - t * vy_s[chunk, p], last_x, last_y)
                        column_s[chunk, p] = column
                        row_s[chunk, p] = row0
                        fx_s[chunk, p] = fx
                        fy_s[chunk, p] = fy
                        inside_x_s[chunk, p] = inside_x
                        inside_y_s[chunk, p] = inside_y
                        g_fx_s[chunk, p] = 0.0
                        g_fy_s[chunk, p] = 0.0
                        g_mass_s[chunk, p] = 0.0
                    for c in range(channels):
                        for p in range(size):  # vectorized: the colours read and their slopes
                            row0 = row_s[chunk, p]
                            index = image_start + (row0 * width + column_s[chunk, p]) * channels + c
                            below = width * channels if row0 < height - 1 else 0
                            slope_x, slope_y, c_y = _pair_read_slopes(pairs, index, below, fx_s[chunk, p], fy_s[chunk, p])
                            g = g_s[chunk, c, p]
                            g_mass_s[chunk, p] += g * c_y
                            g_fx_s[chunk, p] += g * slope_x
                            g_fy_s[chunk, p] += g * slope_y
                    g_mass = 0.0
                    for p in range(size):
                        g_mass += g_mass_s[chunk, p]
                        g_vx_s[chunk, p] -= mass * g_fx_s[chunk, p] * t * inside_x_s[chunk, p]
                        g_vy_s[chunk, p] -= mass * g_fy_s[chunk, p] * t * inside_y_s[chunk, p]
                    g_masses[count, k] += g_mass
                    if scatter_color != 0:
                        for p in range(size):  # scalar: the 4 pixels each tap read
                            row0 = row_s[chunk, p]
                            column = column_s[chunk, p]
                            row1 = min(row0 + 1, height - 1)
                            column1 = min(column + 1, width - 1)
                            for c in range(channels):
                                _scatter_chunk(grads, chunk, b, c, row0, row1, column, column1, fx_s[chunk, p], fy_s[chunk, p], g_s[chunk, c, p] * mass)
                for p in range(size):
                    grad_velocity[b, 0, y, np.uint64(start + p)] = g_vx_s[chunk, p]
                    grad_velocity[b, 1, y, np.uint64(start + p)] = g_vy_s[chunk, p]
                start = end
        grad_masses[chunk] = g_masses


@_jit
def _gather_tile_counts(velocity, classes, still, tile, counts):
    """counts (B, TH, TW): the taps of each tile's class from its largest |V|, as
    `diffblur.ops.adaptive.tile_sample_counts` (0 at most `still`, else the smallest class c with
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


class GatherForwardScratch(NamedTuple):
    """`_gather_forward`'s scratch (its *_s parameters, in order): each pixel's V[X], the current
    tap's read position, and the colour total."""

    vx: Floats
    vy: Floats
    index: Ints
    below: Ints
    fx: Floats
    fy: Floats
    total: ChannelFloats


class GatherBackwardScratch(NamedTuple):
    """`_gather_backward`'s scratch (its *_s parameters, in order): each pixel's V[X], the current
    tap's position and the gradients of its reads, the gradients accumulated for V[X], and the
    output's gradient."""

    vx: Floats
    vy: Floats
    column: Ints
    row: Ints
    fx: Floats
    fy: Floats
    inside_x: Floats
    inside_y: Floats
    g_fx: Floats
    g_fy: Floats
    g_mass: Floats
    g_vx: Floats
    g_vy: Floats
    g: ChannelFloats


check_scratch(_gather_forward, GatherForwardScratch)
check_scratch(_gather_backward, GatherBackwardScratch)


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
    color, velocity, masses = read_only(color, velocity, masses)
    batch, _, height, width = color.shape
    out = np.empty_like(color)
    counts = _gather_counts(velocity, samples, classes, still, tile)
    tile = max(height, width) if classes is None else int(tile)
    workers = min(batch * height, _threads())
    scratch = scratch_for(GatherForwardScratch, workers, color.shape[1])
    order = row_order(batch * height)
    _gather_forward(_color_pairs(color), velocity, counts, masses, tile, order, work_pieces(batch * height, workers), work_counter(), out, *scratch)
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
    needs: tuple[bool, bool, bool] = (True, True, True),
) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """Gradients of `gather_forward`'s image w.r.t. color, velocity and masses. needs: whether each
    wants its gradient; None for the others. Without the colour's, the scatter to the taps' pixels
    (most of the backward's time) is skipped."""
    color, velocity, masses, grad_out = read_only(color, velocity, masses, grad_out)
    batch, channels, height, width = color.shape
    chunks = min(_threads(), batch * height)
    need_color, need_velocity, need_masses = (bool(need) for need in needs)
    grads = np.zeros((chunks, batch, height, width, channels) if need_color else (chunks, batch, 1, 1, channels), dtype=color.dtype)
    grad_velocity = np.empty_like(velocity)
    grad_masses = np.zeros((chunks, *masses.shape), dtype=masses.dtype)
    counts = _gather_counts(velocity, samples, classes, still, tile)
    tile = max(height, width) if classes is None else int(tile)
    scratch = scratch_for(GatherBackwardScratch, chunks, channels)
    arrays = (_color_pairs(color), velocity, counts, masses, tile, row_order(batch * height), int(need_color))
    _gather_backward(*arrays, grad_out, grads, grad_velocity, grad_masses, *scratch)
    grad_color = None
    if need_color:
        grad_color = np.empty_like(color)
        _deinterleave_sum(grads, grad_color, 0)
    return grad_color, grad_velocity if need_velocity else None, grad_masses.sum(axis=0) if need_masses else None
