"""The curve scatter of seed 003 (Guertin & Nowrouzezahrai 2015): every moving pixel splats its colour
along a Bezier curve (or a circular arc) through its positions over the exposure."""

from __future__ import annotations

import math
import torch
import torch.nn.functional as F
from jaxtyping import Float
from torch import Tensor
from torch.utils.checkpoint import checkpoint

from diffblur import checks
from diffblur._scatter_options import (
    COMPOSITES,
    DEFAULT_BACKGROUND_WEIGHT,
    DEFAULT_COMPOSITE,
    DEFAULT_FILL,
    DEFAULT_MAX_SAMPLES,
    DEFAULT_NORMALIZATION,
    DEFAULT_SHUTTER,
    DEFAULT_RELATIVE_Z_EXTENT,
    FILLS,
    MID_PREV_TIME,
    constant_masses,
    curve_point,
    has_constant_parameters,
    moving_mask,
    point_count,
    point_masses,
    point_times,
    polyline_length,
    resolve_options,
    resolve_path,
    traced_count_message,
    warn_without_still,
)
from diffblur.conventions import DEPTH_CHANNELS, VECTOR_CHANNELS
from diffblur.shutters import ShutterWindow, get_shutter
from torch_impl import _checks
from torch_impl._primitives import _soft_depth_compare
from torch_impl._sampling import pixel_grid, position_dtype

#: Points are splatted in chunks of about this many pixel-points (B H W x points of the chunk): one
#: scatter-add per chunk. With more than one chunk the backward recomputes each chunk's splats
#: (activation checkpointing), so it keeps O(pixels) memory, not O(pixels x samples).
_CHUNK_PIXEL_POINTS = 1 << 18


def _finite_values(name: str, x: Tensor) -> None:
    """Raise ValueError if any element is NaN or infinite (eager only, as `_checks.positive_values`)."""
    _checks.finite_values(name, x)


def _extent(value: object, like: Tensor, name: str = "soft_z_extent") -> float | Tensor:
    """soft_z_extent (or relative_z_extent, `name`): a number > 0 or a 0-d tensor > 0 (kept, so it
    gets a gradient)."""
    if isinstance(value, Tensor):
        _checks.floating_tensor(name, value)
        if value.ndim != 0:
            raise ValueError(f"{name} must be a number or a 0-d tensor, got shape {tuple(value.shape)}")
        _checks.same_dtype_and_device(name, value, "depth", like)
        _checks.positive_values(name, value)
        return value
    return checks.require_positive_number(name, value)


def _bezier_terms(degree: int, prev: Tensor, nxt: Tensor, mid: Tensor | None) -> tuple:
    """Power-basis coefficients (constant, linear, quadratic, cubic) of the Bezier through the given
    positions (see `_scatter_options`): the offset p(t) - X is their polynomial in t."""
    half_sum, half_difference = 0.5 * (nxt + prev), 0.5 * (nxt - prev)
    if degree == 1:
        return (half_sum, half_difference, None, None)
    if degree == 2:  # p(-1) = X + prev, p(0) = X, p(1) = X + next
        return (None, half_difference, half_sum, None)
    # The cubic also meets X + mid at tau: c (tau^3 - tau) = mid - h tau - b tau^2 with a = h - c.
    tau = MID_PREV_TIME
    cubic = (mid - half_difference * tau - half_sum * (tau * tau)) / (tau**3 - tau)
    return (None, half_difference - cubic, half_sum, cubic)


def _safe_hypot(a: Tensor, b: Tensor) -> Tensor:
    squared = a * a + b * b
    positive = squared > 0
    return torch.where(positive, torch.sqrt(torch.where(positive, squared, 1.0)), 0.0)


