"""Fused CPU kernels (numba) for the splats of `bezier_scatter`, behind the backends' custom gradients.

The tensor ops splat every point of every moving pixel's curve with ~40 full-resolution ops and
one scatter-add per chunk of points (seconds at 1280x720 on 2 cores); the backward transposes that
scatter-add. These kernels sum the splats in one parallel loop over source pixels, and their
hand-written backward in a second one (with the numba set-up of `diffblur.kernels.shared`). Only
the accumulation is fused: the power-basis terms of the Bezier, the shutter's masses, the `moving`
mask, the normalisation and the fill stay tensor ops, so autograd carries the kernels' gradients
w.r.t. the terms and the masses back to the offsets and the shutter's parameters exactly as on the
pure path.

A source pixel's point k at time t_k (`diffblur.ops.scatter.point_times`) sits at p(t_k) on its path and
splats omega = bilinear * soft_depth_compare(destination depth, source depth, extent) * weight, with
weight = m_k (times 2 |p'(t_k)| for normalization="paper"), to the 4 pixels around it on the image
padded by a one-pixel ring, adding omega [color, 1]. The kernels repeat the tensor ops' arithmetic
(the same floors, `where` branches and soft-depth band, so the same one-sided derivatives) in
float64 scalars, reading and writing the arrays' dtype.

Splats land anywhere: each chunk of source rows (one per thread) sums into its own buffer of the
padded image's cells, channels last, and the chunks are summed (the backward: its own padded depth
gradient, whose ring then folds onto the border it repeats); memory O(pixels x threads), never
O(pixels x points). The kernels take the colour three channels at a time (`GROUP`), which keeps it
in registers; C = 3 runs once, other counts in ceil(C / 3) runs.

composite="instants" has its own pair (`instant_forward`, `instant_backward`): per instant, each
padded cell's nearest source depth among the splats weighing more than NEAREST_SPLAT_WEIGHT (a
min per chunk of rows, then over the chunks), then the sums of omega [color, 1, log depth] and
weight [color, 1]; the backward shares each cell's nearest-depth gradient evenly among the splats
that set it, as the frameworks' scatter-min does. The instants' composite stays tensor ops.

Measured (scripts/measure_fused_scatter.py, 1280x720 float32, 16 points, 2 cores): the forward
kernel ~150 ms, the backward ~340 ms; a point costs ~20 ns forward on one core, most of it the 16
read-modify-writes of its 4 cells. The instants' kernels: ~80 ms forward and ~130 ms backward per
instant at 1280x720 (one call per instant there).
"""

from __future__ import annotations

import math

import numpy as np

from diffblur.ops.scatter import NEAREST_SPLAT_WEIGHT, point_times
from diffblur.kernels.shared import _inline, _jit, _length, _soft_depth_compare, _threads, numba, read_only, row_order

__all__ = ["ARC_CHANNELS", "BEZIER_CHANNELS", "instant_backward", "instant_forward", "splat_backward", "splat_forward", "splat_unfused_reason"]

#: The kernels' path array (B, P, H, W): a Bezier's power-basis terms (constant, linear, quadratic,
#: cubic; x and y each, zeros for a term the degree lacks), or an arc's centre (x, y) and angle.
BEZIER_CHANNELS = 8
ARC_CHANNELS = 3
#: Colour channels per kernel run: an image of C channels runs ceil(C / 3) times (C = 3: once).
GROUP = 3


def splat_unfused_reason(dtype_name: str) -> str | None:
    """Why bezier_scatter's splats of an image of this dtype (a string) cannot take the fused path,
    or None when they can (the backends add device and tracing checks)."""
    if numba is None:
        return "numba is not installed"
    if dtype_name not in ("float32", "float64"):
        return f"dtype {dtype_name} (the fused kernel takes float32 and float64)"
    return None


@_inline
def _terms_at(path, arc, b, y, x):
    """Pixel (x, y)'s path channels as float64 scalars (the arc's 3, then zeros)."""
    if arc:
        return (np.float64(path[b, 0, y, x]), np.float64(path[b, 1, y, x]), np.float64(path[b, 2, y, x]), 0.0, 0.0, 0.0, 0.0, 0.0)
    return (
        np.float64(path[b, 0, y, x]),
        np.float64(path[b, 1, y, x]),
        np.float64(path[b, 2, y, x]),
        np.float64(path[b, 3, y, x]),
        np.float64(path[b, 4, y, x]),
        np.float64(path[b, 5, y, x]),
        np.float64(path[b, 6, y, x]),
        np.float64(path[b, 7, y, x]),
    )


@_inline
def _position(terms, arc, x, y, t):
    """p(t) and p'(t) of pixel (x, y)'s path (`terms` from `_terms_at`), in the tensor ops' order of
    operations (`_point`)."""
    if arc:
        cx, cy, angle = terms[0], terms[1], terms[2]
        rx = x - cx
        ry = y - cy
        cos = math.cos(angle * t)
        sin = math.sin(angle * t)
        px = cx + cos * rx - sin * ry
        py = cy + sin * rx + cos * ry
        return px, py, -angle * (py - cy), angle * (px - cx)
    constant_x, constant_y, linear_x, linear_y, quadratic_x, quadratic_y, cubic_x, cubic_y = terms
    tt = t * t
    ttt = tt * t
    px = x + (((linear_x * t + quadratic_x * tt) + cubic_x * ttt) + constant_x)
    py = y + (((linear_y * t + quadratic_y * tt) + cubic_y * ttt) + constant_y)
    vx = (linear_x + quadratic_x * (2.0 * t)) + cubic_x * (3.0 * t * t)
    vy = (linear_y + quadratic_y * (2.0 * t)) + cubic_y * (3.0 * t * t)
    return px, py, vx, vy


