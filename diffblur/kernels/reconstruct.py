"""The fused CPU kernels (numba) of `reconstruct`, behind the PyTorch and JAX ops' custom gradients.

A tensor framework runs `reconstruct` as ~200 full-resolution elementwise ops per tap; on a 2-core
CPU that cannot reach the 100 ms target at 1280x720 (BENCHMARKS.md), and JAX's backward is
dominated by the scatter-add that transposes the bilinear reads. These kernels do the whole filter
in one parallel loop over pixels, and its hand-written backward in a second one, each running a
block of one row at a time as SIMD vectors (`diffblur.kernels.shared`: the pair layouts, the blocks,
the scratch). They take and return NumPy arrays, so both backends share them: `torch_impl._fused`
wraps them in custom operators, `jax_impl._fused` in a `custom_vjp` over `pure_callback`.

The pure tensor ops stay the reference: tests compare outputs and gradients of both paths. The
kernels repeat the pure ops' arithmetic (the same clamps, floors and `where` branches, so the same
one-sided derivatives at kinks), reading and writing the arrays' dtype. `reconstruct`'s shifted
rows compute the taps in that dtype too (float32 vectors hold twice the lanes); the per-pixel taps
and the other kernels compute in float64.

Scope, checked by `reconstruct_unfused_reason`: bilinear sampling, the box shutter, float32 or
float64, no pyramid. The tap count is per tile (`counts`), which is how adaptive sampling and the
early-out run here: a tile with count 0 returns the image and costs one copy.

Two ways to read the taps, chosen per call by `shifted_rows`, each compiled as a kernel of its own
(which arguments are None picks it; see `_reconstruct_backward`):

- Shifted rows, when every tile's taps share their offsets (no jitter, or one constant per tile,
  and every tap along NeighborMax, which is constant over a tile): tap k of a tile is the tile's
  row read at one offset v_N t_k, so the reads are contiguous runs of the planar images with one
  pair of bilinear fractions, and the backward's bilinear scatter is one vector pass per row read
  in which no two lanes add to one pixel. Neighbouring tiles with the same NeighborMax and jitter (a pan, any
  region of one dominant motion) are read as one run. The taps of a run's pixels clamped at the
  image border all read one point (column 0 or W - 1): read once, their classifiers as vectors.
- Per pixel, otherwise (the "noise" jitter, directions="neighbor_and_own"): each pixel's tap read
  from a buffer of (left, right) pairs, and the backward scatters each tap's gradient to the 4
  pixels it read, which lanes may share, one pixel at a time.

The backward's scatter adds to pixels that other rows' taps also read. With shifted rows the
image is cut into bands of whole tile rows (`_bands`, 4 per thread, taken by the threads as they come
free); a band writes its own rows of the output in place and the rows its taps read beyond them
(|NeighborMax_y| + 2 above and below) into margins of its own, added to the output after
(`_add_margins`): no thread writes another's element, and the memory is the output plus the margins.
Per pixel, each thread accumulates into its own full-size buffer, summed at the end: O(pixels x
threads) (2 threads here). Neither is O(pixels x taps).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from diffblur.conventions import CYLINDER_INNER, CYLINDER_OUTER, EPSILON
from diffblur.kernels.shared import (
    _BLOCK,
    ChannelFloats,
    Floats,
    GradientFloats,
    Ints,
    _block_end,
    _deinterleave_sum,
    _inline,
    _jit,
    _length,
    _llvm_inline,
    _pair_read,
    _pair_read_slopes,
    _pairs,
    _real,
    _scatter_chunk,
    _soft_depth_compare,
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
    "ReconstructBackwardScratch",
    "ReconstructForwardScratch",
    "reconstruct_backward",
    "reconstruct_backward_stacked",
    "reconstruct_forward",
    "reconstruct_unfused_reason",
    "shifted_rows",
    "tile_counts",
]

_INVERSE_CYLINDER_SPAN = 1.0 / (CYLINDER_OUTER - CYLINDER_INNER)


def reconstruct_unfused_reason(o: Any, dtype_name: str) -> str | None:
    """Why `reconstruct` with options `o` (`diffblur.ops.reconstruct.ReconstructOptions`) cannot take the
    fused path, or None when it can. dtype_name: the image's dtype, as a string."""
    from diffblur.shutters import Box

    if numba is None:
        return "numba is not installed"
    if o.sampling != "bilinear":
        return f"sampling={o.sampling!r} (the fused kernel reads bilinearly, from the image only)"
    if type(o.window) is not Box:
        return f"shutter {o.window.name!r} (the fused kernel takes the box shutter)"
    if dtype_name not in ("float32", "float64"):
        return f"dtype {dtype_name} (the fused kernel takes float32 and float64)"
    return None


def tile_counts(speed: Any, o: Any, xp: Any) -> Any:
    """The kernel's taps per tile from the tiles' |NeighborMax| (any shape, numpy/torch/jax.numpy):
    the adaptive classes, else the full rate, 0 where the early-out returns the image."""
    from diffblur.ops.adaptive import still_speed, tile_sample_counts

    if o.classes is not None:
        return tile_sample_counts(speed, o.classes, still_speed(o.early_out), xp)
    # Without the early-out no tile is skipped: the full-rate filter runs on still tiles too.
    return tile_sample_counts(speed, (o.samples,), still_speed(True) if o.early_out else -1.0, xp)


@_inline
def _floored_inverse(speed):
    """1 / max(speed, EPSILON): the classifiers divide by the floored speed; one division per speed."""
    floor = _real(EPSILON, speed)  # in the speed's precision: float32(EPSILON) is the first float32 above it
    return _real(1.0, speed) / (speed if speed >= floor else floor)


@_inline
def _cone(distance, inverse):
    """max(1 - distance / speed, 0): distance >= 0 (|t| times a length), so it is never above 1."""
    ratio = distance * inverse
    u = _real(1.0, ratio) - ratio
    return _real(0.0, u) if u < 0.0 else u


@_inline
def _cylinder(distance, inverse):
    ratio = distance * inverse
    q = (ratio - _real(CYLINDER_INNER, ratio)) * _real(_INVERSE_CYLINDER_SPAN, ratio)
    one = _real(1.0, ratio)
    q = _real(0.0, ratio) if q < 0.0 else (one if q > 1.0 else q)
    return one - q * q * (_real(3.0, ratio) - _real(2.0, ratio) * q)


@_inline
def _classifier_slope(distance, inverse, depth_weight, other_cylinder):
    """d / d ratio of depth_weight * cone + 2 cylinder * other_cylinder, both at ratio = distance *
    inverse (the pure op's one-sided rules: zero where a clamp holds). d ratio / d distance is
    inverse and d ratio / d speed is -ratio * inverse, so one slope serves both derivatives."""
    ratio = distance * inverse
    zero = _real(0.0, ratio)
    q = (ratio - _real(CYLINDER_INNER, ratio)) * _real(_INVERSE_CYLINDER_SPAN, ratio)
    cone_slope = depth_weight if _real(1.0, ratio) - ratio >= 0.0 else zero  # d cone / d ratio = -1
    cylinder_slope = other_cylinder * (q - q * q) if (q >= 0.0) & (q <= 1.0) else zero  # d cylinder / d q = -6 q (1 - q)
    return _real(-12.0 * _INVERSE_CYLINDER_SPAN, ratio) * cylinder_slope - cone_slope



@_llvm_inline
def _tap_alpha(z_x, z_y, v_yx, v_yy, distance, inverse_x, min_radius, extent, inverse_extent):
    """A tap's weight from Z[X], the values read at Y and the tap's distance: the three classifiers."""
    length_y = math.sqrt(v_yx * v_yx + v_yy * v_yy)
    speed_y = length_y if length_y >= min_radius else min_radius
    inverse_y = _floored_inverse(speed_y)
    return (
        _soft_depth_compare(z_x, z_y, extent, inverse_extent) * _cone(distance, inverse_y)
        + _soft_depth_compare(z_y, z_x, extent, inverse_extent) * _cone(distance, inverse_x)
        + _cylinder(distance, inverse_y) * _cylinder(distance, inverse_x) * _real(2.0, distance * inverse_x)
    )


@_llvm_inline
def _keep_tap_alpha(alpha_s, weight_s, chunk, u, z_x, z_y, v_yx, v_yy, distance, inverse_x, min_radius, extent, inverse_extent):
    """A shifted-row tap's weight for pixel u (`_tap_alpha`): kept for the colours' loop and added
    to the pixel's weight sum."""
    alpha = _tap_alpha(z_x, z_y, v_yx, v_yy, distance, inverse_x, min_radius, extent, inverse_extent)
    alpha_s[chunk, u] = alpha
    weight_s[chunk, u] += alpha


