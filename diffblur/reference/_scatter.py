"""NumPy reference of the Bezier scatter of seed 003 (Guertin & Nowrouzezahrai 2015): the oracle.

Written for clarity: one loop over the moving pixels, one over the points of each curve, one over the
four pixels a point splats onto. The curves are written in Bezier form with their control points, as
the paper does (the backends use the power basis in t, an independent formulation).
"""

from __future__ import annotations

import math

import numpy as np

from diffblur import checks
from diffblur.ops.scatter import (
    DEFAULT_BACKGROUND_WEIGHT,
    DEFAULT_COMPOSITE,
    DEFAULT_FILL,
    DEFAULT_MAX_SAMPLES,
    DEFAULT_NORMALIZATION,
    DEFAULT_SHUTTER,
    DEFAULT_RELATIVE_Z_EXTENT,
    MID_PREV_TIME,
    NEAREST_SPLAT_WEIGHT,
    UNCOVERED_DEPTH_POWER,
    ScatterOptions,
    length_times,
    point_count,
    point_masses,
    point_times,
    resolve_path,
    warn_without_still,
)
from diffblur.conventions import DEPTH_CHANNELS, STILL_SPEED
from diffblur.shutters import ShutterWindow

__all__ = ["bezier_control_points", "bezier_scatter", "still_fill"]


def _bernstein(degree: int, s: float) -> list[float]:
    return [math.comb(degree, i) * (1.0 - s) ** (degree - i) * s**i for i in range(degree + 1)]


def bezier_control_points(positions: list[np.ndarray], degree: int) -> list[np.ndarray]:
    """Control points B_0..B_degree of the Bezier curve B(s), s = (t + 1) / 2, through given positions.

    positions: degree 1: [p(-1), p(1)]; degree 2: [p(-1), p(0), p(1)]; degree 3: [p(-1), p(-1/2), p(0),
    p(1)] (each a 2-vector). Degree 2 uses the corrected control point of seed 003 sec. 3.2 (see the
    ERRATA): B1 = 2 p(0) - (p(-1) + p(1)) / 2, so that B(1/2) = p(0).
    """
    if degree == 1:
        return [positions[0], positions[1]]
    if degree == 2:
        p_prev, p_mid, p_next = positions
        return [p_prev, 2.0 * p_mid - 0.5 * (p_prev + p_next), p_next]
    # Cubic: B0 = p(-1), B3 = p(1); B1 and B2 from B(s1) = p(-1/2) and B(1/2) = p(0).
    p_prev, p_quarter, p_mid, p_next = positions
    s1 = 0.5 * (MID_PREV_TIME + 1.0)
    rows, rhs = [], []
    for s, p in ((s1, p_quarter), (0.5, p_mid)):
        b = _bernstein(3, s)
        rows.append([b[1], b[2]])
        rhs.append(p - b[0] * p_prev - b[3] * p_next)
    inner = np.linalg.solve(np.array(rows), np.array(rhs))
    return [p_prev, inner[0], inner[1], p_next]


def _bezier_point(control: list[np.ndarray], s: float) -> np.ndarray:
    """B(s) = sum_i C(n, i) (1 - s)^(n - i) s^i B_i (seed 003 eq. 1, with its (1 - s)^2 erratum fixed)."""
    degree = len(control) - 1
    return sum(w * b for w, b in zip(_bernstein(degree, s), control))


def _bezier_speed(control: list[np.ndarray], s: float) -> float:
    """|dB/dt| = |dB/ds| / 2, dB/ds = n sum_i b_{n-1,i}(s) (B_{i+1} - B_i)."""
    degree = len(control) - 1
    weights = _bernstein(degree - 1, s)
    derivative = degree * sum(w * (control[i + 1] - control[i]) for i, w in enumerate(weights))
    return 0.5 * math.hypot(derivative[0], derivative[1])