def _splat(
    paper: bool,
    kind: str,
    times: Tensor,
    masses: Tensor,
    terms: tuple,
    x: Tensor,
    y: Tensor,
    rows: Tensor,
    depth: Tensor,
    extent: float | Tensor,
    moving: Tensor,
) -> Tensor:
    """The splats of every curve's points at `times` (K,) with `masses` (K,), one scatter-add for the
    K points: (B * (H + 2) * (W + 2), C + 1) sums of omega * [color, 1] on the image padded by a ring
    of one pixel, which catches the corners just outside the image (the caller crops it)."""
    px, py, vx, vy = curve_point(kind, terms, x, y, times.reshape(-1, 1, 1, 1), torch)
    points, batch, height, width = px.shape
    weight = torch.where(moving[None], masses.reshape(-1, 1, 1, 1), 0.0)
    if paper:  # weight per pixel of path length: |dp| = |dp/dt| dt, with dt = 2 / count ~ 2 mass
        weight = weight * (2.0 * _safe_hypot(vx, vy))
    x0, y0 = torch.floor(px), torch.floor(py)
    fx, fy = px - x0, py - y0
    # Points with a corner in the image have their top-left corner in the padded image.
    near = (x0 >= -1) & (x0 <= width - 1) & (y0 >= -1) & (y0 <= height - 1)
    weight = torch.where(near, weight, 0.0)
    stride = width + 2
    first = (torch.arange(batch, device=px.device) * ((height + 2) * stride)).reshape(1, batch, 1, 1)
    top_left = first + (torch.where(near, y0, -1.0).long() + 1) * stride + torch.where(near, x0, -1.0).long() + 1
    # The four pixels around each point, stacked in front: (4, K, B, H, W).
    index = torch.stack([top_left, top_left + 1, top_left + stride, top_left + stride + 1]).reshape(-1)
    bilinear = torch.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy])
    padded_depth = F.pad(depth, (1, 1, 1, 1), mode="replicate")
    destination_depth = padded_depth.reshape(-1)[index].reshape(bilinear.shape)
    in_front = _soft_depth_compare(destination_depth, depth[None, None, :, 0], extent)
    omega = bilinear * in_front * weight[None]
    values = (omega.reshape(4 * points, -1, 1) * rows[None]).reshape(-1, rows.shape[1])
    return torch.zeros(padded_depth.numel(), rows.shape[1], dtype=values.dtype, device=rows.device).index_add(0, index, values)


@torch.compiler.assume_constant_result
def _constant_masses(window: ShutterWindow, samples: int) -> tuple[float, ...]:
    """`constant_masses`, which torch.compile runs as Python (it computes in NumPy) and keeps as constants."""
    return constant_masses(window, samples)


def _longest(kind: str, terms: tuple, x: Tensor, y: Tensor) -> float:
    """Length in pixels of the longest curve (`polyline_length`). No gradient flows here, so a piece
    is one `torch.hypot`, not `_safe_hypot`'s five ops (the measurement took half the time at 720p)."""
    with torch.no_grad():
        return float(polyline_length(kind, terms, x, y, torch, torch.hypot).max())


def _upsample_rows(x: Tensor, size: int) -> Tensor:
    """Rows (dim -2) doubled by linear interpolation between centres (each new row 3/4 of its parent,
    1/4 of the parent's neighbour on its side, the border repeated), cropped to `size`."""
    before = torch.cat([x[..., :1, :], x[..., :-1, :]], dim=-2)
    after = torch.cat([x[..., 1:, :], x[..., -1:, :]], dim=-2)
    doubled = torch.stack([0.75 * x + 0.25 * before, 0.75 * x + 0.25 * after], dim=-2)
    return doubled.reshape(*x.shape[:-2], 2 * x.shape[-2], x.shape[-1])[..., :size, :]


def _upsample(x: Tensor, height: int, width: int) -> Tensor:
    """Bilinear upsampling by 2 (half-pixel centres, border clamped), cropped to height x width."""
    return _upsample_rows(_upsample_rows(x, height).transpose(-1, -2), width).transpose(-1, -2)


def _pool(x: Tensor) -> Tensor:
    """Sums over 2 x 2 blocks, an odd side padded with zeros, in JAX's order (see its `_pool`)."""
    x = F.pad(x, (0, x.shape[-1] % 2, 0, x.shape[-2] % 2))
    return (x[..., 0::2, 0::2] + x[..., 0::2, 1::2]) + (x[..., 1::2, 0::2] + x[..., 1::2, 1::2])


def _still_fill(color: Tensor, still: Tensor) -> Tensor:
    """The colour behind each pixel estimated from the still pixels (`still`, (B, 1, H, W) of 0 and 1)
    by push-pull (see `diffblur._scatter_options.FILLS`); color where the image has no still pixel."""
    levels = [(color * still, still)]
    while max(levels[-1][1].shape[-2:]) > 1:
        levels.append(tuple(_pool(v) for v in levels[-1]))
    total, weight = levels[-1]
    estimate = total / torch.where(weight > 0, weight, 1.0)
    for total, weight in reversed(levels[:-1]):
        mean = torch.where(weight > 0, total / torch.where(weight > 0, weight, 1.0), 0.0)
        share = torch.clamp(weight, max=1.0)
        estimate = share * mean + (1.0 - share) * _upsample(estimate, *weight.shape[-2:])
    return torch.where(levels[-1][1] > 0, estimate, color)