@_llvm_inline
def _row_read(flat, top, below, fx, fy):
    """Bilinear read of a flat image at index `top` (top-left) and `top + below` (the row below), in
    the images' dtype, the arithmetic of `_pair_read`. Along a shifted row consecutive pixels read consecutive
    indices: contiguous vector loads, no gathers. The indices are unsigned: a signed index would
    carry numba's negative-index wraparound, a select that turns the loads into gathers."""
    one = np.uint64(1)
    top_left = flat[top]
    top_right = flat[top + one]
    bottom_left = flat[top + below]
    bottom_right = flat[top + below + one]
    top_row = top_left + fx * (top_right - top_left)
    bottom_row = bottom_left + fx * (bottom_right - bottom_left)
    return top_row + fy * (bottom_row - top_row)


@_llvm_inline
def _on_row_read(flat, top, fx):
    """`_row_read` of a tap that lies on a row (fy = 0): the row below has no weight."""
    left = flat[top]
    return left + fx * (flat[top + np.uint64(1)] - left)


@_inline
def _row_read_slopes(flat, top, below, fx, fy):
    """d read / d fx, d read / d fy and the read of `_row_read`."""
    one = np.uint64(1)
    top_left = flat[top]
    top_right = flat[top + one]
    bottom_left = flat[top + below]
    bottom_right = flat[top + below + one]
    top_row = top_left + fx * (top_right - top_left)
    bottom_row = bottom_left + fx * (bottom_right - bottom_left)
    return (_real(1.0, fy) - fy) * (top_right - top_left) + fy * (bottom_right - bottom_left), bottom_row - top_row, top_row + fy * (bottom_row - top_row)


@_inline
def _clamped_read_slopes(flat, plane, width, row0, row1, column, fx, fy):
    """`_row_read_slopes` at one point (a tap clamped at the border): plane is the index of
    the image plane's first pixel, the right column clamped to the image as `_pairs` does."""
    column1 = min(column + 1, width - 1)
    top_left = flat[plane + row0 * width + column]
    top_right = flat[plane + row0 * width + column1]
    bottom_left = flat[plane + row1 * width + column]
    bottom_right = flat[plane + row1 * width + column1]
    top_row = top_left + fx * (top_right - top_left)
    bottom_row = bottom_left + fx * (bottom_right - bottom_left)
    return (_real(1.0, fy) - fy) * (top_right - top_left) + fy * (bottom_right - bottom_left), bottom_row - top_row, top_row + fy * (bottom_row - top_row)


@_inline
def _shifted_rows(py, shift_x, start, segment, segment_end, height, width, last_y):
    """A tile segment [segment, segment_end)'s tap at offset (shift_x, py - y): the rows read and
    their fraction, the whole-pixel column shift and the column fraction, whether the row was
    clamped (inside_y 0.0) and the segment's pixels whose reads lie inside the image, as block
    offsets [first, last). The others are clamped at the border: column 0 before first, W - 1 from last."""
    clamped_y = min(max(py, 0.0), last_y)
    row0 = np.int64(clamped_y)
    fy = clamped_y - row0
    row1 = min(row0 + 1, height - 1)
    inside_y = 1.0 if (py >= 0.0) & (py <= last_y) else 0.0
    shift = np.int64(math.floor(shift_x))
    first = min(max(segment, -shift), segment_end)
    last = max(min(segment_end, width - 1 - shift), first)
    return row0, row1, fy, inside_y, shift, shift_x - shift, first - start, last - start


@_inline
def _border_run(side, q, first, last, end, width):
    """A shifted-row segment [q, end)'s pixels whose taps fall off the image (block offsets [lo, hi))
    and the column they are clamped to: side 0 those before `first` (column 0), side 1 those from
    `last` on (column W - 1). Selects and one return: a tuple merged from two returns, or chosen
    by a conditional expression, is an alias to numba's parallel loops (the backward ran 4x slower)."""
    lo = q if side == 0 else last
    hi = first if side == 0 else end
    column = 0 if side == 0 else width - 1
    return lo, hi, column