def _arc_point(center: np.ndarray, angle: float, x: np.ndarray, t: float) -> np.ndarray:
    cos, sin = math.cos(angle * t), math.sin(angle * t)
    r = x - center
    return center + np.array([cos * r[0] - sin * r[1], sin * r[0] + cos * r[1]])


def _bilinear_splat(x: float, y: float, height: int, width: int) -> list[tuple[int, int, float]]:
    """The pixels (row, column) a point at (x, y) lands on, with their bilinear weights; pixels outside
    the image are dropped (what leaves the frame is lost)."""
    x0, y0 = math.floor(x), math.floor(y)
    fx, fy = x - x0, y - y0
    corners = [(y0, x0, (1 - fx) * (1 - fy)), (y0, x0 + 1, fx * (1 - fy)), (y0 + 1, x0, (1 - fx) * fy), (y0 + 1, x0 + 1, fx * fy)]
    return [(r, c, w) for r, c, w in corners if 0 <= r < height and 0 <= c < width]


def _inside(x: float, y: float, height: int, width: int) -> bool:
    """Whether (x, y) lies within the image's pixels (half a pixel around the border centres)."""
    return -0.5 <= x <= width - 0.5 and -0.5 <= y <= height - 0.5


def _soft_in_front(z_destination: float, z_source: float, extent: float) -> float:
    """Seed 000's softDepthCompare(z_a = destination, z_b = source) for positive depth."""
    return min(max(1.0 - (z_source - z_destination) / extent, 0.0), 1.0)