def bezier_scatter(
    color: Float[Tensor, "b c h w"],
    depth: Float[Tensor, "b 1 h w"],
    offset_prev: Float[Tensor, "b 2 h w"] | None,
    offset_next: Float[Tensor, "b 2 h w"] | None,
    *,
    degree: int = 2,
    offset_mid_prev: Float[Tensor, "b 2 h w"] | None = None,
    arc_center: Float[Tensor, "b 2 h w"] | None = None,
    arc_angle: Float[Tensor, "b 1 h w"] | None = None,
    samples: int | None = None,
    max_samples: int = DEFAULT_MAX_SAMPLES,
    shutter: str | ShutterWindow = DEFAULT_SHUTTER,
    normalization: str = DEFAULT_NORMALIZATION,
    fill: str = DEFAULT_FILL,
    background: Float[Tensor, "b c h w"] | None = None,
    background_weight: float = DEFAULT_BACKGROUND_WEIGHT,
    soft_z_extent: float | Tensor | None = None,
    relative_z_extent: float | Tensor = DEFAULT_RELATIVE_Z_EXTENT,
    composite: str = DEFAULT_COMPOSITE,
    fused: bool | None = None,
) -> Float[Tensor, "b c h w"]:
    """Scatter every moving pixel's colour along its curved path over the exposure (seed 003).

    Each pixel X whose point moves follows a path p(t), t in [-1, 1]: a Bezier curve through its
    positions X + offset_prev (t = -1), X (t = 0) and X + offset_next (t = 1), with the control point
    B1 = 2 p(0) - (p(-1) + p(1)) / 2 so that B(1/2) = p(0) (seed 003's erratum fixed); or a circular
    arc. `samples` points at the midpoints t_k of equal strata of the exposure, each carrying the
    shutter's mass m_k on its stratum, are splatted bilinearly (differentiable in the positions) onto
    the pixels around them, where the source is in front of or within the depth band behind the
    destination's depth (seed 000's softDepthCompare; no depth write), and summed into A (colour)
    and alpha (weight). Still pixels, whose point moves at most `diffblur.conventions.STILL_SPEED`
    px (a renderer's float leftovers included), are skipped (a mask: shapes never depend on data).

    Normalisation, with fill = color where the pixel is still; where it moves, `background` if given,
    else (fill="still", the default) the colour behind it estimated from the still pixels by push-pull,
    or (fill="color") its own colour:

    - "coverage" (default): every moving point spreads total weight 1 over its exposure, so alpha is
      the fraction of the exposure something covers the pixel; out = A + (1 - alpha) fill where
      alpha <= 1, A / alpha where alpha > 1. Closer to the ground truth than "paper" on the
      presets measured, with every fill (docs/methods.md).
    - "paper": seed 003 eq. 4, out = (A + w_b fill) / (alpha + w_b), with the points weighted per
      pixel of path length (2 m_k |p'(t_k)|, 1 per pixel for the box shutter), as rasterised lines
      deposit them, and w_b = `background_weight`.

    Args:
        color: (B, C, H, W) the sharp frame (t = 0), linear intensities, any C.
        depth: (B, 1, H, W) positive depth, larger = farther.
        offset_prev, offset_next: (B, 2, H, W) pixels, where the point seen at X is at t = -1 and
            t = +1, relative to X (channel 0 = x); linear motion is (-V, +V). None with an arc.
        degree: 1 (the segment from X + offset_prev to X + offset_next), 2 (the quadratic Bezier
            through the three positions) or 3 (the cubic through them and X + offset_mid_prev).
        offset_mid_prev: (B, 2, H, W) pixels, where the point is at t = -1/2 relative to X; required
            by degree=3 (seed 003 sec. 5.1's extra motion pass), refused otherwise.
        arc_center, arc_angle: (B, 2, H, W) image coordinates (pixels) of the centre of rotation and
            (B, 1, H, W) radians at t = 1, given together instead of the offsets: the point follows
            c + R(angle t) (X - c), a rotation by 2 angle over the exposure, positive turning +x
            towards +y (as `diffblur.scenes.Rotation`). No quadratic follows a circle exactly.
        samples: points per curve, an int >= 1, the same for every curve; None picks one per pixel of
            the longest curve, at most `max_samples` (eager only: it measures the data; under
            torch.compile pass an int). Curves longer than the count in pixels are dotted.
        max_samples: the cap of the automatic count, an int >= 1.
        shutter: a name in `diffblur.shutters.SHUTTERS` or a `ShutterWindow` whose parameters may be
            tensors to fit. Default: the box, as every op (`diffblur.conventions.DEFAULT_SHUTTER`);
            seed 003 weighs its curves with a Gaussian (shutter="gaussian").
        normalization: "coverage" or "paper" (above).
        fill: what a moving pixel shows for the part of the exposure nothing covers it, without a
            `background`: "still" (default), an estimate of the scene behind it from the pixels that
            do not move (push-pull: the still pixels' colours averaged over 2 x 2 blocks down to one
            pixel, then filled back in from coarse to fine where a block has no still pixel; the
            pixel's own colour where the image has none, with a UserWarning in eager mode, once per
            process; there, with composite="layers", what passes behind the pixel comes first, see
            `composite`), or "color", its own colour. "still" is the default because a moving object
            uncovers what is behind it, which the still pixels show better than the object's own
            colour does (measured on the presets: docs/methods.md). Still pixels in front of
            moving ones count as background too.
        background: (B, C, H, W) the static scene behind the moving objects (seed 003 sec. 5.1's
            two-layer extension): moving pixels show it, not their own colour, for the part of the
            exposure nothing covers them.
        background_weight: seed 003's w_b, a number > 0 (used by "paper").
        soft_z_extent: the depth band in depth units, a number > 0 or a 0-d tensor (differentiable);
            None (default): the band relative to depth, `relative_z_extent`.
        relative_z_extent: with soft_z_extent=None, the band as a fraction of the destination's
            depth, a number > 0 or a 0-d tensor: a splat counts fully up to level with the
            destination, fading linearly in log depth to nothing at z_source = z_dest (1 + r), so
            that the output does not depend on the scene's depth units.
        composite: how "coverage" composites a moving pixel's splats. "layers" (default): front to
            back, each layer over what is behind it by its coverage: the splats from sources nearer
            than the depth band in front, those level with the pixel, those from behind it (which a
            depth test without depth write drops; they are what the pixel shows once its own surface
            has moved off it: what a moving camera or a moving object uncovers), then the fill.
            Where fill="still" finds no still pixel in an image, the behind splats are weighed
            against the pixel's own colour as (A_behind + m C) / (alpha_behind + m), m = 1 / samples
            (one point's mean mass): wherever something passes behind, that is what it uncovers.
            "sum": seed 003's one sum of the splats the depth test passes, over the fill, where
            splats that overlap in the exposure are averaged whatever their depth. Still pixels keep
            the sum in both (they are their own level layer, in front of what passes behind them);
            "paper" has no layers. "layers" splats three times (nearer, passed, all).
        fused: sum the splats and their backward in one parallel CPU loop each
            (`diffblur.kernels.scatter`, numba), with the same result and gradients (tested) and
            O(pixels) memory, faster on the CPU (timings: docs/fused.md). The normalisation and the fill stay tensor ops.
            None (default): fused where it applies (CPU, float32/float64; under torch.compile
            too, where the kernel and its backward are custom operators), tensor ops elsewhere. True: fused or a ValueError saying why not.
            False: always the tensor ops. The fused backward is not differentiable again (no double
            backward).

    Returns:
        (B, C, H, W), color's dtype. Splats beyond the border are lost. On the tensor ops points are
        splatted in chunks of about 2^18 pixel-points; with several chunks the backward recomputes
        each chunk (activation checkpointing), so its memory is O(pixels), not O(pixels x samples).

    >>> import torch
    >>> color = torch.zeros(1, 1, 1, 5); color[..., 2] = 1.0
    >>> offset = torch.zeros(1, 2, 1, 5); offset[:, 0, :, 2] = 1.0
    >>> depth = torch.ones(1, 1, 1, 5)
    >>> bezier_scatter(color, depth, -offset, offset, samples=3, shutter="box", background=torch.zeros_like(color))
    tensor([[[[0.0000, 0.2222, 0.5556, 0.2222, 0.0000]]]])
    >>> bezier_scatter(color, depth, -offset, offset, samples=3, shutter="box", fill="color")  # fills with its own colour
    tensor([[[[0.0000, 0.2222, 1.0000, 0.2222, 0.0000]]]])
    """
    color = _checks.image("color", color)
    depth = _checks.image("depth", depth, channels=DEPTH_CHANNELS)
    kind = resolve_path(
        degree,
        offset_prev=offset_prev is not None,
        offset_next=offset_next is not None,
        offset_mid_prev=offset_mid_prev is not None,
        arc_center=arc_center is not None,
        arc_angle=arc_angle is not None,
    )
    samples, max_samples, normalization, background_weight = resolve_options(
        samples=samples, max_samples=max_samples, normalization=normalization, background_weight=background_weight
    )
    given = {}
    for name, value in (("offset_prev", offset_prev), ("offset_next", offset_next), ("offset_mid_prev", offset_mid_prev), ("arc_center", arc_center)):
        if value is not None:
            given[name] = _checks.image(name, value, channels=VECTOR_CHANNELS)
    if arc_angle is not None:
        given["arc_angle"] = _checks.image("arc_angle", arc_angle, channels=1)
    checks.require_same_batch_and_size("color", color.shape, [("depth", depth.shape), *((n, v.shape) for n, v in given.items())])
    for name, value in (("depth", depth), *given.items()):
        _checks.same_dtype_and_device(name, value, "color", color)
    if background is not None:
        _checks.same_shape("background", _checks.image("background", background), "color", color)
    fill = checks.require_choice("fill", fill, FILLS)
    composite = checks.require_choice("composite", composite, COMPOSITES)
    relative, band = checks.depth_band(soft_z_extent, relative_z_extent)
    extent = _extent(band, depth, "relative_z_extent" if relative else "soft_z_extent")
    window = get_shutter(shutter)
    _checks.positive_values("depth", depth)
    _finite_values("depth", depth)
    if relative:  # the band relative to depth: compare log depths (`diffblur.checks.depth_band`)
        depth = torch.log(depth)
        extent = torch.log1p(extent) if isinstance(extent, Tensor) else math.log1p(extent)
    for name, value in given.items():
        _finite_values(name, value)
    _finite_values("color", color)
    if background is not None:
        _finite_values("background", background)

    if fused is not False:
        from diffblur.kernels.shared import use_fused
        from torch_impl._fused_scatter import unfused_reason

        fused = use_fused("bezier_scatter", fused, unfused_reason(color))

    # Positions, offsets, splat weights and the sums in float32 for a half image (its dtype else).
    wide = position_dtype(color.dtype)
    given = {name: value.to(wide) for name, value in given.items()}
    if samples is None:
        if torch.compiler.is_compiling():
            raise ValueError(traced_count_message("torch.compile"))
        x, y = pixel_grid(color.shape[2], color.shape[3], color)
        samples = point_count(_longest(kind, _terms(kind, degree, given), x[None], y[None]), max_samples)
    if has_constant_parameters(window):
        masses = torch.as_tensor(_constant_masses(window, samples), dtype=wide, device=color.device)
    else:  # a shape parameter being fitted: the masses carry its gradient
        times = torch.as_tensor(point_times(samples), dtype=wide, device=color.device)
        masses = point_masses(window, times, samples, torch).to(wide)
    return _scatter(
        color,
        depth,
        given,
        masses,
        extent,
        background,
        kind=kind,
        degree=degree,
        paper=normalization == "paper",
        background_weight=background_weight,
        fill=fill,
        layers=composite == "layers",
        fused=fused,
    )