@_inline
def _position_grad(terms, arc, x, y, t, px, py, g_px, g_py, g_vx, g_vy):
    """The gradient w.r.t. the path's channels at (x, y) (as `_terms_at`), given those of p(t), p'(t)."""
    if arc:
        cx, cy, angle = terms[0], terms[1], terms[2]
        rx = x - cx
        ry = y - cy
        cos = math.cos(angle * t)
        sin = math.sin(angle * t)
        # p' = angle R90 (p - c), written as the tensor ops do with p, c and the angle.
        g_angle = g_vy * (px - cx) - g_vx * (py - cy)
        g_px = g_px + g_vy * angle
        g_py = g_py - g_vx * angle
        g_cx = g_px - g_vy * angle
        g_cy = g_py + g_vx * angle
        g_cos = g_px * rx + g_py * ry
        g_sin = g_py * rx - g_px * ry
        g_rx = g_px * cos + g_py * sin
        g_ry = g_py * cos - g_px * sin
        g_angle += (cos * g_sin - sin * g_cos) * t
        return (g_cx - g_rx, g_cy - g_ry, g_angle, 0.0, 0.0, 0.0, 0.0, 0.0)
    tt = t * t
    return (
        g_px,
        g_py,
        g_px * t + g_vx,
        g_py * t + g_vy,
        g_px * tt + g_vx * (2.0 * t),
        g_py * tt + g_vy * (2.0 * t),
        g_px * (tt * t) + g_vx * (3.0 * tt),
        g_py * (tt * t) + g_vy * (3.0 * tt),
    )


@_inline
def _add8(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3], a[4] + b[4], a[5] + b[5], a[6] + b[6], a[7] + b[7])


@_inline
def _anchor(px, py, width, height):
    """The point's top-left corner on the padded image and its fractions, or near=False where no
    corner is in the image (`_splat`'s `near`: those points weigh nothing)."""
    x0 = math.floor(px)
    y0 = math.floor(py)
    near = x0 >= -1.0 and x0 <= width - 1.0 and y0 >= -1.0 and y0 <= height - 1.0
    if not near:
        return False, 0, 0, 0.0, 0.0
    return True, int(y0) + 1, int(x0) + 1, px - x0, py - y0


@_jit
def _pad_depth(depth, padded):
    """padded (B, H + 2, W + 2): depth (B, 1, H, W) with its border repeated (`F.pad` "replicate")."""
    batch, _, height, width = depth.shape
    for row in numba.prange(batch * (height + 2)):
        b = row // (height + 2)
        y = min(max(row % (height + 2) - 1, 0), height - 1)
        for column in range(width + 2):
            padded[b, row % (height + 2), column] = depth[b, 0, y, min(max(column - 1, 0), width - 1)]


@_inline
def _deposit(cells, cell, omega, rgb):
    """cells[cell] += omega [rgb, 1]."""
    cells[cell, 0] += omega * rgb[0]
    cells[cell, 1] += omega * rgb[1]
    cells[cell, 2] += omega * rgb[2]
    cells[cell, 3] += omega


