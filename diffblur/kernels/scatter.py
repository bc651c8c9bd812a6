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

Measured (scripts/measure_fused_scatter.py, 1280x720 float32, 16 points, 2 cores): the forward
kernel ~150 ms, the backward ~340 ms; a point costs ~20 ns forward on one core, most of it the 16
read-modify-writes of its 4 cells.
"""

from __future__ import annotations

import math

import numpy as np

from diffblur.ops.scatter import point_times
from diffblur.kernels.shared import _inline, _jit, _length, _soft_depth_compare, _threads, numba, read_only, row_order

__all__ = ["ARC_CHANNELS", "BEZIER_CHANNELS", "splat_backward", "splat_forward", "splat_unfused_reason"]

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
    faster than any C)."""
    batch, channels, height, width = color.shape
    padded = np.zeros((batch, -(-channels // GROUP) * GROUP, height, width), dtype=color.dtype)
    padded[:, :channels] = color
    return [(start, np.ascontiguousarray(padded[:, start : start + GROUP])) for start in range(0, padded.shape[1], GROUP)]


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
            _pad_channels_last(grad_group_sums, grad_cells)
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