def _moved_by(kind: str, degree: int, given: dict[str, Tensor]) -> tuple:
    """What `moving_mask` reads: the offsets given, or the arc's (center, angle)."""
    if kind == "arc":
        return (given["arc_center"], given["arc_angle"])
    return (given["offset_prev"], given["offset_next"]) + ((given["offset_mid_prev"],) if degree == 3 else ())


def _terms(kind: str, degree: int, given: dict[str, Tensor]) -> tuple:
    if kind == "arc":
        return (given["arc_center"], given["arc_angle"])
    return _bezier_terms(degree, given["offset_prev"], given["offset_next"], given.get("offset_mid_prev"))


def _splat_sums(
    color: Tensor, depth: Tensor, terms: tuple, masses: Tensor, extent: float | Tensor, moving: Tensor, x: Tensor, y: Tensor, *, kind: str, paper: bool, passes: int = 1
) -> Tensor:
    """The sums (B, C + 1, H, W) of omega * [color, 1] over every moving pixel's points, by tensor
    ops (one scatter-add per chunk of points), cropped to the image."""
    batch, channels, height, width = color.shape
    wide = position_dtype(color.dtype)
    samples = masses.shape[0]
    # Rows of [color, 1] per source pixel: one scatter-add per point sums colour and weight together.
    rows = torch.cat([color, torch.ones_like(depth)], dim=1).permute(0, 2, 3, 1).reshape(-1, channels + 1)
    times = torch.as_tensor(point_times(samples), dtype=wide, device=color.device)
    # composite="layers" runs `passes` (3) of these in one call: they share the chunk budget.
    chunk = max(1, _CHUNK_PIXEL_POINTS // (passes * rows.shape[0]))
    # Under torch.compile the compiler chooses what the backward keeps.
    recompute = chunk < samples and torch.is_grad_enabled() and not torch.compiler.is_compiling()
    accumulated = torch.zeros(batch * (height + 2) * (width + 2), channels + 1, dtype=wide, device=color.device)
    for start in range(0, samples, chunk):
        arguments = (paper, kind, times[start : start + chunk], masses[start : start + chunk], terms, x[None], y[None], rows, depth, extent, moving)
        if recompute:  # keep only the inputs for the backward; each chunk is recomputed there
            accumulated = accumulated + checkpoint(_splat, *arguments, use_reentrant=False, preserve_rng_state=False)
        else:
            accumulated = accumulated + _splat(*arguments)
    return accumulated.reshape(batch, height + 2, width + 2, channels + 1)[:, 1:-1, 1:-1].permute(0, 3, 1, 2)


def _scatter(
    color: Tensor,
    depth: Tensor,
    given: dict[str, Tensor],
    masses: Tensor,
    extent: float | Tensor,
    background: Tensor | None,
    *,
    kind: str,
    degree: int,
    paper: bool,
    background_weight: float,
    fill: str,
    layers: bool,
    fused: bool,
) -> Tensor:
    """The scatter after the checks: `given` and `masses` in `position_dtype(color.dtype)`; the
    splats on the fused kernel (`torch_impl._fused_scatter`) if `fused`; `layers`: composite="layers"
    (with "coverage")."""
    _, channels, height, width = color.shape
    x, y = pixel_grid(height, width, color)
    terms = _terms(kind, degree, given)
    moving = moving_mask(kind, _moved_by(kind, degree, given), x, y)
    if fill == "still" and background is None and not torch.compiler.is_compiling():
        warn_without_still(moving.cpu().numpy(), stacklevel=4)  # + the public wrapper (checks.lists_options)

    def sums(depth):
        if fused:
            from torch_impl._fused_scatter import fused_splat

            return fused_splat(color, depth, kind, terms, masses, extent, moving, paper)
        return _splat_sums(color, depth, terms, masses, extent, moving, x, y, kind=kind, paper=paper, passes=3 if layers and not paper else 1)

    accumulated = sums(depth)
    splatted, alpha = accumulated[:, :channels], accumulated[:, channels:]
    still_fill = background is None and fill == "still"
    if background is None:
        background = color if fill == "color" else _still_fill(color, (~moving).unsqueeze(1).to(color.dtype))
    fill = torch.where(moving.unsqueeze(1), background, color)
    if paper:
        return ((splatted + background_weight * fill) / (alpha + background_weight)).to(color.dtype)
    summed = _over(splatted, alpha, fill)
    if not layers:
        return summed.to(color.dtype)
    # The same splats with the depths negated pass where the source is level or behind, so their
    # complement is the nearer ones; with equal depths every splat passes.
    every = sums(torch.zeros_like(depth))
    near = every - sums(-depth)
    level, behind = accumulated - near, every - accumulated
    back = _over(behind[:, :channels], behind[:, channels:], fill)
    if still_fill:  # where an image has no still pixel, what passes behind a pixel is what it uncovers
        mass = 1.0 / masses.shape[0]
        unknown = (behind[:, :channels] + mass * fill) / (behind[:, channels:] + mass)
        back = torch.where(moving.flatten(1).all(1).reshape(-1, 1, 1, 1), unknown, back)
    layered = _over(near[:, :channels], near[:, channels:], _over(level[:, :channels], level[:, channels:], back))
    return torch.where(moving.unsqueeze(1), layered, summed).to(color.dtype)


def _over(splatted: Tensor, alpha: Tensor, behind: Tensor) -> Tensor:
    """A layer of splats over what is behind it, by coverage (`_scatter_options.COMPOSITES`)."""
    uncovered = torch.where(alpha < 1, 1.0 - alpha, 0.0)
    return (splatted + uncovered * behind) / torch.where(alpha > 1, alpha, 1.0)