@_jit
def _splat_forward(color, padded_depth, path, masses, times, extent, moving, arc, paper, order, sums):
    """color: (B, 3, H, W) (a group of `GROUP` channels); sums: (chunks, B (H + 2) (W + 2), 4) zeros,
    one per chunk of source rows: the padded image's cells, channels last."""
    chunks = sums.shape[0]
    batch, _, height, width = color.shape
    stride = width + 2
    count = masses.shape[0]
    inverse_extent = 1.0 / extent
    rows = batch * height
    for chunk in numba.prange(chunks):
        cells = sums[chunk]
        for i in range(chunk * rows // chunks, (chunk + 1) * rows // chunks):
            row = order[i]
            b = row // height
            y = row % height
            for x in range(width):
                if not moving[b, y, x]:
                    continue
                z_source = np.float64(padded_depth[b, y + 1, x + 1])
                rgb = (np.float64(color[b, 0, y, x]), np.float64(color[b, 1, y, x]), np.float64(color[b, 2, y, x]))
                terms = _terms_at(path, arc, b, y, x)
                for k in range(count):
                    px, py, vx, vy = _position(terms, arc, x, y, times[k])
                    near, top, left, fx, fy = _anchor(px, py, width, height)
                    if not near:
                        continue
                    weight = np.float64(masses[k])
                    if paper:  # per pixel of path length
                        weight = weight * (2.0 * _length(vx, vy))
                    gx = 1.0 - fx
                    gy = 1.0 - fy
                    cell = (b * (height + 2) + top) * stride + left
                    front = _soft_depth_compare(np.float64(padded_depth[b, top, left]), z_source, extent, inverse_extent)
                    _deposit(cells, cell, gx * gy * front * weight, rgb)
                    front = _soft_depth_compare(np.float64(padded_depth[b, top, left + 1]), z_source, extent, inverse_extent)
                    _deposit(cells, cell + 1, fx * gy * front * weight, rgb)
                    front = _soft_depth_compare(np.float64(padded_depth[b, top + 1, left]), z_source, extent, inverse_extent)
                    _deposit(cells, cell + stride, gx * fy * front * weight, rgb)
                    front = _soft_depth_compare(np.float64(padded_depth[b, top + 1, left + 1]), z_source, extent, inverse_extent)
                    _deposit(cells, cell + stride + 1, fx * fy * front * weight, rgb)


@_jit
def _crop_sum(sums, out):
    """out (B, K, H, W) = the image's cells of the (chunks, B (H + 2) (W + 2), K) buffers, summed."""
    chunks = sums.shape[0]
    batch, channels, height, width = out.shape
    for row in numba.prange(batch * height):
        b = row // height
        y = row % height
        first = (b * (height + 2) + y + 1) * (width + 2) + 1
        for x in range(width):
            for c in range(channels):
                total = 0.0
                for chunk in range(chunks):
                    total += sums[chunk, first + x, c]
                out[b, c, y, x] = total


@_jit
def _pad_channels_last(grad, padded):
    """padded (B (H + 2) (W + 2), K) zeros gets grad (B, K, H, W) in the image's cells: the ring's
    splats are cropped, so their gradient is 0."""
    batch, channels, height, width = grad.shape
    for row in numba.prange(batch * height):
        b = row // height
        y = row % height
        first = (b * (height + 2) + y + 1) * (width + 2) + 1
        for x in range(width):
            for c in range(channels):
                padded[first + x, c] = grad[b, c, y, x]


@_jit
def _fold_depth(grads, out):
    """out (B, 1, H, W) = the (chunks, B, H + 2, W + 2) padded-depth gradients summed, the ring
    onto the border pixels it repeats (the transpose of `_pad_depth`)."""
    chunks = grads.shape[0]
    batch, _, height, width = out.shape
    for row in numba.prange(batch * height):
        b = row // height
        y = row % height
        first_row = 0 if y == 0 else y + 1
        last_row = height + 1 if y == height - 1 else y + 1
        for x in range(width):
            first_column = 0 if x == 0 else x + 1
            last_column = width + 1 if x == width - 1 else x + 1
            total = 0.0
            for chunk in range(chunks):
                for r in range(first_row, last_row + 1):
                    for q in range(first_column, last_column + 1):
                        total += grads[chunk, b, r, q]
            out[b, 0, y, x] = total


@_inline
def _corner_backward(grad_cells, cell, z_destination, z_source, extent, inverse_extent, bilinear, weight, rgb):
    """One corner's splat omega = bilinear * front * weight, backwards: d/d bilinear, d/d weight,
    d/d z_source (= -d/d z_destination), d/d extent and d/d rgb of <cells' gradient, omega [rgb, 1]>."""
    front = _soft_depth_compare(z_destination, z_source, extent, inverse_extent)
    omega = bilinear * front * weight
    g_red = np.float64(grad_cells[cell, 0])
    g_green = np.float64(grad_cells[cell, 1])
    g_blue = np.float64(grad_cells[cell, 2])
    g_omega = np.float64(grad_cells[cell, 3]) + g_red * rgb[0] + g_green * rgb[1] + g_blue * rgb[2]
    g_front = g_omega * bilinear * weight
    behind = z_source - z_destination
    g_z_source = 0.0
    g_extent = 0.0
    if behind >= 0.0 and behind <= extent:  # the ramp 1 - behind / extent
        g_z_source = -g_front * inverse_extent
        g_extent = g_front * behind * inverse_extent * inverse_extent
    return g_omega * front * weight, g_omega * bilinear * front, g_z_source, g_extent, omega * g_red, omega * g_green, omega * g_blue


@_jit
def _splat_backward(
    color, padded_depth, path, masses, times, extent, moving, arc, paper, order, grad_cells, grad_color, grad_path, grad_depth, grad_masses, grad_extent
):
    """color: (B, 3, H, W); grad_cells: (B (H + 2) (W + 2), 4), the padded image's cells, 0 on the
    ring. Each source pixel writes its own grad_color (B, 3, H, W) and grad_path (B, P, H, W); the
    per-chunk zeros grad_depth (chunks, B, H + 2, W + 2) (the padded depth's), grad_masses (chunks, K)
    and grad_extent (chunks,) collect what lands elsewhere."""
    chunks = grad_depth.shape[0]
    batch, _, height, width = color.shape
    stride = width + 2
    path_channels = path.shape[1]  # 3 or 8 (`_terms_at`)
    count = masses.shape[0]
    inverse_extent = 1.0 / extent
    rows = batch * height
    for chunk in numba.prange(chunks):
        depth_grads = grad_depth[chunk]
        g_extent = 0.0
        # Accumulated in the thread's own memory: written per sample, grad_masses' rows lie side by side.
        g_masses = np.zeros(count)
        for i in range(chunk * rows // chunks, (chunk + 1) * rows // chunks):
            row = order[i]
            b = row // height
            y = row % height
            for x in range(width):
                g_red = 0.0
                g_green = 0.0
                g_blue = 0.0
                g_path = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
                if moving[b, y, x]:
                    z_source = np.float64(padded_depth[b, y + 1, x + 1])
                    g_z_source = 0.0
                    rgb = (np.float64(color[b, 0, y, x]), np.float64(color[b, 1, y, x]), np.float64(color[b, 2, y, x]))
                    terms = _terms_at(path, arc, b, y, x)
                    for k in range(count):
                        t = times[k]
                        px, py, vx, vy = _position(terms, arc, x, y, t)
                        near, top, left, fx, fy = _anchor(px, py, width, height)
                        if not near:
                            continue
                        mass = np.float64(masses[k])
                        speed = _length(vx, vy) if paper else 0.0
                        weight = mass * (2.0 * speed) if paper else mass
                        gx = 1.0 - fx
                        gy = 1.0 - fy
                        cell = (b * (height + 2) + top) * stride + left
                        z = np.float64(padded_depth[b, top, left])
                        g00, g_weight, g_z, g_e, d_red, d_green, d_blue = _corner_backward(
                            grad_cells, cell, z, z_source, extent, inverse_extent, gx * gy, weight, rgb
                        )
                        depth_grads[b, top, left] -= g_z
                        g_z_source += g_z
                        g_extent += g_e
                        g_red += d_red
                        g_green += d_green
                        g_blue += d_blue
                        z = np.float64(padded_depth[b, top, left + 1])
                        g01, g_w, g_z, g_e, d_red, d_green, d_blue = _corner_backward(
                            grad_cells, cell + 1, z, z_source, extent, inverse_extent, fx * gy, weight, rgb
                        )
                        depth_grads[b, top, left + 1] -= g_z
                        g_weight += g_w
                        g_z_source += g_z
                        g_extent += g_e
                        g_red += d_red
                        g_green += d_green
                        g_blue += d_blue
                        z = np.float64(padded_depth[b, top + 1, left])
                        g10, g_w, g_z, g_e, d_red, d_green, d_blue = _corner_backward(
                            grad_cells, cell + stride, z, z_source, extent, inverse_extent, gx * fy, weight, rgb
                        )
                        depth_grads[b, top + 1, left] -= g_z
                        g_weight += g_w
                        g_z_source += g_z
                        g_extent += g_e
                        g_red += d_red
                        g_green += d_green
                        g_blue += d_blue
                        z = np.float64(padded_depth[b, top + 1, left + 1])
                        g11, g_w, g_z, g_e, d_red, d_green, d_blue = _corner_backward(
                            grad_cells, cell + stride + 1, z, z_source, extent, inverse_extent, fx * fy, weight, rgb
                        )
                        depth_grads[b, top + 1, left + 1] -= g_z
                        g_weight += g_w
                        g_z_source += g_z
                        g_extent += g_e
                        g_red += d_red
                        g_green += d_green
                        g_blue += d_blue
                        # The bilinear weights' fractions f = p - floor(p); the floor passes no gradient.
                        g_fx = (g01 - g00) * gy + (g11 - g10) * fy
                        g_fy = (g10 - g00) * gx + (g11 - g01) * fx
                        g_vx = 0.0
                        g_vy = 0.0
                        if paper:
                            g_masses[k] += g_weight * (2.0 * speed)
                            if speed > 0.0:  # the safe norm: no gradient at 0
                                g_speed = g_weight * mass * 2.0
                                g_vx = g_speed * vx / speed
                                g_vy = g_speed * vy / speed
                        else:
                            g_masses[k] += g_weight
                        g_path = _add8(g_path, _position_grad(terms, arc, x, y, t, px, py, g_fx, g_fy, g_vx, g_vy))
                    depth_grads[b, y + 1, x + 1] += g_z_source
                grad_color[b, 0, y, x] = g_red
                grad_color[b, 1, y, x] = g_green
                grad_color[b, 2, y, x] = g_blue
                for p in range(path_channels):
                    grad_path[b, p, y, x] = g_path[p]
        grad_extent[chunk] += g_extent
        grad_masses[chunk] += g_masses


def _settings(color: np.ndarray, depth: np.ndarray, masses: np.ndarray, extent: np.ndarray) -> tuple:
    """The replicate-padded depth, the point times (float64, as `point_times`), the extent as a
    float and the row order."""
    batch, _, height, width = color.shape
    padded_depth = np.empty((batch, height + 2, width + 2), dtype=depth.dtype)
    _pad_depth(depth, padded_depth)
    return padded_depth, np.asarray(point_times(masses.shape[0])), float(np.asarray(extent)), row_order(batch * height)


def _groups(color: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """color (B, C, H, W) as (first channel, (B, GROUP, H, W) group) pairs, the last group padded with
    zero channels: the kernels take a fixed GROUP, which keeps a source's colour in registers (~20 %
    faster than any C). Read-only, as `read_only` makes the kernels' inputs: a writable group would
    compile every splat kernel a second time (a type of its own to numba)."""
    batch, channels, height, width = color.shape
    padded = np.zeros((batch, -(-channels // GROUP) * GROUP, height, width), dtype=color.dtype)
    padded[:, :channels] = color
    return [(start, read_only(np.ascontiguousarray(padded[:, start : start + GROUP]))[0]) for start in range(0, padded.shape[1], GROUP)]


def splat_forward(
    color: np.ndarray,
    depth: np.ndarray,
    path: np.ndarray,
    masses: np.ndarray,
    extent: np.ndarray,
    moving: np.ndarray,
    *,
    arc: bool,
    paper: bool,
) -> np.ndarray:
    """The splats' sums (B, C + 1, H, W) of omega * [color, 1], cropped to the image.

    color (B, C, H, W), depth (B, 1, H, W), path (B, P, H, W) (see BEZIER_CHANNELS), masses (K,),
    extent (0-d, already floored as `_soft_depth_compare` does), all C-contiguous in one float dtype;
    moving (B, H, W) bool, the pixels that splat."""
    color, depth, path, masses, extent, moving = read_only(color, depth, path, masses, extent, moving)
    batch, channels, height, width = color.shape
    padded_depth, times, extent_value, order = _settings(color, depth, masses, extent)
    chunks = min(_threads(), batch * height)
    sums = np.empty((chunks, batch * (height + 2) * (width + 2), GROUP + 1), dtype=color.dtype)
    if channels == GROUP:
        out = np.empty((batch, GROUP + 1, height, width), dtype=color.dtype)
        sums[...] = 0.0
        _splat_forward(color, padded_depth, path, masses, times, extent_value, moving, bool(arc), bool(paper), order, sums)
        _crop_sum(sums, out)
        return out
    out = np.empty((batch, channels + 1, height, width), dtype=color.dtype)
    summed = np.empty((batch, GROUP + 1, height, width), dtype=color.dtype)
    for start, group in _groups(color):
        sums[...] = 0.0
        _splat_forward(group, padded_depth, path, masses, times, extent_value, moving, bool(arc), bool(paper), order, sums)
        _crop_sum(sums, summed)
        stop = min(start + GROUP, channels)
        out[:, start:stop] = summed[:, : stop - start]
    out[:, channels] = summed[:, GROUP]
    return out


def splat_backward(
    color: np.ndarray,
    depth: np.ndarray,
    path: np.ndarray,
    masses: np.ndarray,
    extent: np.ndarray,
    moving: np.ndarray,
    grad_sums: np.ndarray,
    *,
    arc: bool,
    paper: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Gradients of `splat_forward`'s sums w.r.t. color, depth, path, masses and extent (0-d), given
    the sums' gradient grad_sums (B, C + 1, H, W)."""
    color, depth, path, masses, extent, moving, grad_sums = read_only(color, depth, path, masses, extent, moving, grad_sums)
    batch, channels, height, width = color.shape
    padded_depth, times, extent_value, order = _settings(color, depth, masses, extent)
    chunks = min(_threads(), batch * height)
    grad_color = np.empty_like(color)
    grad_path = np.empty_like(path)
    grad_padded_depth = np.zeros((chunks, *padded_depth.shape), dtype=color.dtype)
    grad_masses = np.zeros((chunks, masses.shape[0]), dtype=np.float64)
    grad_extent = np.zeros(chunks, dtype=np.float64)
    grad_cells = np.zeros((batch * (height + 2) * (width + 2), GROUP + 1), dtype=color.dtype)
    settings = (padded_depth, path, masses, times, extent_value, moving, bool(arc), bool(paper), order, grad_cells)
    if channels == GROUP:
        _pad_channels_last(grad_sums, grad_cells)
        _splat_backward(color, *settings, grad_color, grad_path, grad_padded_depth, grad_masses, grad_extent)
    else:
        grad_group = np.empty((batch, GROUP, height, width), dtype=color.dtype)
        group_path = np.empty_like(path)
        for start, group in _groups(color):
            stop = min(start + GROUP, channels)
            # The group's colour sums, and the weight sums' gradient in the first group only: each
            # group's splats carry the weights, which the forward counted once.
            grad_group_sums = np.zeros((batch, GROUP + 1, height, width), dtype=color.dtype)
            grad_group_sums[:, : stop - start] = grad_sums[:, start:stop]
            if start == 0:
                grad_group_sums[:, GROUP] = grad_sums[:, channels]
            _pad_channels_last(read_only(grad_group_sums)[0], grad_cells)
            _splat_backward(group, *settings, grad_group, group_path, grad_padded_depth, grad_masses, grad_extent)
            grad_color[:, start:stop] = grad_group[:, : stop - start]
            if start == 0:
                grad_path[...] = group_path
            else:
                grad_path += group_path
    grad_depth = np.empty_like(depth)
    _fold_depth(grad_padded_depth, grad_depth)
    dtype = color.dtype
    return grad_color, grad_depth, grad_path, grad_masses.sum(axis=0).astype(dtype), np.asarray(grad_extent.sum(), dtype=dtype)


# -- composite="instants": each instant's nearest layer and its splats ------------------------------

#: The nearest-depth buffers start here, which counts as +inf (nothing lies so far): the kernels
#: are compiled with fastmath, which assumes no infinities.
_FAR = 1e300


@_inline
def _instant_corner(j, top, left, fx, fy):
    """Corner j (0: top-left, 1: top-right, 2: bottom-left, 3: bottom-right, `_padded_corners`'
    order) of a point: its padded row and column, its x and y factors of the bilinear weight and
    their signs in fx and fy."""
    right = j % 2
    down = j // 2
    wx = fx if right else 1.0 - fx
    wy = fy if down else 1.0 - fy
    return top + down, left + right, wx, wy, 1.0 if right else -1.0, 1.0 if down else -1.0


@_inline
def _instant_weight(padded_depth, still, b, r, q, z_source, wx, wy, extent, inverse_extent):
    """A splat's bilinear weight, times the depth test against the destination where it is still (it
    is then the layer behind): (weight, bilinear, the test or 1)."""
    bilinear = wx * wy
    test = 1.0
    if still[b, r, q]:
        test = _soft_depth_compare(np.float64(padded_depth[b, r, q]), z_source, extent, inverse_extent)
    return bilinear * test, bilinear, test


@_jit
def _instant_nearest(padded_depth, still, path, times, extent, moving, arc, order, nearest):
    """nearest (chunks, K B (H + 2) (W + 2)) at _FAR: per chunk of source rows, each padded cell's
    smallest source depth among the splats weighing more than NEAREST_SPLAT_WEIGHT at each instant."""
    chunks = nearest.shape[0]
    batch, height, width = moving.shape
    stride = width + 2
    plane = (height + 2) * stride
    inverse_extent = 1.0 / extent
    rows = batch * height
    for chunk in numba.prange(chunks):
        cells = nearest[chunk]
        for i in range(chunk * rows // chunks, (chunk + 1) * rows // chunks):
            row = order[i]
            b = row // height
            y = row % height
            for x in range(width):
                if not moving[b, y, x]:
                    continue
                z_source = np.float64(padded_depth[b, y + 1, x + 1])
                terms = _terms_at(path, arc, b, y, x)
                for k in range(times.shape[0]):
                    px, py, _, _ = _position(terms, arc, x, y, np.float64(times[k]))
                    near, top, left, fx, fy = _anchor(px, py, width, height)
                    if not near:
                        continue
                    first = (k * batch + b) * plane
                    for j in range(4):
                        r, q, wx, wy, _, _ = _instant_corner(j, top, left, fx, fy)
                        weight, _, _ = _instant_weight(padded_depth, still, b, r, q, z_source, wx, wy, extent, inverse_extent)
                        cell = first + r * stride + q
                        if weight > NEAREST_SPLAT_WEIGHT and z_source < cells[cell]:
                            cells[cell] = z_source


@_jit
def _min_over_chunks(nearest):
    """nearest[0] = the smallest of nearest (chunks, N) over its chunks."""
    chunks, size = nearest.shape
    for cell in numba.prange(size):
        smallest = nearest[0, cell]
        for chunk in range(1, chunks):
            smallest = min(smallest, nearest[chunk, cell])
        nearest[0, cell] = smallest


@_jit
def _instant_splat(color, log_depth, padded_depth, still, path, times, extent, moving, arc, order, nearest, sums):
    """sums (chunks, K B (H + 2) (W + 2), 2 C + 3) zeros: per chunk of source rows, each padded
    cell's omega [color, 1, log depth] (omega = weight x the depth test against the cell's nearest
    depth, `nearest` (K B (H + 2) (W + 2),)) and weight [color, 1] at each instant."""
    chunks = sums.shape[0]
    batch, channels, height, width = color.shape
    stride = width + 2
    plane = (height + 2) * stride
    inverse_extent = 1.0 / extent
    rows = batch * height
    for chunk in numba.prange(chunks):
        cells = sums[chunk]
        for i in range(chunk * rows // chunks, (chunk + 1) * rows // chunks):
            row = order[i]
            b = row // height
            y = row % height
            for x in range(width):
                if not moving[b, y, x]:
                    continue
                z_source = np.float64(padded_depth[b, y + 1, x + 1])
                log_source = np.float64(log_depth[b, 0, y, x])
                terms = _terms_at(path, arc, b, y, x)
                for k in range(times.shape[0]):
                    px, py, _, _ = _position(terms, arc, x, y, np.float64(times[k]))
                    near, top, left, fx, fy = _anchor(px, py, width, height)
                    if not near:
                        continue
                    first = (k * batch + b) * plane
                    for j in range(4):
                        r, q, wx, wy, _, _ = _instant_corner(j, top, left, fx, fy)
                        weight, _, _ = _instant_weight(padded_depth, still, b, r, q, z_source, wx, wy, extent, inverse_extent)
                        cell = first + r * stride + q
                        omega = weight * _soft_depth_compare(nearest[cell], z_source, extent, inverse_extent)
                        for c in range(channels):
                            value = np.float64(color[b, c, y, x])
                            cells[cell, c] += omega * value
                            cells[cell, channels + 2 + c] += weight * value
                        cells[cell, channels] += omega
                        cells[cell, channels + 1] += omega * log_source
                        cells[cell, 2 * channels + 2] += weight


@_jit
def _crop_instants(sums, out):
    """out (K, B, V, H, W) = the image's cells of the (chunks, K B (H + 2) (W + 2), V) buffers, summed."""
    chunks = sums.shape[0]
    count, batch, channels, height, width = out.shape
    for row in numba.prange(count * batch * height):
        image = row // height
        y = row % height
        first = (image * (height + 2) + y + 1) * (width + 2) + 1
        for x in range(width):
            for c in range(channels):
                total = 0.0
                for chunk in range(chunks):
                    total += sums[chunk, first + x, c]
                out[image // batch, image % batch, c, y, x] = total


@_jit
def _instant_backward(
    color, log_depth, padded_depth, still, path, times, extent, moving, arc, order, nearest, grad_cells,
    grad_color, grad_log, grad_path, grad_depth, grad_nearest, ties, grad_extent,
):  # fmt: skip
    """The transpose of `_instant_splat` given the cells' gradient grad_cells (K B (H + 2) (W + 2),
    V), 0 on the ring. Each source pixel writes its own grad_color (B, C, H, W), grad_log (B, 1, H,
    W) and grad_path (B, P, H, W); the per-chunk zeros grad_depth (chunks, B, H + 2, W + 2) (the
    padded depth's: the source's and the still destinations'), grad_nearest and ties (chunks, K B
    (H + 2) (W + 2): the gradient w.r.t. each cell's nearest depth and how many splats set it) and
    grad_extent (chunks,) collect what lands elsewhere."""
    chunks = grad_depth.shape[0]
    batch, channels, height, width = color.shape
    stride = width + 2
    plane = (height + 2) * stride
    path_channels = path.shape[1]
    inverse_extent = 1.0 / extent
    rows = batch * height
    for chunk in numba.prange(chunks):
        depth_grads = grad_depth[chunk]
        nearest_grads = grad_nearest[chunk]
        tie_counts = ties[chunk]
        g_extent = 0.0
        for i in range(chunk * rows // chunks, (chunk + 1) * rows // chunks):
            row = order[i]
            b = row // height
            y = row % height
            for x in range(width):
                for c in range(channels):
                    grad_color[b, c, y, x] = 0.0
                g_log = 0.0
                g_path = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
                if moving[b, y, x]:
                    z_source = np.float64(padded_depth[b, y + 1, x + 1])
                    log_source = np.float64(log_depth[b, 0, y, x])
                    g_z_source = 0.0
                    terms = _terms_at(path, arc, b, y, x)
                    for k in range(times.shape[0]):
                        t = np.float64(times[k])
                        px, py, _, _ = _position(terms, arc, x, y, t)
                        near, top, left, fx, fy = _anchor(px, py, width, height)
                        if not near:
                            continue
                        first = (k * batch + b) * plane
                        g_fx = 0.0
                        g_fy = 0.0
                        for j in range(4):
                            r, q, wx, wy, sx, sy = _instant_corner(j, top, left, fx, fy)
                            weight, bilinear, test = _instant_weight(padded_depth, still, b, r, q, z_source, wx, wy, extent, inverse_extent)
                            cell = first + r * stride + q
                            z_nearest = nearest[cell]
                            front = _soft_depth_compare(z_nearest, z_source, extent, inverse_extent)
                            omega = weight * front
                            g_omega = np.float64(grad_cells[cell, channels]) + np.float64(grad_cells[cell, channels + 1]) * log_source
                            g_weight = np.float64(grad_cells[cell, 2 * channels + 2])
                            for c in range(channels):
                                value = np.float64(color[b, c, y, x])
                                g_value = np.float64(grad_cells[cell, c])
                                g_shown = np.float64(grad_cells[cell, channels + 2 + c])
                                g_omega += g_value * value
                                g_weight += g_shown * value
                                grad_color[b, c, y, x] += omega * g_value + weight * g_shown
                            g_log += omega * np.float64(grad_cells[cell, channels + 1])
                            g_weight += g_omega * front
                            g_front = g_omega * weight
                            behind = z_source - z_nearest
                            if behind >= 0.0 and behind <= extent:  # the ramp 1 - behind / extent
                                g_z_source -= g_front * inverse_extent
                                nearest_grads[cell] += g_front * inverse_extent
                                g_extent += g_front * behind * inverse_extent * inverse_extent
                            if weight > NEAREST_SPLAT_WEIGHT and z_source == z_nearest:
                                tie_counts[cell] += 1.0
                            if still[b, r, q]:
                                g_test = g_weight * bilinear
                                behind = z_source - np.float64(padded_depth[b, r, q])
                                if behind >= 0.0 and behind <= extent:
                                    g_z_source -= g_test * inverse_extent
                                    depth_grads[b, r, q] += g_test * inverse_extent
                                    g_extent += g_test * behind * inverse_extent * inverse_extent
                            g_bilinear = g_weight * test
                            g_fx += g_bilinear * (sx * wy)
                            g_fy += g_bilinear * (wx * sy)
                        # The fractions f = p - floor(p); the floor passes no gradient.
                        g_path = _add8(g_path, _position_grad(terms, arc, x, y, t, px, py, g_fx, g_fy, 0.0, 0.0))
                    depth_grads[b, y + 1, x + 1] += g_z_source
                grad_log[b, 0, y, x] = g_log
                for p in range(path_channels):
                    grad_path[b, p, y, x] = g_path[p]
        grad_extent[chunk] += g_extent


@_jit
def _sum_over_chunks(buffers):
    """buffers[0] = the sum of buffers (chunks, N) over its chunks."""
    chunks, size = buffers.shape
    for cell in numba.prange(size):
        total = buffers[0, cell]
        for chunk in range(1, chunks):
            total += buffers[chunk, cell]
        buffers[0, cell] = total


@_jit
def _nearest_backward(padded_depth, still, path, times, extent, moving, arc, order, nearest, grad_nearest, ties, grad_depth):
    """Each cell's nearest-depth gradient (grad_nearest, ties: (K B (H + 2) (W + 2),)) shared evenly
    among the splats whose source depth set it (as the frameworks' scatter-min), into the per-chunk
    padded depth gradients grad_depth (chunks, B, H + 2, W + 2) at the sources."""
    chunks = grad_depth.shape[0]
    batch, height, width = moving.shape
    stride = width + 2
    plane = (height + 2) * stride
    inverse_extent = 1.0 / extent
    rows = batch * height
    for chunk in numba.prange(chunks):
        depth_grads = grad_depth[chunk]
        for i in range(chunk * rows // chunks, (chunk + 1) * rows // chunks):
            row = order[i]
            b = row // height
            y = row % height
            for x in range(width):
                if not moving[b, y, x]:
                    continue
                z_source = np.float64(padded_depth[b, y + 1, x + 1])
                terms = _terms_at(path, arc, b, y, x)
                g_z_source = 0.0
                for k in range(times.shape[0]):
                    px, py, _, _ = _position(terms, arc, x, y, np.float64(times[k]))
                    near, top, left, fx, fy = _anchor(px, py, width, height)
                    if not near:
                        continue
                    first = (k * batch + b) * plane
                    for j in range(4):
                        r, q, wx, wy, _, _ = _instant_corner(j, top, left, fx, fy)
                        cell = first + r * stride + q
                        if z_source != nearest[cell] or grad_nearest[cell] == 0.0:
                            continue
                        weight, _, _ = _instant_weight(padded_depth, still, b, r, q, z_source, wx, wy, extent, inverse_extent)
                        if weight > NEAREST_SPLAT_WEIGHT:
                            g_z_source += grad_nearest[cell] / ties[cell]
                depth_grads[b, y + 1, x + 1] += g_z_source


def _instant_settings(depth: np.ndarray, moving: np.ndarray, times: np.ndarray, extent: np.ndarray) -> tuple:
    """The replicate-padded depth and still mask, the times as float64, the extent as a float, the
    row order and the chunk count."""
    batch, _, height, width = depth.shape
    padded_depth = np.empty((batch, height + 2, width + 2), dtype=depth.dtype)
    _pad_depth(depth, padded_depth)
    still = np.pad(np.logical_not(moving), ((0, 0), (1, 1), (1, 1)), mode="edge")
    chunks = min(_threads(), batch * height)
    return padded_depth, still, np.asarray(times, dtype=np.float64), float(np.asarray(extent)), row_order(batch * height), chunks


def _instant_nearest_depths(padded_depth, still, path, times, extent, moving, arc, order, chunks) -> np.ndarray:
    nearest = np.full((chunks, times.shape[0] * moving.shape[0] * (moving.shape[1] + 2) * (moving.shape[2] + 2)), _FAR)
    _instant_nearest(padded_depth, still, path, times, extent, moving, arc, order, nearest)
    _min_over_chunks(nearest)
    return nearest[0]


def instant_forward(
    color: np.ndarray, log_depth: np.ndarray, depth: np.ndarray, path: np.ndarray, times: np.ndarray, extent: np.ndarray, moving: np.ndarray, *, arc: bool
) -> np.ndarray:
    """composite="instants"'s sums at each instant (K, B, 2 C + 3, H, W), cropped to the image: omega
    [color, 1, log depth] of each cell's nearest layer and weight [color, 1] of every splat
    (`diffblur.ops.scatter._instant_sums`).

    color (B, C, H, W), log_depth and depth (B, 1, H, W) (the depth the band compares, and the log
    depth the uncovered fill weighs: the same array under a relative band), path (B, P, H, W) (see
    BEZIER_CHANNELS), times (K,), extent (0-d, already floored), all C-contiguous in one float
    dtype; moving (B, H, W) bool, the pixels that splat."""
    color, log_depth, depth, path, times, extent, moving = read_only(color, log_depth, depth, path, times, extent, moving)
    batch, channels, height, width = color.shape
    padded_depth, still, times64, extent_value, order, chunks = _instant_settings(depth, moving, times, extent)
    settings = (padded_depth, still, path, times64, extent_value, moving, bool(arc), order)
    nearest = _instant_nearest_depths(*settings, chunks)
    count = times64.shape[0]
    sums = np.zeros((chunks, count * batch * (height + 2) * (width + 2), 2 * channels + 3), dtype=color.dtype)
    _instant_splat(color, log_depth, *settings, nearest, sums)
    out = np.empty((count, batch, 2 * channels + 3, height, width), dtype=color.dtype)
    _crop_instants(sums, out)
    return out


def instant_backward(
    color: np.ndarray,
    log_depth: np.ndarray,
    depth: np.ndarray,
    path: np.ndarray,
    times: np.ndarray,
    extent: np.ndarray,
    moving: np.ndarray,
    grad_sums: np.ndarray,
    *,
    arc: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Gradients of `instant_forward`'s sums w.r.t. color, log_depth, depth, path and extent (0-d),
    given the sums' gradient grad_sums (K, B, 2 C + 3, H, W)."""
    color, log_depth, depth, path, times, extent, moving, grad_sums = read_only(color, log_depth, depth, path, times, extent, moving, grad_sums)
    batch, channels, height, width = color.shape
    padded_depth, still, times64, extent_value, order, chunks = _instant_settings(depth, moving, times, extent)
    settings = (padded_depth, still, path, times64, extent_value, moving, bool(arc), order)
    nearest = _instant_nearest_depths(*settings, chunks)
    count = times64.shape[0]
    grad_cells = np.zeros((count * batch, height + 2, width + 2, 2 * channels + 3), dtype=color.dtype)
    grad_cells[:, 1:-1, 1:-1] = grad_sums.reshape(count * batch, 2 * channels + 3, height, width).transpose(0, 2, 3, 1)
    grad_cells = grad_cells.reshape(-1, 2 * channels + 3)
    grad_color = np.empty_like(color)
    grad_log = np.empty_like(log_depth)
    grad_path = np.empty_like(path)
    grad_padded_depth = np.zeros((chunks, *padded_depth.shape), dtype=color.dtype)
    grad_nearest = np.zeros((chunks, nearest.shape[0]))
    ties = np.zeros((chunks, nearest.shape[0]))
    grad_extent = np.zeros(chunks)
    _instant_backward(color, log_depth, *settings, nearest, grad_cells, grad_color, grad_log, grad_path, grad_padded_depth, grad_nearest, ties, grad_extent)
    _sum_over_chunks(grad_nearest)
    _sum_over_chunks(ties)
    _nearest_backward(*settings, nearest, grad_nearest[0], ties[0], grad_padded_depth)
    grad_depth = np.empty_like(depth)
    _fold_depth(grad_padded_depth, grad_depth)
    return grad_color, grad_log, grad_depth, grad_path, np.asarray(grad_extent.sum(), dtype=color.dtype)