def _upsampled(coarse: np.ndarray, height: int, width: int) -> np.ndarray:
    """Bilinear upsampling by 2 of a (C, h, w) image to (C, height, width): fine pixel i sits at
    coarse coordinate (i + 1/2) / 2 - 1/2, between coarse pixels i // 2 and its neighbour on the side
    of i (3/4 and 1/4), the border repeated."""
    channels, h, w = coarse.shape
    out = np.zeros((channels, height, width), dtype=coarse.dtype)
    for i in range(height):
        for j in range(width):
            value = 0.0
            for r, wr in ((i // 2, 0.75), (min(max(i // 2 + (1 if i % 2 else -1), 0), h - 1), 0.25)):
                for c, wc in ((j // 2, 0.75), (min(max(j // 2 + (1 if j % 2 else -1), 0), w - 1), 0.25)):
                    value = value + wr * wc * coarse[:, r, c]
            out[:, i, j] = value
    return out


def still_fill(color: np.ndarray, still: np.ndarray) -> np.ndarray:
    """fill="still": the colour behind each pixel estimated from the still pixels by push-pull.

    color (B, C, H, W); still (B, 1, H, W) of 0 and 1. Pull: level 0 holds (still * color, still);
    each next level sums 2 x 2 blocks of the previous one (an odd side padded with weight 0), down to
    one pixel. Push: the one pixel's mean, then at each finer level, per pixel with summed weight w,
    min(w, 1) * its mean + (1 - min(w, 1)) * the coarser estimate upsampled bilinearly. An image
    without still pixels keeps its colour."""
    out = np.empty_like(color)
    for b in range(color.shape[0]):
        levels = [(color[b] * still[b], still[b])]
        while max(levels[-1][1].shape[1:]) > 1:
            total, weight = levels[-1]
            _, h, w = weight.shape
            coarse_total = np.zeros((total.shape[0], (h + 1) // 2, (w + 1) // 2), dtype=color.dtype)
            coarse_weight = np.zeros((1, (h + 1) // 2, (w + 1) // 2), dtype=color.dtype)
            for i in range(h):
                for j in range(w):
                    coarse_total[:, i // 2, j // 2] += total[:, i, j]
                    coarse_weight[:, i // 2, j // 2] += weight[:, i, j]
            levels.append((coarse_total, coarse_weight))
        total, weight = levels[-1]
        if weight[0, 0, 0] == 0:
            out[b] = color[b]
            continue
        estimate = total / weight
        for total, weight in reversed(levels[:-1]):
            up = _upsampled(estimate, *weight.shape[1:])
            share = np.minimum(weight, 1.0)
            mean = np.divide(total, weight, out=np.zeros_like(total), where=weight > 0)
            estimate = share * mean + (1.0 - share) * up
        out[b] = estimate
    return out


def bezier_scatter(
    color: np.ndarray,
    depth: np.ndarray,
    offset_prev: np.ndarray | None,
    offset_next: np.ndarray | None,
    *,
    degree: int = 2,
    offset_mid_prev: np.ndarray | None = None,
    arc_center: np.ndarray | None = None,
    arc_angle: np.ndarray | None = None,
    samples: int | None = None,
    max_samples: int = DEFAULT_MAX_SAMPLES,
    shutter: str | ShutterWindow = DEFAULT_SHUTTER,
    normalization: str = DEFAULT_NORMALIZATION,
    fill: str | np.ndarray = DEFAULT_FILL,
    background_weight: float = DEFAULT_BACKGROUND_WEIGHT,
    soft_z_extent: float | np.ndarray | None = None,
    relative_z_extent: float | np.ndarray = DEFAULT_RELATIVE_Z_EXTENT,
    composite: str = DEFAULT_COMPOSITE,
) -> np.ndarray:
    """Seed 003's scatter: every moving pixel splats its colour along its path over the exposure.

    See `torch_impl.bezier_scatter` for the arguments. Per moving source pixel S (still pixels, which
    move at most STILL_SPEED px, are skipped) and per point k at time t_k with shutter mass m_k, the
    point p_S(t_k) splats bilinearly onto up to four pixels D with weight

        omega = bilinear(D) * softDepthCompare(depth[D], depth[S], soft_z_extent) * m_k * f,

    f = 1 ("coverage") or 2 |p_S'(t_k)| ("paper": weight per pixel of path length, 1 for the box
    shutter), adding omega * color[S] to A[D] and omega to alpha[D]. Then, with fill = color where the
    pixel is still, and where it moves the fill: the array given as `fill`, else `still_fill` of the
    still pixels (fill="still") or color (fill="color"):

        coverage: (A + max(1 - alpha, 0) fill) / max(alpha, 1)
        paper:    (A + w_b fill) / (alpha + w_b)

    With "coverage" and composite="layers" (the default) a moving pixel instead composites, front to
    back by the same over (A + max(1 - alpha, 0) behind) / max(alpha, 1), three sums of its splats
    split by the depth test: from sources nearer than the band in front, level (within the band),
    from behind it; then the fill. composite="sum" is the sum above for every pixel (seed 003).
    """
    path = resolve_path(
        degree,
        offset_prev=offset_prev is not None,
        offset_next=offset_next is not None,
        offset_mid_prev=offset_mid_prev is not None,
        arc_center=arc_center is not None,
        arc_angle=arc_angle is not None,
    )
    o = ScatterOptions(
        degree=degree,
        samples=samples,
        max_samples=max_samples,
        shutter=shutter,
        normalization=normalization,
        fill=fill,
        background_weight=background_weight,
        soft_z_extent=soft_z_extent,
        relative_z_extent=relative_z_extent,
        composite=composite,
    )
    samples, normalization, background_weight, composite, background = o.samples, o.normalization, o.background_weight, o.composite, o.background
    fill = "array" if background is not None else o.fill
    batch, channels, height, width = checks.require_image("color", color.shape)
    checks.require_image("depth", depth.shape, channels=DEPTH_CHANNELS)
    relative, extent = checks.depth_band(soft_z_extent, relative_z_extent)
    extent = float(extent)
    log_depths = np.log(depth)
    if relative:  # the band relative to depth: compare log depths (`diffblur.checks.depth_band`)
        depth, extent = np.log(depth), math.log1p(extent)
    window = o.window

    def curve(b: int, i: int, j: int):
        """(moving, position(t), speed(t)) of the point seen at row i, column j."""
        x = np.array([float(j), float(i)])
        if path == "arc":
            center, angle = arc_center[b, :, i, j], float(arc_angle[b, 0, i, j])
            radius = math.hypot(*(x - center))
            return abs(angle) * radius > STILL_SPEED, (lambda t: _arc_point(center, angle, x, t)), (lambda t: abs(angle) * radius)
        offsets = [offset_prev[b, :, i, j], offset_next[b, :, i, j]]
        if degree == 1:
            positions = [x + offsets[0], x + offsets[1]]
        elif degree == 2:
            positions = [x + offsets[0], x, x + offsets[1]]
        else:
            offsets.append(offset_mid_prev[b, :, i, j])
            positions = [x + offsets[0], x + offsets[2], x, x + offsets[1]]
        control = bezier_control_points(positions, degree)
        moving = any(math.hypot(*o) > STILL_SPEED for o in offsets)
        return moving, (lambda t: _bezier_point(control, 0.5 * (t + 1.0))), (lambda t: _bezier_speed(control, 0.5 * (t + 1.0)))

    if samples is None:
        longest = 0.0
        for b in range(batch):
            for i in range(height):
                for j in range(width):
                    _, position, _ = curve(b, i, j)
                    polyline = [position(t) for t in length_times()]
                    length = sum(math.hypot(*(q - p)) for p, q in zip(polyline[:-1], polyline[1:]))
                    longest = max(longest, length)
        samples = point_count(longest, max_samples)
    times = point_times(samples)
    masses = point_masses(window, np.array(times), samples, np)

    accumulated = np.zeros_like(color)
    alpha = np.zeros((batch, 1, height, width), dtype=color.dtype)
    # composite="layers": the splats from sources nearer than the band in front (near) and every
    # splat regardless of depth (every), besides those the depth test passes (accumulated, alpha).
    near_accumulated, near_alpha = np.zeros_like(color), np.zeros_like(alpha)
    every_accumulated, every_alpha = np.zeros_like(color), np.zeros_like(alpha)
    moving_pixels = np.zeros((batch, 1, height, width), dtype=bool)
    for b in range(batch):
        for i in range(height):
            for j in range(width):
                moving, position, speed = curve(b, i, j)
                moving_pixels[b, 0, i, j] = moving
                if not moving:
                    continue  # seed 003: motionless pixels are discarded before segment generation
                for t, mass in zip(times, masses):
                    x, y = position(t)
                    weight = mass if normalization == "coverage" else 2.0 * mass * speed(t)
                    for row, column, bilinear in _bilinear_splat(x, y, height, width):
                        test = _soft_in_front(depth[b, 0, row, column], depth[b, 0, i, j], extent)
                        omega = bilinear * test * weight
                        accumulated[b, :, row, column] += omega * color[b, :, i, j]
                        alpha[b, 0, row, column] += omega
                        # nearer by more than the band: the depth test with the roles swapped fails
                        near = (1.0 - _soft_in_front(depth[b, 0, i, j], depth[b, 0, row, column], extent)) * bilinear * weight
                        near_accumulated[b, :, row, column] += near * color[b, :, i, j]
                        near_alpha[b, 0, row, column] += near
                        every_accumulated[b, :, row, column] += bilinear * weight * color[b, :, i, j]
                        every_alpha[b, 0, row, column] += bilinear * weight

    if background is None and fill == "still":
        warn_without_still(moving_pixels[:, 0])
    unknown_behind = background is None and fill == "still"
    if background is None:
        background = color if fill == "color" else still_fill(color, (~moving_pixels).astype(color.dtype))
    fill = np.where(moving_pixels, background, color)
    if normalization == "paper":
        return (accumulated + background_weight * fill) / (alpha + background_weight)
    if composite == "instants":
        # a moving pixel's uncovered time: what passes behind it over the exposure, over the fill
        behind = _over(every_accumulated - accumulated, every_alpha - alpha, fill)
        return _instants(color, depth, log_depths, curve, times, masses, extent, np.where(moving_pixels, behind, color), unknown_behind)
    summed = _over(accumulated, alpha, fill)
    if composite == "sum":
        return summed
    # "layers": a moving pixel composites, front to back, the splats from nearer sources, those level
    # with it (within the band), those from behind it, then the fill; a still pixel is its own level
    # layer, which hides what passes behind it: the summed result.
    level_accumulated, level_alpha = accumulated - near_accumulated, alpha - near_alpha
    behind_accumulated, behind_alpha = every_accumulated - accumulated, every_alpha - alpha
    back = _over(behind_accumulated, behind_alpha, fill)
    if unknown_behind:
        # fill="still" in an image without a still pixel (its fill is its own colour): what passes
        # behind a moving pixel is the estimate of what it uncovers, counting as fully as the fill
        # once it weighs one point's mean mass, 1 / samples.
        mass = 1.0 / samples
        for b in range(batch):
            if moving_pixels[b].all():
                back[b] = (behind_accumulated[b] + mass * fill[b]) / (behind_alpha[b] + mass)
    layered = _over(near_accumulated, near_alpha, _over(level_accumulated, level_alpha, back))
    return np.where(moving_pixels, layered, summed)


def _instants(color, depth, log_depths, curve, times, masses, extent, behind, unknown) -> np.ndarray:
    """composite="instants": per instant t_k, every moving pixel's point splats bilinearly (onto a
    still pixel times the depth test against it, seed 003's); a destination's nearest depth is the least among splats of bilinear weight above
    NEAREST_SPLAT_WEIGHT; the splats within the band behind it are summed (A, alpha, and the sum of
    log depths); the part of the pixel they leave (1 - alpha) shows the other splats up to their
    coverage, then `behind`; over 1, A / alpha; the instants summed by their masses. `unknown` (fill="still"):
    in an image without a still pixel each instant's uncovered part is `still_fill` of its own
    picture (A / alpha) weighted by min(alpha, 1) (depth / farthest depth)^UNCOVERED_DEPTH_POWER
    over the pixels with alpha >= 1/2, instead of `behind`. Either gives way, on a moving pixel X,
    to X's own object (`_own_surface`) by 1 - softDepthCompare(z at X + p(-t) read bilinearly,
    z[X]): X's object going on behind a nearer surface."""
    batch, channels, height, width = color.shape
    out = np.zeros_like(color)
    curves = [[[curve(b, i, j) for j in range(width)] for i in range(height)] for b in range(batch)]
    from diffblur.reference import sample_bilinear

    own = _own_surface(color, depth, curves, times, masses, extent)
    for b in range(batch):
        no_still = unknown and all(curves[b][i][j][0] for i in range(height) for j in range(width))
        for t, mass in zip(times, masses):
            splats = []
            for i in range(height):
                for j in range(width):
                    is_moving, position, _ = curves[b][i][j]
                    if not is_moving:
                        continue
                    x, y = position(t)
                    for row, column, weight in _bilinear_splat(x, y, height, width):
                        if not curves[b][row][column][0]:  # a still pixel is the layer behind: seed 003's depth test
                            weight *= _soft_in_front(depth[b, 0, row, column], depth[b, 0, i, j], extent)
                        splats.append((row, column, weight, i, j))
            nearest = np.full((height, width), np.inf)
            for row, column, weight, i, j in splats:
                if weight > NEAREST_SPLAT_WEIGHT:
                    nearest[row, column] = min(nearest[row, column], depth[b, 0, i, j])
            accumulated = np.zeros((channels, height, width), dtype=color.dtype)
            alpha = np.zeros((1, height, width), dtype=color.dtype)
            log_sum = np.zeros((1, height, width), dtype=color.dtype)
            hidden, hidden_alpha = np.zeros_like(accumulated), np.zeros_like(alpha)
            for row, column, weight, i, j in splats:
                omega = weight * (1.0 if nearest[row, column] == np.inf else _soft_in_front(nearest[row, column], depth[b, 0, i, j], extent))
                accumulated[:, row, column] += omega * color[b, :, i, j]
                alpha[0, row, column] += omega
                log_sum[0, row, column] += omega * log_depths[b, 0, i, j]
                hidden[:, row, column] += (weight - omega) * color[b, :, i, j]
                hidden_alpha[0, row, column] += weight - omega
            uncovered = _uncovered(accumulated, alpha, log_sum, behind[b]) if no_still else behind[b].copy()
            # a moving pixel X whose own path at -t, X + p(-t), lies behind a nearer surface in the
            # sharp frame: its object goes on behind that surface, so X uncovers its own object
            for i in range(height):
                for j in range(width):
                    is_moving, position, _ = curves[b][i][j]
                    x, y = position(-t) if is_moving else (-1.0, -1.0)
                    if _inside(x, y, height, width):
                        nearer = 1.0 - _soft_in_front(sample_bilinear(depth[b], x, y)[0], depth[b, 0, i, j], extent)
                        uncovered[:, i, j] += nearer * (own[b, :, i, j] - uncovered[:, i, j])
            # the part of a pixel the nearest layer leaves shows the other splats up to their
            # coverage, then what is uncovered
            gap = np.maximum(1.0 - alpha, 0.0)
            shown = np.minimum(hidden_alpha, gap)
            beside = np.divide(hidden * shown, hidden_alpha, out=np.zeros_like(hidden), where=hidden_alpha > 0)
            out[b] += mass * (accumulated + beside + (gap - shown) * uncovered) / np.maximum(alpha, 1.0)
    return out


def _own_surface(color, depth, curves, times, masses, extent) -> np.ndarray:
    """Per moving pixel X, the mean by the masses of the colours at X + p(-t) (bilinear), every point
    time t with X + p(-t) in the image, weighted by how level the depth there is with X's
    (softDepthCompare both ways); X's colour where that weight is 0."""
    from diffblur.reference import sample_bilinear

    batch, channels, height, width = color.shape
    own = color.copy()
    for b in range(batch):
        for i in range(height):
            for j in range(width):
                is_moving, position, _ = curves[b][i][j]
                if not is_moving:
                    continue
                total, weight = np.zeros(channels), 0.0
                for t, mass in zip(times, masses):
                    x, y = position(-t)
                    if not _inside(x, y, height, width):
                        continue
                    z = sample_bilinear(depth[b], x, y)[0]
                    level = _soft_in_front(depth[b, 0, i, j], z, extent) * _soft_in_front(z, depth[b, 0, i, j], extent)
                    total += mass * level * sample_bilinear(color[b], x, y)
                    weight += mass * level
                if weight > 0:
                    own[b, :, i, j] = total / weight
    return own


def _uncovered(accumulated: np.ndarray, alpha: np.ndarray, log_sum: np.ndarray, behind: np.ndarray) -> np.ndarray:
    """An instant's picture (C, H, W) pushed-pulled into what nothing covers (see `_instants`);
    `behind` where the instant covers no pixel at least halfway."""
    covered = alpha >= 0.5
    mean_log = np.divide(log_sum, alpha, out=np.full_like(log_sum, -np.inf), where=covered)
    farthest = mean_log.max() if covered.any() else 0.0
    weight = np.where(covered, np.minimum(alpha, 1.0) * np.exp(UNCOVERED_DEPTH_POWER * (np.where(covered, mean_log, farthest) - farthest)), 0.0)
    picture = np.where(covered, np.divide(accumulated, alpha, out=np.zeros_like(accumulated), where=covered), behind)
    return still_fill(picture[None], weight[None])[0]


def _over(accumulated: np.ndarray, alpha: np.ndarray, behind: np.ndarray) -> np.ndarray:
    """A layer of splats over what is behind it, by coverage: A + (1 - alpha) behind where alpha <= 1,
    A / alpha where alpha > 1."""
    return (accumulated + np.maximum(1.0 - alpha, 0.0) * behind) / np.maximum(alpha, 1.0)