@_inline
def _segment_end(segment, start, end, tile, chunk, jitter_s, nx_s, ny_s):
    """Where the shifted-row segment that starts at column `segment` of the block [start, end) ends:
    the run of whole tiles whose taps share its offsets (the same NeighborMax and jitter, as over a
    uniform pan). One long run vectorizes better than one loop per tile of `tile` pixels (a 20-pixel
    loop spends much of its time outside the full SIMD vectors)."""
    q = segment - start
    segment_end = min((segment // tile + 1) * tile, end)
    while segment_end < end:
        p = segment_end - start
        if (nx_s[chunk, p] != nx_s[chunk, q]) | (ny_s[chunk, p] != ny_s[chunk, q]) | (jitter_s[chunk, p] != jitter_s[chunk, q]):
            break
        segment_end = min(segment_end + tile, end)
    return segment_end


@_inline
def _tap_gradients(z_x, speed_x, inverse_x, distance, g_alpha, v_yx, v_yy, z_y, min_radius, extent, inverse_extent):
    """A tap's weight alpha and the derivatives of g_alpha * alpha: w.r.t. V[Y] (x, y), Z[Y], the
    classifiers' speed of X, Z[X] and the tap's distance (the pure op's one-sided rules)."""
    length_y = math.sqrt(v_yx * v_yx + v_yy * v_yy)
    speed_y = length_y if length_y >= min_radius else min_radius
    inverse_y = _floored_inverse(speed_y)
    front = _soft_depth_compare(z_x, z_y, extent, inverse_extent)
    behind = _soft_depth_compare(z_y, z_x, extent, inverse_extent)
    cone_y = _cone(distance, inverse_y)
    cone_x = _cone(distance, inverse_x)
    cylinder_y = _cylinder(distance, inverse_y)
    cylinder_x = _cylinder(distance, inverse_x)
    two = _real(2.0, distance * inverse_x)
    alpha = front * cone_y + behind * cone_x + cylinder_y * cylinder_x * two
    zero = _real(0.0, alpha)
    front_slope = cone_y if (z_y - z_x >= 0.0) & (z_y - z_x <= extent) else zero  # times g_alpha / extent
    behind_slope = cone_x if (z_x - z_y >= 0.0) & (z_x - z_y <= extent) else zero
    g_z_y = g_alpha * inverse_extent * (behind_slope - front_slope)
    d_distance_y = g_alpha * inverse_y * _classifier_slope(distance, inverse_y, front, cylinder_x)
    d_distance_x = g_alpha * inverse_x * _classifier_slope(distance, inverse_x, behind, cylinder_y)
    floor = _real(EPSILON, speed_y)  # below it the inverse is floored: no gradient to the speed
    g_speed_y = -(distance * inverse_y) * d_distance_y if speed_y >= floor else zero
    g_speed_x = -(distance * inverse_x) * d_distance_x if speed_x >= floor else zero
    g_distance = d_distance_y + d_distance_x
    # V[Y] through speed_y = max(|V[Y]|, min_radius): d |V| / d V = V / |V|, with inverse_y for 1 / |V|
    # (equal where the speed is at least EPSILON; below it the classifiers' g_speed_y is zero).
    moving = (length_y >= min_radius) & (length_y > 0.0)
    g_over_length = g_speed_y * inverse_y
    g_v_yx = g_over_length * v_yx if moving else zero
    g_v_yy = g_over_length * v_yy if moving else zero
    return alpha, g_v_yx, g_v_yy, g_z_y, g_speed_x, -g_z_y, g_distance


@_inline
def _block_state(velocity, depth, neighbors, jitter, b, jb, y, start, end, tile, min_radius, chunk, jitter_s, nx_s, ny_s, speed_n_s, vx_s, vy_s, length_x_s, speed_x_s, inverse_x_s, z_x_s):
    """The scratch entries of the block [start, end) of row y, image b, chunk `chunk` (entry p for
    pixel start + p): the jitter, NeighborMax v_N and |v_N|, V[X], |V[X]|, the classifiers' speed
    and its floored inverse, Z[X]. NeighborMax is read once per tile (the block starts on a tile's
    edge), so that the per-pixel loop has no integer division and runs as vectors."""
    tile_y = y // tile
    for tile_x in range(start // tile, (end - 1) // tile + 1):
        nx = np.float64(neighbors[b, 0, tile_y, tile_x])
        ny = np.float64(neighbors[b, 1, tile_y, tile_x])
        speed_n = _length(nx, ny)
        for p in range(np.uint64(max(tile_x * tile, start) - start), np.uint64(min((tile_x + 1) * tile, end) - start)):  # vectorized: unsigned, see below
            nx_s[chunk, p] = nx
            ny_s[chunk, p] = ny
            speed_n_s[chunk, p] = speed_n
    for p in range(end - start):  # vectorized
        x = np.uint64(start + p)  # unsigned: no negative-index wraparound, whose select blocks the vector loads
        jitter_s[chunk, p] = jitter[jb, 0, y, x]
        vx = np.float64(velocity[b, 0, y, x])
        vy = np.float64(velocity[b, 1, y, x])
        vx_s[chunk, p] = vx
        vy_s[chunk, p] = vy
        length_x = _length(vx, vy)
        length_x_s[chunk, p] = length_x
        speed_x = length_x if length_x >= min_radius else min_radius
        speed_x_s[chunk, p] = speed_x
        inverse_x_s[chunk, p] = _floored_inverse(speed_x)
        z_x_s[chunk, p] = depth[b, 0, y, x]


@_jit
def _reconstruct_forward(
    pairs, color_flat, velocity_flat, depth_flat, color, velocity, depth, neighbors, counts, jitter, tile, extent, min_radius, own_odd, order, chunks, pieces, taken, out, weight,
    jitter_s, nx_s, ny_s, speed_n_s, vx_s, vy_s, length_x_s, speed_x_s, inverse_x_s, z_x_s, weight_s, total_s, index_s, below_s, fx_s, fy_s, alpha_s,
):
    """chunks workers, one parallel iteration each, take the rows (in `order`) in `pieces` pieces
    (`_take_next` on `taken`); the *_s scratch arrays hold one block per worker: (chunks,
    >= _BLOCK), total_s (chunks, C, >= _BLOCK). own_odd is an int (0 or 1): see the note above on
    aliases. Shifted rows (pairs None): every tap along NeighborMax with a jitter constant per tile
    (the caller checked), read as shifted rows of the flat images (*_flat); per pixel (*_flat None):
    each pixel's tap read from `pairs`. As in the backward, the None picks the path when numba
    compiles, each into a kernel of its own."""
    batch, channels, height, width = color.shape
    stored = channels + 3
    plane = height * width
    jitter_batch = jitter.shape[0]
    inverse_extent = _real(1.0, extent) / extent
    image_rows = batch * height
    last_x = width - 1.0
    last_y = height - 1.0
    for chunk in numba.prange(chunks):  # one iteration per worker; chunk: its scratch
        while True:  # the rows order[...] in `pieces` pieces, taken in turn by whichever worker is free
            piece = _take_next(taken)
            if piece >= pieces:
                break
            for i in range(piece * image_rows // pieces, (piece + 1) * image_rows // pieces):
                    row = order[i]
                    b = row // height
                    y = row % height
                    jb = b if jitter_batch > 1 else 0
                    image_start = b * height * width * stored
                    start = 0
                    while start < width:
                        end = _block_end(counts, b, y // tile, start, width, tile, _BLOCK)
                        size = end - start
                        count = counts[b, y // tile, start // tile]
                        if count == 0:  # the early-out: the image
                            for c in range(channels):
                                for x in range(np.uint64(start), np.uint64(end)):  # vectorized: contiguous copies
                                    out[b, c, y, x] = color[b, c, y, x]
                            for x in range(np.uint64(start), np.uint64(end)):
                                weight[b, y, x] = 0.0
                            start = end
                            continue
                        _block_state(velocity, depth, neighbors, jitter, b, jb, y, start, end, tile, min_radius, chunk, jitter_s, nx_s, ny_s, speed_n_s, vx_s, vy_s, length_x_s, speed_x_s, inverse_x_s, z_x_s)
                        for p in range(size):
                            weight_s[chunk, p] = _real(1.0, weight_s) / speed_x_s[chunk, p]
                        for c in range(channels):
                            for p in range(size):  # vectorized
                                total_s[chunk, c, p] = weight_s[chunk, p] * color[b, c, y, np.uint64(start + p)]
                        middle = (count - 1) // 2
                        step = 2.0 / (count + 1.0)
                        for k in range(count):
                            if k == middle:
                                continue
                            if color_flat is not None:  # shifted rows (None per pixel, whose kernel compiles without this): one offset per tile segment
                                segment = start
                                while segment < end:
                                    segment_end = _segment_end(segment, start, end, tile, chunk, jitter_s, nx_s, ny_s)
                                    q = segment - start
                                    t = -1.0 + (k + jitter_s[chunk, q] + 1.0) * step
                                    shift_x = nx_s[chunk, q] * t
                                    py = y + ny_s[chunk, q] * t
                                    row0, row1, fy, _, shift, fx, first, last = _shifted_rows(py, shift_x, start, segment, segment_end, height, width, last_y)
                                    # The taps' arithmetic in the images' precision: float32 vectors hold twice the lanes.
                                    distance = _real(abs(t) * speed_n_s[chunk, q], color_flat)
                                    fx = _real(fx, color_flat)
                                    fy = _real(fy, color_flat)
                                    below = np.uint64((row1 - row0) * width)
                                    top = row0 * width + start + shift  # + u: pixel u's top-left read
                                    top_vx = np.uint64(2 * b * plane + top)
                                    top_vy = np.uint64((2 * b + 1) * plane + top)
                                    top_z = np.uint64(b * plane + top)
                                    if fy == 0.0:  # the tap lies on a row (every tap of a horizontal motion): one row read, the same values
                                        for u in range(np.uint64(first), np.uint64(last)):  # vectorized: contiguous reads
                                            v_yx = _on_row_read(velocity_flat, top_vx + u, fx)
                                            v_yy = _on_row_read(velocity_flat, top_vy + u, fx)
                                            z_y = _on_row_read(depth_flat, top_z + u, fx)
                                            _keep_tap_alpha(alpha_s, weight_s, chunk, u, z_x_s[chunk, u], z_y, v_yx, v_yy, distance, inverse_x_s[chunk, u], min_radius, extent, inverse_extent)
                                        for c in range(channels):
                                            top_c = np.uint64((b * channels + c) * plane + top)
                                            for u in range(np.uint64(first), np.uint64(last)):  # vectorized
                                                total_s[chunk, c, u] += alpha_s[chunk, u] * _on_row_read(color_flat, top_c + u, fx)
                                    else:
                                        for u in range(np.uint64(first), np.uint64(last)):  # vectorized: contiguous reads
                                            v_yx = _row_read(velocity_flat, top_vx + u, below, fx, fy)
                                            v_yy = _row_read(velocity_flat, top_vy + u, below, fx, fy)
                                            z_y = _row_read(depth_flat, top_z + u, below, fx, fy)
                                            _keep_tap_alpha(alpha_s, weight_s, chunk, u, z_x_s[chunk, u], z_y, v_yx, v_yy, distance, inverse_x_s[chunk, u], min_radius, extent, inverse_extent)
                                        for c in range(channels):
                                            top_c = np.uint64((b * channels + c) * plane + top)
                                            for u in range(np.uint64(first), np.uint64(last)):  # vectorized
                                                total_s[chunk, c, u] += alpha_s[chunk, u] * _row_read(color_flat, top_c + u, below, fx, fy)
                                    for side in range(2):  # the border: [q, first) clamped to column 0, [last, segment's end) to W - 1
                                        lo, hi, column = _border_run(side, q, first, last, segment_end - start, width)
                                        if hi <= lo:
                                            continue
                                        zero = _real(0.0, fy)  # fx: every tap of the run reads the one clamped point
                                        _, _, v_yx = _clamped_read_slopes(velocity_flat, 2 * b * plane, width, row0, row1, column, zero, fy)
                                        _, _, v_yy = _clamped_read_slopes(velocity_flat, (2 * b + 1) * plane, width, row0, row1, column, zero, fy)
                                        _, _, z_y = _clamped_read_slopes(depth_flat, b * plane, width, row0, row1, column, zero, fy)
                                        for u in range(np.uint64(lo), np.uint64(hi)):  # vectorized
                                            _keep_tap_alpha(alpha_s, weight_s, chunk, u, z_x_s[chunk, u], z_y, v_yx, v_yy, distance, inverse_x_s[chunk, u], min_radius, extent, inverse_extent)
                                        for c in range(channels):
                                            _, _, c_y = _clamped_read_slopes(color_flat, (b * channels + c) * plane, width, row0, row1, column, zero, fy)
                                            for u in range(np.uint64(lo), np.uint64(hi)):  # vectorized
                                                total_s[chunk, c, u] += alpha_s[chunk, u] * c_y
                                    segment = segment_end
                                continue
                            if pairs is not None:  # per pixel (pairs is None on shifted rows, whose kernel compiles without this)
                                own = own_odd * (k % 2)
                                for p in range(size):  # vectorized: no branches, gathers
                                    t = -1.0 + (k + jitter_s[chunk, p] + 1.0) * step
                                    dx = vx_s[chunk, p] if own != 0 else nx_s[chunk, p]
                                    dy = vy_s[chunk, p] if own != 0 else ny_s[chunk, p]
                                    speed = length_x_s[chunk, p] if own != 0 else speed_n_s[chunk, p]
                                    column, row0, fx, fy, _, _ = _tap_corner((start + p) + dx * t, y + dy * t, last_x, last_y)
                                    index = image_start + (row0 * width + column) * stored
                                    below_pair = width * stored if row0 < height - 1 else 0
                                    index_s[chunk, p] = index
                                    below_s[chunk, p] = below_pair
                                    fx_s[chunk, p] = fx
                                    fy_s[chunk, p] = fy
                                    v_yx = _pair_read(pairs, index + channels, below_pair, fx, fy)
                                    v_yy = _pair_read(pairs, index + channels + 1, below_pair, fx, fy)
                                    z_y = _pair_read(pairs, index + channels + 2, below_pair, fx, fy)
                                    alpha = _tap_alpha(z_x_s[chunk, p], z_y, v_yx, v_yy, abs(t) * speed, inverse_x_s[chunk, p], min_radius, extent, inverse_extent)
                                    alpha_s[chunk, p] = alpha
                                    weight_s[chunk, p] += alpha
                                for c in range(channels):
                                    for p in range(size):  # vectorized
                                        read = _pair_read(pairs, index_s[chunk, p] + c, below_s[chunk, p], fx_s[chunk, p], fy_s[chunk, p])
                                        total_s[chunk, c, p] += alpha_s[chunk, p] * read
                        for c in range(channels):
                            for p in range(size):  # vectorized
                                out[b, c, y, np.uint64(start + p)] = total_s[chunk, c, p] / weight_s[chunk, p]
                        for p in range(size):
                            weight[b, y, np.uint64(start + p)] = weight_s[chunk, p]
                        start = end



@_inline
def _add_own(grads, grads_rows, chunk, b, y, start, size, k, value_s, stored, plane, width):
    """Add value_s[chunk, k, p] to input channel k's gradient at the pixels (y, start + p) of image b,
    p < size: into the planar flat (B, stored, H, W) `grads_rows` on shifted rows (one contiguous
    vector add into the band's own row), into chunk `chunk`'s interleaved `grads` per pixel (where
    grads_rows is None, and numba compiles only that branch)."""
    if grads_rows is not None:
        at = np.uint64((b * stored + k) * plane + y * width + start)
        for p in range(np.uint64(size)):  # vectorized
            grads_rows[at + p] += value_s[chunk, k, p]
    else:
        for p in range(size):
            grads[chunk, b, y, np.uint64(start + p), k] += value_s[chunk, k, p]


@_inline
def _row_target(bands, chunk, reach, b, row, stored, plane, width, margins):
    """Where the gradients of row `row` of image b go in the shifted-row backward's flat buffer,
    for band `chunk`: the index of the row's first pixel in channel 0, and the stride between
    channels. A band's own rows are the output's (B, stored, H, W) at the buffer's start; the
    `reach` rows above and below it the band's own margins, (bands, stored, 2 reach, W) from index
    `margins` on, so that no two bands write one element and none needs a full-size buffer."""
    first_row = bands[chunk] - b * (plane // width)
    end_row = bands[chunk + 1] - b * (plane // width)
    band = margins + chunk * stored * 2 * reach * width
    above = row < first_row
    below = row >= end_row
    at = band + (row - first_row + reach) * width if above else (band + (reach + row - end_row) * width if below else b * stored * plane + row * width)
    return at, 2 * reach * width if above | below else plane


@_inline
def _add_row(target, at, row_weight, fx, value_s, chunk, k, first, last):
    """Add value_s[chunk, k, u] for u in [first, last), times row_weight, to the 2 pixels of one row
    that pixel u's tap read (flat indices at + u and at + u + 1, with their bilinear weights): pixel
    at + u takes the left share of value u and the right share of value u - 1, so that no two lanes
    of a vector add to one pixel and each pixel is loaded and stored once."""
    if last <= first:
        return
    one = np.uint64(1)
    left = row_weight * (_real(1.0, fx) - fx)
    right = row_weight * fx
    target[at + np.uint64(first)] += left * value_s[chunk, k, np.uint64(first)]
    for u in range(np.uint64(first) + one, np.uint64(last)):  # vectorized: contiguous adds
        target[at + u] += left * value_s[chunk, k, u] + right * value_s[chunk, k, u - one]
    target[at + np.uint64(last)] += right * value_s[chunk, k, np.uint64(last) - one]


@_inline
def _add_rows(grads_rows, top_at, bottom_at, fx, fy, value_s, chunk, k, first, last):
    """`_add_row` for both rows a tap reads, weighted 1 - fy and fy; only the top row where the tap
    lies on a row (fy = 0: every tap of a horizontal motion)."""
    _add_row(grads_rows, np.uint64(top_at), _real(1.0, fy) - fy, fx, value_s, chunk, k, first, last)
    if fy != 0.0:
        _add_row(grads_rows, np.uint64(bottom_at), fy, fx, value_s, chunk, k, first, last)


@_inline
def _scatter_rows(grads_rows, top_at, bottom_at, column0, column1, fx, fy, grad):
    """`_scatter_chunk` into two rows of the flat buffer, the top row's first pixel at index top_at,
    the bottom row's at bottom_at (`_row_target`'s)."""
    one = _real(1.0, fx)
    grads_rows[top_at + column0] += grad * (one - fx) * (one - fy)
    grads_rows[top_at + column1] += grad * fx * (one - fy)
    grads_rows[bottom_at + column0] += grad * (one - fx) * fy
    grads_rows[bottom_at + column1] += grad * fx * fy


@_inline
def _border_run_backward(
    color_flat, velocity_flat, depth_flat, color, b, chunk, lo, hi, column, row0, fy, inside_y, t, distance, min_radius, extent,
    g_total_s, g_out_s, z_x_s, speed_x_s, inverse_x_s, g_alpha_s, slope_y_s, alpha_s, g_speed_x_s, own_s, g_ny_s, g_speed_n_s,
):
    """The shifted rows' border pixels [lo, hi) of a segment, whose taps are clamped to one column
    (fx = 0: no gradient along x) and so read one point: its values read once, the classifiers'
    derivatives as vectors into the pixels' sums, each pixel's alpha into alpha_s (for the colours'
    scatter). Returns the sums of the V[Y] and Z[Y] gradients, which all go to that point. Fewer
    than 30 arguments: past that Python passes them as *args, which numba cannot inline."""
    _, channels, height, width = color.shape
    plane = height * width
    row1 = min(row0 + 1, height - 1)
    inverse_extent = _real(1.0, extent) / extent
    zero = _real(0.0, fy)
    for u in range(np.uint64(lo), np.uint64(hi)):
        g_alpha_s[chunk, u] = -g_out_s[chunk, u]
        slope_y_s[chunk, u] = zero
    for c in range(channels):
        _, d_y, c_y = _clamped_read_slopes(color_flat, (b * channels + c) * plane, width, row0, row1, column, zero, fy)
        for u in range(np.uint64(lo), np.uint64(hi)):  # vectorized
            g_total = g_total_s[chunk, c, u]
            g_alpha_s[chunk, u] += g_total * c_y
            slope_y_s[chunk, u] += g_total * d_y
    _, slope_vxy, v_yx = _clamped_read_slopes(velocity_flat, 2 * b * plane, width, row0, row1, column, zero, fy)
    _, slope_vyy, v_yy = _clamped_read_slopes(velocity_flat, (2 * b + 1) * plane, width, row0, row1, column, zero, fy)
    _, slope_zy, z_y = _clamped_read_slopes(depth_flat, b * plane, width, row0, row1, column, zero, fy)
    along = abs(t)
    g_vx_sum = zero
    g_vy_sum = zero
    g_z_sum = zero
    for u in range(np.uint64(lo), np.uint64(hi)):  # vectorized
        alpha, g_v_yx, g_v_yy, g_z_y, g_speed_x, g_z_x, g_distance = _tap_gradients(
            z_x_s[chunk, u], speed_x_s[chunk, u], inverse_x_s[chunk, u], distance, g_alpha_s[chunk, u], v_yx, v_yy, z_y, min_radius, extent, inverse_extent
        )
        g_fy = alpha * slope_y_s[chunk, u] + g_v_yx * slope_vxy + g_v_yy * slope_vyy + g_z_y * slope_zy
        alpha_s[chunk, u] = alpha
        g_speed_x_s[chunk, u] += g_speed_x
        own_s[chunk, channels + 2, u] += g_z_x
        g_ny_s[chunk, u] += g_fy * t * inside_y
        g_speed_n_s[chunk, u] += g_distance * along
        g_vx_sum += g_v_yx
        g_vy_sum += g_v_yy
        g_z_sum += g_z_y
    return g_vx_sum, g_vy_sum, g_z_sum


@_jit
def _reconstruct_backward(
    pairs, color_flat, velocity_flat, depth_flat, color, velocity, depth, neighbors, counts, jitter, tile, extent, min_radius, own_odd, order,
    scatter, bands, turns, workers, taken, reach, block, out, weight, grad_out, grads, grads_rows, margins, grad_neighbors,
    jitter_s, nx_s, ny_s, speed_n_s, vx_s, vy_s, length_x_s, speed_x_s, inverse_x_s, z_x_s, g_total_s, g_out_s,
    column_s, row_s, t_s, fx_s, fy_s, inside_x_s, inside_y_s, g_alpha_s, slope_x_s, slope_y_s, alpha_s, tap_grads_s,
    g_speed_x_s, g_length_x_s, g_nx_s, g_ny_s, g_speed_n_s, own_s,
):
    """The forward's layout (blocks of one row as vectors, scratch arguments) for the hand-written
    backward. scatter: (C + 3,) ints, 1 for each input channel whose gradient is asked for (the
    colours, V's two, Z); the others come out incomplete. The scatters loop over the channels (one
    copy of their code, not one per input: numba compiles every inlined copy). A chunk is the rows
    order[bands[chunk]:bands[chunk + 1]]; `workers` workers take them in the order `turns`, each the
    next one left when it is free (`_take_next` on `taken`). grad_neighbors:
    (chunks, B, 2, TH, TW) zeros, or (1, B, 2, TH, TW) for shifted rows (a band owns its tile rows);
    block: the most pixels of a row taken at once (`_BLOCK`; `_ROW_BLOCK` for shifted rows);
    *_s scratch: (chunks, >= block), g_total_s (chunks, C, >= block); tap_grads_s and own_s
    (chunks, C + 3, >= block), per input channel: the current tap's gradient w.r.t. the values it
    read, and the gradient w.r.t. the pixel's own values (the centre's colours, V[X], Z[X]).

    Per pixel (pairs given, grads_rows None): per tap index k one vector loop places the taps, one
    per channel reads the colours, one runs the classifiers' derivatives; then a scalar loop
    scatters the gradients of the 4 pixels each tap read (lanes may collide, so it cannot be a
    vector scatter) into grads, (chunks, B, H, W, C + 3) zeros, one buffer per chunk of rows (C, V,
    Z gradients interleaved). Shifted rows (pairs None, grads_rows given; *_flat): the same loops
    per run of tiles on contiguous reads, and the scatter as one contiguous vector pass per row read
    (`_add_row`) into grads_rows, a flat buffer that the kernel zeroes: the (B, C + 3, H, W) output,
    each band's own rows, then from index `margins` on the bands' margins, (chunks, C + 3, 2 reach,
    W) (`_row_target`). The None picks the path at compile time: numba drops the branches guarded by
    `is not None` on a None argument before typing, so each path compiles (and is cached) as a
    kernel of its own, and a call compiles only the path it takes (float32, cold cache: about 20 s
    per pixel, 38 s shifted rows, against 65 s for the two in one)."""
    _, channels, height, width = color.shape
    stored = channels + 3
    plane = height * width
    jitter_batch = jitter.shape[0]
    inverse_extent = _real(1.0, extent) / extent
    last_x = width - 1.0
    last_y = height - 1.0
    for _ in numba.prange(workers):  # one iteration per worker, each taking the chunks in turns' order (`_band_turns`) while any is left
        while True:
            turn = _take_next(taken)
            if turn >= turns.shape[0]:
                break
            chunk = turns[turn]
            slot = np.int64(chunk) % grad_neighbors.shape[0]  # shifted rows: one shared buffer, a band owns its tile rows
            if grads_rows is not None:  # shifted rows: a band's own rows of the output and its margins start at zero
                image = bands[chunk] // height
                for channel in range(stored):
                    own = (image * stored + channel) * plane + (bands[chunk] - image * height) * width
                    for index in range(np.uint64(own), np.uint64(own + (bands[chunk + 1] - bands[chunk]) * width)):  # unsigned: a memset, not a scatter
                        grads_rows[index] = 0.0
                for index in range(np.uint64(margins + chunk * stored * 2 * reach * width), np.uint64(margins + (chunk + 1) * stored * 2 * reach * width)):
                    grads_rows[index] = 0.0
            for i in range(bands[chunk], bands[chunk + 1]):
                row = order[i]
                b = row // height
                y = row % height
                jb = b if jitter_batch > 1 else 0
                image_start = b * height * width * stored
                start = 0
                while start < width:
                    end = _block_end(counts, b, y // tile, start, width, tile, block)
                    size = end - start
                    count = counts[b, y // tile, start // tile]
                    if count == 0:  # the early-out: out = C[X], the colour's gradient is the output's
                        for c in range(channels):
                            for p in range(size):  # vectorized
                                own_s[chunk, c, p] = grad_out[b, c, y, np.uint64(start + p)]
                            _add_own(grads, grads_rows, chunk, b, y, start, size, c, own_s, stored, plane, width)
                        start = end
                        continue
                    _block_state(velocity, depth, neighbors, jitter, b, jb, y, start, end, tile, min_radius, chunk, jitter_s, nx_s, ny_s, speed_n_s, vx_s, vy_s, length_x_s, speed_x_s, inverse_x_s, z_x_s)
                    # out = total / w: d total = g / w, d w = -sum(g out) / w; per tap alpha and
                    # alpha C[Y] both enter, so d alpha = sum(g C[Y]) / w - g_out, with g_out = sum(g
                    # out) / w the same for every tap. g_speed_x_s first sums g (C[X] - out), the
                    # centre's share.
                    for p in range(size):
                        g_speed_x_s[chunk, p] = 0.0
                        g_out_s[chunk, p] = 0.0
                    for c in range(channels):
                        for p in range(size):  # vectorized
                            x = start + p
                            ux = np.uint64(x)  # unsigned: see _block_state
                            g_total = grad_out[b, c, y, ux] / weight[b, y, ux]
                            g_total_s[chunk, c, p] = g_total
                            g_out_s[chunk, p] += g_total * out[b, c, y, ux]
                            g_speed_x_s[chunk, p] += g_total * (color[b, c, y, ux] - out[b, c, y, ux])
                            own_s[chunk, c, p] = g_total / speed_x_s[chunk, p]  # the centre's C[X] / speed
                        _add_own(grads, grads_rows, chunk, b, y, start, size, c, own_s, stored, plane, width)
                    for p in range(size):  # vectorized
                        speed_x = speed_x_s[chunk, p]
                        g_speed_x_s[chunk, p] = -g_speed_x_s[chunk, p] / (speed_x * speed_x)
                        own_s[chunk, channels, p] = 0.0
                        own_s[chunk, channels + 1, p] = 0.0
                        own_s[chunk, channels + 2, p] = 0.0
                        g_length_x_s[chunk, p] = 0.0
                        g_nx_s[chunk, p] = 0.0
                        g_ny_s[chunk, p] = 0.0
                        g_speed_n_s[chunk, p] = 0.0
                    middle = (count - 1) // 2
                    step = 2.0 / (count + 1.0)
                    for k in range(count):
                        if k == middle:
                            continue
                        if grads_rows is not None:  # shifted rows (None per pixel, whose kernel compiles without this): one offset per tile segment
                            segment = start
                            while segment < end:
                                segment_end = _segment_end(segment, start, end, tile, chunk, jitter_s, nx_s, ny_s)
                                q = segment - start
                                t = -1.0 + (k + jitter_s[chunk, q] + 1.0) * step
                                shift_x = nx_s[chunk, q] * t
                                py = y + ny_s[chunk, q] * t
                                row0, row1, fy, inside_y, shift, fx, first, last = _shifted_rows(py, shift_x, start, segment, segment_end, height, width, last_y)
                                distance = abs(t) * speed_n_s[chunk, q]
                                along = _real(abs(t), color_flat)
                                # The taps' arithmetic in the images' precision: float32 vectors hold twice the lanes.
                                distance_r = _real(distance, color_flat)
                                t_r = _real(t, color_flat)
                                inside_y_r = _real(inside_y, color_flat)
                                fx_r = _real(fx, color_flat)
                                fy_r = _real(fy, color_flat)
                                below = np.uint64((row1 - row0) * width)
                                top = row0 * width + start + shift  # + u: pixel u's top-left read
                                top_vx = np.uint64(2 * b * plane + top)
                                top_vy = np.uint64((2 * b + 1) * plane + top)
                                top_z = np.uint64(b * plane + top)
                                if channels == 3:  # the usual case: the three colours read in one loop, their sums in registers
                                    top_c = np.uint64(3 * b * plane + top)
                                    plane_u = np.uint64(plane)
                                    for u in range(np.uint64(first), np.uint64(last)):  # vectorized
                                        d_x0, d_y0, c_y0 = _row_read_slopes(color_flat, top_c + u, below, fx_r, fy_r)
                                        d_x1, d_y1, c_y1 = _row_read_slopes(color_flat, top_c + plane_u + u, below, fx_r, fy_r)
                                        d_x2, d_y2, c_y2 = _row_read_slopes(color_flat, top_c + plane_u + plane_u + u, below, fx_r, fy_r)
                                        g_0 = g_total_s[chunk, 0, u]
                                        g_1 = g_total_s[chunk, 1, u]
                                        g_2 = g_total_s[chunk, 2, u]
                                        g_alpha_s[chunk, u] = g_0 * c_y0 + g_1 * c_y1 + g_2 * c_y2 - g_out_s[chunk, u]
                                        slope_x_s[chunk, u] = g_0 * d_x0 + g_1 * d_x1 + g_2 * d_x2
                                        slope_y_s[chunk, u] = g_0 * d_y0 + g_1 * d_y1 + g_2 * d_y2
                                else:
                                    for u in range(np.uint64(first), np.uint64(last)):
                                        g_alpha_s[chunk, u] = -g_out_s[chunk, u]
                                        slope_x_s[chunk, u] = 0.0
                                        slope_y_s[chunk, u] = 0.0
                                    for c in range(channels):
                                        top_c = np.uint64((b * channels + c) * plane + top)
                                        for u in range(np.uint64(first), np.uint64(last)):  # vectorized: the colours read
                                            d_x, d_y, c_y = _row_read_slopes(color_flat, top_c + u, below, fx_r, fy_r)
                                            g_total = g_total_s[chunk, c, u]
                                            g_alpha_s[chunk, u] += g_total * c_y
                                            slope_x_s[chunk, u] += g_total * d_x  # times alpha below
                                            slope_y_s[chunk, u] += g_total * d_y
                                for u in range(np.uint64(first), np.uint64(last)):  # vectorized: the classifiers
                                    slope_vxx, slope_vxy, v_yx = _row_read_slopes(velocity_flat, top_vx + u, below, fx_r, fy_r)
                                    slope_vyx, slope_vyy, v_yy = _row_read_slopes(velocity_flat, top_vy + u, below, fx_r, fy_r)
                                    slope_zx, slope_zy, z_y = _row_read_slopes(depth_flat, top_z + u, below, fx_r, fy_r)
                                    alpha, g_v_yx, g_v_yy, g_z_y, g_speed_x, g_z_x, g_distance = _tap_gradients(
                                        z_x_s[chunk, u], speed_x_s[chunk, u], inverse_x_s[chunk, u], distance_r, g_alpha_s[chunk, u], v_yx, v_yy, z_y, min_radius, extent, inverse_extent
                                    )
                                    g_fx = alpha * slope_x_s[chunk, u] + g_v_yx * slope_vxx + g_v_yy * slope_vyx + g_z_y * slope_zx
                                    g_fy = alpha * slope_y_s[chunk, u] + g_v_yx * slope_vxy + g_v_yy * slope_vyy + g_z_y * slope_zy
                                    alpha_s[chunk, u] = alpha
                                    tap_grads_s[chunk, channels, u] = g_v_yx
                                    tap_grads_s[chunk, channels + 1, u] = g_v_yy
                                    tap_grads_s[chunk, channels + 2, u] = g_z_y
                                    g_speed_x_s[chunk, u] += g_speed_x
                                    own_s[chunk, channels + 2, u] += g_z_x
                                    g_nx_s[chunk, u] += g_fx * t_r  # an interior tap: its x is not clamped
                                    g_ny_s[chunk, u] += g_fy * t_r * inside_y_r
                                    g_speed_n_s[chunk, u] += g_distance * along
                                # the rows' first pixels in the gradient buffer (`_row_target`); + shifted + u: pixel u's read
                                top_at, top_stride = _row_target(bands, chunk, reach, b, row0, stored, plane, width, margins)
                                bottom_at, bottom_stride = _row_target(bands, chunk, reach, b, row1, stored, plane, width, margins)
                                shifted = start + shift
                                for channel in range(stored):
                                    if scatter[channel] == 0:
                                        continue
                                    if channel < channels:
                                        for u in range(np.uint64(first), np.uint64(last)):
                                            tap_grads_s[chunk, channel, u] = alpha_s[chunk, u] * g_total_s[chunk, channel, u]
                                    _add_rows(grads_rows, top_at + channel * top_stride + shifted, bottom_at + channel * bottom_stride + shifted, fx_r, fy_r, tap_grads_s, chunk, channel, first, last)
                                for side in range(2):  # the border: [q, first) clamped to column 0, [last, segment's end) to W - 1
                                    lo, hi, column = _border_run(side, q, first, last, segment_end - start, width)
                                    if hi <= lo:
                                        continue
                                    g_vx_sum, g_vy_sum, g_z_sum = _border_run_backward(
                                        color_flat, velocity_flat, depth_flat, color, b, chunk, lo, hi, column, row0, fy_r, inside_y_r, t_r, distance_r, min_radius, extent,
                                        g_total_s, g_out_s, z_x_s, speed_x_s, inverse_x_s, g_alpha_s, slope_y_s, alpha_s, g_speed_x_s, own_s, g_ny_s, g_speed_n_s,
                                    )
                                    # every tap of the run read the one point: its gradients go there, summed
                                    zero = _real(0.0, fy_r)
                                    for channel in range(stored):
                                        if scatter[channel] == 0:
                                            continue
                                        if channel < channels:
                                            summed = zero
                                            for u in range(np.uint64(lo), np.uint64(hi)):  # vectorized
                                                summed += alpha_s[chunk, u] * g_total_s[chunk, channel, u]
                                        else:
                                            summed = g_vx_sum if channel == channels else (g_vy_sum if channel == channels + 1 else g_z_sum)
                                        _scatter_rows(grads_rows, top_at + channel * top_stride, bottom_at + channel * bottom_stride, column, column, zero, fy_r, summed)
                                segment = segment_end
                            continue
                        if pairs is not None:  # per pixel (pairs is None on shifted rows, whose kernel compiles without this)
                            own = own_odd * (k % 2)
                            for p in range(size):  # vectorized: the taps' positions
                                t = -1.0 + (k + jitter_s[chunk, p] + 1.0) * step
                                px = (start + p) + (vx_s[chunk, p] if own != 0 else nx_s[chunk, p]) * t
                                py = y + (vy_s[chunk, p] if own != 0 else ny_s[chunk, p]) * t
                                column, row0, fx, fy, inside_x, inside_y = _tap_corner(px, py, last_x, last_y)
                                column_s[chunk, p] = column
                                row_s[chunk, p] = row0
                                t_s[chunk, p] = t
                                fx_s[chunk, p] = fx
                                fy_s[chunk, p] = fy
                                inside_x_s[chunk, p] = inside_x
                                inside_y_s[chunk, p] = inside_y
                                g_alpha_s[chunk, p] = -g_out_s[chunk, p]
                                slope_x_s[chunk, p] = 0.0
                                slope_y_s[chunk, p] = 0.0
                            for c in range(channels):
                                for p in range(size):  # vectorized: the colours read
                                    row0 = row_s[chunk, p]
                                    index = image_start + (row0 * width + column_s[chunk, p]) * stored + c
                                    below_pair = width * stored if row0 < height - 1 else 0
                                    d_x, d_y, c_y = _pair_read_slopes(pairs, index, below_pair, fx_s[chunk, p], fy_s[chunk, p])
                                    g_total = g_total_s[chunk, c, p]
                                    g_alpha_s[chunk, p] += g_total * c_y
                                    slope_x_s[chunk, p] += g_total * d_x  # times alpha below
                                    slope_y_s[chunk, p] += g_total * d_y
                            for p in range(size):  # vectorized: the classifiers and their derivatives
                                row0 = row_s[chunk, p]
                                index = image_start + (row0 * width + column_s[chunk, p]) * stored + channels
                                below_pair = width * stored if row0 < height - 1 else 0
                                fx = fx_s[chunk, p]
                                fy = fy_s[chunk, p]
                                t = t_s[chunk, p]
                                slope_vxx, slope_vxy, v_yx = _pair_read_slopes(pairs, index, below_pair, fx, fy)
                                slope_vyx, slope_vyy, v_yy = _pair_read_slopes(pairs, index + 1, below_pair, fx, fy)
                                slope_zx, slope_zy, z_y = _pair_read_slopes(pairs, index + 2, below_pair, fx, fy)
                                distance = abs(t) * (length_x_s[chunk, p] if own != 0 else speed_n_s[chunk, p])
                                alpha, g_v_yx, g_v_yy, g_z_y, g_speed_x, g_z_x, g_distance = _tap_gradients(
                                    z_x_s[chunk, p], speed_x_s[chunk, p], inverse_x_s[chunk, p], distance, g_alpha_s[chunk, p], v_yx, v_yy, z_y, min_radius, extent, inverse_extent
                                )
                                g_fx = alpha * slope_x_s[chunk, p] + g_v_yx * slope_vxx + g_v_yy * slope_vyx + g_z_y * slope_zx
                                g_fy = alpha * slope_y_s[chunk, p] + g_v_yx * slope_vxy + g_v_yy * slope_vyy + g_z_y * slope_zy
                                # The tap position X + direction t (no gradient where clamped) and the
                                # distance |t| speed; own (0 or 1) picks V[X] or NeighborMax.
                                g_dx = g_fx * t * inside_x_s[chunk, p]
                                g_dy = g_fy * t * inside_y_s[chunk, p]
                                g_along = g_distance * abs(t)
                                alpha_s[chunk, p] = alpha
                                tap_grads_s[chunk, channels, p] = g_v_yx
                                tap_grads_s[chunk, channels + 1, p] = g_v_yy
                                tap_grads_s[chunk, channels + 2, p] = g_z_y
                                g_speed_x_s[chunk, p] += g_speed_x
                                own_s[chunk, channels + 2, p] += g_z_x
                                own_s[chunk, channels, p] += g_dx * own
                                own_s[chunk, channels + 1, p] += g_dy * own
                                g_length_x_s[chunk, p] += g_along * own
                                g_nx_s[chunk, p] += g_dx * (1 - own)
                                g_ny_s[chunk, p] += g_dy * (1 - own)
                                g_speed_n_s[chunk, p] += g_along * (1 - own)
                            for p in range(size):  # scalar: the 4 pixels each tap read
                                row0 = row_s[chunk, p]
                                column = column_s[chunk, p]
                                row1 = min(row0 + 1, height - 1)
                                column1 = min(column + 1, width - 1)
                                fx = fx_s[chunk, p]
                                fy = fy_s[chunk, p]
                                alpha = alpha_s[chunk, p]
                                for channel in range(stored):
                                    if scatter[channel] == 0:
                                        continue
                                    value = alpha * g_total_s[chunk, channel, p] if channel < channels else tap_grads_s[chunk, channel, p]
                                    _scatter_chunk(grads, chunk, b, channel, row0, row1, column, column1, fx, fy, value)
                    for p in range(size):  # vectorized: each pixel's own V[X] and NeighborMax through their lengths
                        length_x = length_x_s[chunk, p]
                        zero = _real(0.0, length_x)
                        g_length_x = g_length_x_s[chunk, p] + (g_speed_x_s[chunk, p] if length_x >= min_radius else zero)
                        over_length = g_length_x / length_x if length_x > 0.0 else zero
                        own_s[chunk, channels, p] += over_length * vx_s[chunk, p]
                        own_s[chunk, channels + 1, p] += over_length * vy_s[chunk, p]
                        speed_n = speed_n_s[chunk, p]
                        over_speed = g_speed_n_s[chunk, p] / speed_n if speed_n > 0.0 else zero
                        g_nx_s[chunk, p] += over_speed * nx_s[chunk, p]
                        g_ny_s[chunk, p] += over_speed * ny_s[chunk, p]
                    for channel in range(channels, stored):  # V[X]'s and Z[X]'s
                        _add_own(grads, grads_rows, chunk, b, y, start, size, channel, own_s, stored, plane, width)
                    tile_y = y // tile
                    for tile_x in range(start // tile, (end - 1) // tile + 1):  # NeighborMax's: one sum per tile
                        g_nx = 0.0
                        g_ny = 0.0
                        for p in range(np.uint64(max(tile_x * tile, start) - start), np.uint64(min((tile_x + 1) * tile, end) - start)):  # vectorized: unsigned
                            g_nx += g_nx_s[chunk, p]
                            g_ny += g_ny_s[chunk, p]
                        grad_neighbors[slot, b, 0, tile_y, tile_x] += g_nx
                        grad_neighbors[slot, b, 1, tile_y, tile_x] += g_ny
                    start = end


@_jit
def _add_margins(grads, buffer, margins, bands, reach):
    """Add the shifted-row backward's band margins (the rows above and below each band that its
    taps read: flat (bands, stored, 2 reach, W) from index `margins` of `buffer` on) into grads
    (B, stored, H, W), which holds the bands' own rows; one image plane per iteration, so no two
    iterations add to one element."""
    batch, stored, height, width = grads.shape
    for plane in numba.prange(batch * stored):
        b = plane // stored
        k = plane % stored
        for chunk in range(bands.shape[0] - 1):
            if bands[chunk] // height != b:
                continue
            first_row = bands[chunk] - b * height
            end_row = bands[chunk + 1] - b * height
            at = (chunk * stored + k) * 2 * reach
            for m in range(2 * reach):
                y = first_row - reach + m if m < reach else end_row + m - reach
                if 0 <= y < height:
                    for x in range(width):
                        grads[b, k, y, x] += buffer[margins + (at + m) * width + x]


class ReconstructForwardScratch(NamedTuple):
    """`_reconstruct_forward`'s scratch (its *_s parameters, in order): each pixel's state, its running
    weight and colour total, and the current tap's read position and classifier."""

    jitter: Floats
    nx: Floats
    ny: Floats
    speed_n: Floats
    vx: Floats
    vy: Floats
    length_x: Floats
    speed_x: Floats
    inverse_x: Floats
    z_x: Floats
    weight: Floats
    total: ChannelFloats
    index: Ints
    below: Ints
    fx: Floats
    fy: Floats
    alpha: Floats


class ReconstructBackwardScratch(NamedTuple):
    """`_reconstruct_backward`'s scratch (its *_s parameters, in order): each pixel's state, the
    output's gradient over the weight and the output, the current tap's position, reads and
    classifier gradients, and the gradients accumulated for the pixel's own V[X], Z[X] and
    NeighborMax."""

    jitter: Floats
    nx: Floats
    ny: Floats
    speed_n: Floats
    vx: Floats
    vy: Floats
    length_x: Floats
    speed_x: Floats
    inverse_x: Floats
    z_x: Floats
    g_total: ChannelFloats
    g_out: Floats
    column: Ints
    row: Ints
    t: Floats
    fx: Floats
    fy: Floats
    inside_x: Floats
    inside_y: Floats
    g_alpha: Floats
    slope_x: Floats
    slope_y: Floats
    alpha: Floats
    tap_grads: GradientFloats
    g_speed_x: Floats
    g_length_x: Floats
    g_nx: Floats
    g_ny: Floats
    g_speed_n: Floats
    own: GradientFloats


check_scratch(_reconstruct_forward, ReconstructForwardScratch)
check_scratch(_reconstruct_backward, ReconstructBackwardScratch)


def shifted_rows(jitter: np.ndarray, tile: int, own_odd: bool) -> bool:
    """Whether the kernels read every tap as a shifted row: all taps along NeighborMax (not
    directions="neighbor_and_own") and the jitter (B or 1, 1, H, W) constant over each tile's part
    of a row (jitter="none" is), so that each tile takes tap k at one offset v_N t_k."""
    if own_odd:
        return False
    same = jitter[..., 1:] == jitter[..., :-1]
    same[..., tile - 1 :: tile] = True  # neighbours in different tiles may differ
    return bool(same.all())


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
    into: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The reconstruction filter, fused. color (B, C, H, W), velocity (B, 2, H, W), depth (B, 1, H,
    W), neighbors (B, 2, TH, TW) NeighborMax, counts (B, TH, TW) taps per tile (0: the image),
    jitter (B or 1, 1, H, W), all C-contiguous in one float dtype (counts int32). Returns the
    image and the per-pixel weight sum (B, H, W) that the backward needs, written into `into`'s
    two C-contiguous arrays when given (a caller's own buffers, e.g. XLA's), else new ones."""
    color, velocity, depth, neighbors, counts, jitter = read_only(color, velocity, depth, neighbors, counts, jitter)
    batch, channels, height, width = color.shape
    out, weight = into if into is not None else (np.empty_like(color), np.empty((batch, height, width), dtype=color.dtype))
    chunks = min(batch * height, _threads())
    rows = shifted_rows(jitter, tile, own_odd)
    real = color.dtype.type  # the kernels compute in the images' precision
    settings = (int(tile), real(soft_z_extent), real(min_radius), int(own_odd), row_order(batch * height), chunks, work_pieces(batch * height, chunks), work_counter())
    scratch = scratch_for(ReconstructForwardScratch, chunks, channels, color.dtype)
    # Which of pairs and the flat images is None picks the kernel's path (`_reconstruct_forward`).
    pairs = None if rows else _pairs(color, velocity, depth)
    flats = (color.reshape(-1), velocity.reshape(-1), depth.reshape(-1)) if rows else (None, None, None)
    _reconstruct_forward(pairs, *flats, color, velocity, depth, neighbors, counts, jitter, *settings, out, weight, *scratch)
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
    needs: tuple[bool, bool, bool] = (True, True, True),
    into: list[np.ndarray] | None = None,
) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """Gradients of `reconstruct_forward`'s image w.r.t. color, velocity, depth and neighbors,
    given the forward's out and weight and the output's gradient grad_out, each a C-contiguous
    array of its own. needs: whether color, velocity and depth want theirs; None for the others,
    whose scatter to the taps' pixels (most of the backward's time) is skipped. neighbors' comes
    with velocity's. into: the arrays to write the gradients asked for into, in that order (a
    caller's own buffers, e.g. XLA's); new ones when None."""
    buffers, grad_neighbors = _backward_chunks(color, velocity, depth, neighbors, counts, jitter, out, weight, grad_out, tile, soft_z_extent, min_radius, own_odd, needs)
    channels = color.shape[1]
    need_color, need_velocity, need_depth = (bool(need) for need in needs)
    targets = iter(into) if into is not None else None
    grads = []
    for need, first, count in ((need_color, 0, channels), (need_velocity, channels, 2), (need_depth, channels + 2, 1)):
        target = next(targets) if need and targets is not None else None
        grads.append(_summed(buffers, color, first, count, target) if need else None)
    if need_velocity and targets is not None:
        target = next(targets)
        np.copyto(target, grad_neighbors)
        grad_neighbors = target
    return (*grads, grad_neighbors if need_velocity else None)


def reconstruct_backward_stacked(
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
    needs: tuple[bool, bool, bool] = (True, True, True),
) -> tuple[np.ndarray, np.ndarray | None]:
    """`reconstruct_backward` with the gradients w.r.t. color, velocity and depth in one array
    (B, C + 3, H, W), stacked along the channels as the kernel writes them (the channels of one not
    asked for hold no meaning), and neighbors' gradient (None unless velocity's is asked for).
    The PyTorch operator returns this array whole and slices it, as an operator's outputs may not
    be views of one another."""
    buffers, grad_neighbors = _backward_chunks(color, velocity, depth, neighbors, counts, jitter, out, weight, grad_out, tile, soft_z_extent, min_radius, own_odd, needs)
    return _summed(buffers, color, 0, color.shape[1] + 3), grad_neighbors if needs[1] else None


#: The shifted-row backward's blocks, at most this many pixels of a row (the others' are _BLOCK): per
#: block and tap it places each tile segment, finds the rows its gradients go to and sets up a
#: dozen short vector loops, so fewer, longer blocks spend less beside the taps' arithmetic. Measured
#: at 1280x720, S=15, 2 threads (the kernel alone, in turns with 256, median of 31): 34.8 against
#: 36.8 ms on a pan, 47.0 against 53.5 at 30 degrees, 52.5 against 58.8 vertical; 384, 512, 768 and
#: 1024 were between the two (a row of 1280 then ends in a short block); the forward did not gain.
_ROW_BLOCK = 640

#: Bands per thread of the shifted-row backward, at least: several, so that the threads, taking them
#: one at a time, end together when the motion sits in one part of the image.
_BANDS_PER_THREAD = 4

#: The shifted-row backward's bands are at least this many times their reach high (`_bands`): their
#: margins, 2 reach rows, at most half their own rows. Measured at 720p (kernels alone, 2 threads,
#: 8 to 36 bands): the most bands of that height were the fastest count, or within the noise of
#: it, at 0, 30 and 90 degrees (on one thread the count made no difference).
_BAND_PER_REACH = 4

#: The shifted-row backward's work per tile in units of one tap, for `_band_turns`: a tile with taps
#: costs its count and two (count - 1 taps, about three taps' worth of per-pixel work around them), an
#: early-out tile one. Measured at 720p on one thread: 4.0 ms a tap, 11.9 ms with no tap (S = 1),
#: 3.7 ms with every tile early-out.
_TILE_COST_BESIDE_TAPS = 2.0
_EARLY_OUT_TILE_COST = 1.0


def _band_costs(bands: np.ndarray, counts: np.ndarray, height: int, tile: int) -> np.ndarray:
    """Each shifted-row band's work, estimated from the taps per tile (B, TH, TW) of its tile rows."""
    tile_costs = np.where(counts > 0, counts + _TILE_COST_BESIDE_TAPS, _EARLY_OUT_TILE_COST).sum(axis=2)  # (B, TH)
    row_costs = tile_costs[:, np.arange(height) // tile].reshape(-1)  # per row b * H + y
    before = np.concatenate(([0.0], np.cumsum(row_costs)))
    return before[bands[1:]] - before[bands[:-1]]


def _band_turns(bands: np.ndarray, counts: np.ndarray, height: int, tile: int) -> np.ndarray:
    """The order the shifted-row backward's workers take its bands in: the most work first
    (`_band_costs`), each worker the next band left when it is free, so that the last bands, the
    ones a worker may wait for, are the smallest. 720p's 36 tile rows in 8 bands of 4 and 5 (long
    vertical motion) go 18 and 18 to 2 threads of one speed; every other band would give 16 and 20."""
    return np.argsort(-_band_costs(bands, counts, height, tile), kind="stable").astype(np.int64)


def _bands(neighbors: np.ndarray, height: int, tile: int, threads: int) -> tuple[np.ndarray, int]:
    """The shifted-row backward's bands, as the flat (b * H + y) row where each starts (and the
    end): runs of whole tile rows of one image, so that a band owns its tiles' NeighborMax
    gradients; and their reach, the rows beyond a band that its taps read (|NeighborMax_y| and one
    for the bilinear read). As many bands as keep each at least `_BAND_PER_REACH` times its reach
    high, and at least `_BANDS_PER_THREAD` per thread: the threads take them one at a time, so
    smaller bands let them end closer together, but each band also zeroes and adds the 2 reach rows
    of its margins."""
    batch, _, tiles_y, _ = neighbors.shape
    largest = float(np.abs(neighbors[:, 1]).max()) if neighbors.size else 0.0
    reach = min(int(math.ceil(largest)) + 2, height)
    fitting = tiles_y // -(-_BAND_PER_REACH * reach // tile)  # bands of whole tile rows at least that high
    per_image = max(1, min(tiles_y, max(fitting, -(-_BANDS_PER_THREAD * threads // batch))))
    tile_rows = np.minimum(np.arange(per_image + 1) * tiles_y // per_image * tile, height)
    starts = (np.arange(batch)[:, None] * height + tile_rows[None, :-1]).reshape(-1)
    bands = np.append(starts, batch * height).astype(np.int64)
    return bands, reach


def _backward_chunks(color, velocity, depth, neighbors, counts, jitter, out, weight, grad_out, tile, soft_z_extent, min_radius, own_odd, needs):
    """Run `_reconstruct_backward`: its gradient buffers (for `_summed`) and NeighborMax's
    gradient (B, 2, TH, TW). Shifted rows: one (B, C + 3, H, W) buffer, each band's own rows
    written in place, the rows its taps read beyond them added after; per pixel: one interleaved
    buffer per thread, summed by `_summed`."""
    color, velocity, depth, neighbors, counts, jitter, out, weight, grad_out = read_only(color, velocity, depth, neighbors, counts, jitter, out, weight, grad_out)
    batch, channels, height, width = color.shape
    rows = shifted_rows(jitter, tile, own_odd)
    stored = channels + 3
    threads = _threads()
    if rows:
        bands, reach = _bands(neighbors, height, tile, threads)
        chunks = len(bands) - 1
        grads = np.zeros((chunks, 0, 0, 0, stored), dtype=color.dtype)
        margins = batch * stored * height * width  # the margins' first index in the buffer
        buffer = np.empty(margins + chunks * stored * 2 * reach * width, dtype=color.dtype)  # zeroed by the kernel, band by band
        grad_neighbors = np.zeros((1, *neighbors.shape), dtype=color.dtype)
        order = np.arange(batch * height, dtype=np.int64)
    else:
        chunks = min(threads, batch * height)
        bands, reach = np.arange(chunks + 1, dtype=np.int64) * (batch * height) // chunks, 0
        grads = np.zeros((chunks, batch, height, width, stored), dtype=color.dtype)
        buffer, margins = None, 0
        grad_neighbors = np.zeros((chunks, *neighbors.shape), dtype=color.dtype)
        order = row_order(batch * height)
    need_color, need_velocity, need_depth = (bool(need) for need in needs)
    scatter = np.array([need_color] * channels + [need_velocity] * 2 + [need_depth], dtype=np.int64)  # per stored channel
    real = color.dtype.type  # the kernels compute in the images' precision
    turns = _band_turns(bands, counts, height, tile) if rows else np.arange(chunks, dtype=np.int64)  # per pixel: a chunk per thread
    block = _ROW_BLOCK if rows else _BLOCK
    settings = (int(tile), real(soft_z_extent), real(min_radius), int(own_odd), order, scatter, bands, turns, min(threads, chunks), work_counter(), reach, block)
    scratch = scratch_for(ReconstructBackwardScratch, chunks, channels, color.dtype, block)
    pairs = None if rows else _pairs(color, velocity, depth)  # which of pairs and buffer is None picks the kernel's path
    arrays = (pairs, color.reshape(-1), velocity.reshape(-1), depth.reshape(-1), color, velocity, depth, neighbors, counts, jitter)
    _reconstruct_backward(*arrays, *settings, out, weight, grad_out, grads, buffer, margins, grad_neighbors, *scratch)
    grads_rows = buffer[:margins].reshape(batch, stored, height, width) if rows else None
    if rows:
        _add_margins(grads_rows, buffer, margins, bands, reach)
    return (grads, grads_rows, rows), grad_neighbors.sum(axis=0)


def _summed(buffers, color: np.ndarray, first: int, count: int, into: np.ndarray | None = None) -> np.ndarray:
    """Channels [first, first + count) of `_backward_chunks`' buffers (B, count, H, W): the shifted
    rows' buffer's own channels (a view, or copied into `into`), or the per-thread buffers summed
    (into `into` or a new array)."""
    grads, grads_rows, rows = buffers
    if rows:
        channels = grads_rows[:, first : first + count]
        if into is None:
            return np.ascontiguousarray(channels)
        np.copyto(into, channels)
        return into
    total = into if into is not None else np.empty((color.shape[0], count, *color.shape[2:]), dtype=color.dtype)
    _deinterleave_sum(grads, total, first)
    return total
