"""The curve scatter of seed 003 (Guertin & Nowrouzezahrai 2015): every moving pixel splats its colour
along a Bezier curve (or a circular arc) through its positions over the exposure."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

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
from jax_impl import _checks
from jax_impl._primitives import _soft_depth_compare
from jax_impl._sampling import pixel_grid, position_dtype, widen_window

#: Points are splatted in chunks of about this many pixel-points (B H W x points of the chunk): one
#: scatter-add per chunk. With more than one chunk the backward recomputes each chunk's splats
#: (activation checkpointing), so it keeps O(pixels) memory, not O(pixels x samples).
_CHUNK_PIXEL_POINTS = 1 << 18


def _extent(value: object, like: Array, name: str = "soft_z_extent") -> Array:
    """soft_z_extent (or relative_z_extent, `name`): a number > 0 or a 0-d array > 0, as a 0-d array
    of like's dtype."""
    if isinstance(value, (jax.Array, np.ndarray)):
        value = _checks.floating_array(name, value)
        if value.ndim != 0:
            raise ValueError(f"{name} must be a number or a 0-d array, got shape {tuple(value.shape)}")
        _checks.same_dtype(name, value, "depth", like)
        return _checks.positive_values(name, value)
    return jnp.asarray(checks.require_positive_number(name, value), dtype=like.dtype)


def _bezier_terms(degree: int, prev: Array, nxt: Array, mid: Array | None) -> tuple:
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


def _safe_hypot(a: Array, b: Array) -> Array:
    squared = a * a + b * b
    positive = squared > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, squared, 1.0)), 0.0)


def _splat(
    paper: bool,
    kind: str,
    times: Array,
    masses: Array,
    terms: tuple,
    x: Array,
    y: Array,
    rows: Array,
    depth: Array,
    extent: Array,
    moving: Array,
) -> Array:
    """The splats of every curve's points at `times` (K,) with `masses` (K,), one scatter-add for the
    K points: (B * (H + 2) * (W + 2), C + 1) sums of omega * [color, 1] on the image padded by a ring
    of one pixel, which catches the corners just outside the image (the caller crops it)."""
    px, py, vx, vy = curve_point(kind, terms, x, y, times.reshape(-1, 1, 1, 1), jnp)
    points, batch, height, width = px.shape
    weight = jnp.where(moving[None], masses.reshape(-1, 1, 1, 1), 0.0)
    if paper:  # weight per pixel of path length: |dp| = |dp/dt| dt, with dt = 2 / count ~ 2 mass
        weight = weight * (2.0 * _safe_hypot(vx, vy))
    x0, y0 = jax.lax.stop_gradient(jnp.floor(px)), jax.lax.stop_gradient(jnp.floor(py))
    fx, fy = px - x0, py - y0
    # Points with a corner in the image have their top-left corner in the padded image.
    near = (x0 >= -1) & (x0 <= width - 1) & (y0 >= -1) & (y0 <= height - 1)
    weight = jnp.where(near, weight, 0.0)
    stride = width + 2
    first = (jnp.arange(batch, dtype=jnp.int32) * ((height + 2) * stride)).reshape(1, batch, 1, 1)
    top_left = first + (jnp.where(near, y0, -1.0).astype(jnp.int32) + 1) * stride + jnp.where(near, x0, -1.0).astype(jnp.int32) + 1
    # The four pixels around each point, stacked in front: (4, K, B, H, W).
    index = jnp.stack([top_left, top_left + 1, top_left + stride, top_left + stride + 1]).reshape(-1)
    bilinear = jnp.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy])
    padded_depth = jnp.pad(depth, ((0, 0), (0, 0), (1, 1), (1, 1)), mode="edge")
    destination_depth = padded_depth.reshape(-1)[index].reshape(bilinear.shape)
    in_front = _soft_depth_compare(destination_depth, depth[None, None, :, 0], extent).astype(bilinear.dtype)
    omega = bilinear * in_front * weight[None]
    values = (omega.reshape(4 * points, -1, 1) * rows[None]).reshape(-1, rows.shape[1])
    return jnp.zeros((padded_depth.size, rows.shape[1]), dtype=rows.dtype).at[index].add(values)


def _longest(kind: str, terms: tuple, x: Array, y: Array) -> float:
    """Length in pixels of the longest curve (`polyline_length`; `jnp.hypot` was no faster here than
    `_safe_hypot`, eagerly)."""
    length = polyline_length(kind, jax.lax.stop_gradient(terms), x, y, jnp, _safe_hypot)
    try:
        return float(length.max())
    except jax.errors.ConcretizationTypeError as error:
        raise ValueError(traced_count_message("jax.jit")) from error


def _upsample_axis(x: Array, size: int, axis: int) -> Array:
    """Axis `axis` (-2: rows, -1: columns) doubled by linear interpolation between centres (each new
    element 3/4 of its parent, 1/4 of the parent's neighbour on its side, the border repeated),
    cropped to `size`."""
    n = x.shape[axis]
    before = jnp.concatenate([jax.lax.slice_in_dim(x, 0, 1, axis=axis), jax.lax.slice_in_dim(x, 0, n - 1, axis=axis)], axis=axis)
    after = jnp.concatenate([jax.lax.slice_in_dim(x, 1, n, axis=axis), jax.lax.slice_in_dim(x, n - 1, n, axis=axis)], axis=axis)
    doubled = jnp.stack([0.75 * x + 0.25 * before, 0.75 * x + 0.25 * after], axis=axis % x.ndim + 1)
    shape = list(x.shape)
    shape[axis] = 2 * n
    return jax.lax.slice_in_dim(doubled.reshape(shape), 0, size, axis=axis)


def _upsample(x: Array, height: int, width: int) -> Array:
    """Bilinear upsampling by 2 (half-pixel centres, border clamped), cropped to height x width. Each
    axis in place: with `swapaxes` around a row pass the push-pull fill's jitted value_and_grad took
    166 ms at 1280x720 instead of 110 (XLA:CPU)."""
    return _upsample_axis(_upsample_axis(x, height, -2), width, -1)


def _pool(x: Array) -> Array:
    """Sums over 2 x 2 blocks, an odd side padded with zeros. Strided slices, not a reshape and a sum
    over axes (3, 5): XLA:CPU ran that 2x slower (4.0 against 1.9 ms at 1280x720, value_and_grad)."""
    height, width = x.shape[-2:]
    x = jnp.pad(x, ((0, 0), (0, 0), (0, height % 2), (0, width % 2)))
    return (x[..., 0::2, 0::2] + x[..., 0::2, 1::2]) + (x[..., 1::2, 0::2] + x[..., 1::2, 1::2])


def _still_fill(color: Array, still: Array) -> Array:
    """The colour behind each pixel estimated from the still pixels (`still`, (B, 1, H, W) of 0 and 1)
    by push-pull (see `diffblur._scatter_options.FILLS`); color where the image has no still pixel."""
    levels = [(color * still, still)]
    while max(levels[-1][1].shape[-2:]) > 1:
        levels.append(tuple(_pool(v) for v in levels[-1]))
    total, weight = levels[-1]
    estimate = total / jnp.where(weight > 0, weight, 1.0)
    for total, weight in reversed(levels[:-1]):
        mean = jnp.where(weight > 0, total / jnp.where(weight > 0, weight, 1.0), 0.0)
        share = jnp.minimum(weight, 1.0)
        estimate = share * mean + (1.0 - share) * _upsample(estimate, *weight.shape[-2:])
    return jnp.where(levels[-1][1] > 0, estimate, color)


def bezier_scatter(
    color: Float[Array, "b c h w"],
    depth: Float[Array, "b 1 h w"],
    offset_prev: Float[Array, "b 2 h w"] | None,
    offset_next: Float[Array, "b 2 h w"] | None,
    *,
    degree: int = 2,
    offset_mid_prev: Float[Array, "b 2 h w"] | None = None,
    arc_center: Float[Array, "b 2 h w"] | None = None,
    arc_angle: Float[Array, "b 1 h w"] | None = None,
    samples: int | None = None,
    max_samples: int = DEFAULT_MAX_SAMPLES,
    shutter: str | ShutterWindow = DEFAULT_SHUTTER,
    normalization: str = DEFAULT_NORMALIZATION,
    fill: str = DEFAULT_FILL,
    background: Float[Array, "b c h w"] | None = None,
    background_weight: float = DEFAULT_BACKGROUND_WEIGHT,
    soft_z_extent: float | Array | None = None,
    relative_z_extent: float | Array = DEFAULT_RELATIVE_Z_EXTENT,
    composite: str = DEFAULT_COMPOSITE,
    fused: bool | None = None,
) -> Float[Array, "b c h w"]:
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
            jax.jit pass an int). Curves longer than the count in pixels are dotted.
        max_samples: the cap of the automatic count, an int >= 1.
        shutter: a name in `diffblur.shutters.SHUTTERS` or a `ShutterWindow` whose parameters may be
            arrays to fit. Default: the box, as every op (`diffblur.conventions.DEFAULT_SHUTTER`);
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
        soft_z_extent: the depth band in depth units, a number > 0 or a 0-d array (differentiable);
            None (default): the band relative to depth, `relative_z_extent`.
        relative_z_extent: with soft_z_extent=None, the band as a fraction of the destination's
            depth, a number > 0 or a 0-d array: a splat counts fully up to level with the
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
            (`diffblur.kernels.scatter`, numba, a host callback, also under jax.jit and jax.vmap),
            with the same result and gradients (tested) and O(pixels) memory, faster on the CPU
            (timings: docs/fused.md). The normalisation and the fill stay jax.numpy ops. None (default): fused
            where it applies (JAX's default backend is the CPU, float32/float64), jax.numpy ops
            elsewhere. True: fused or a ValueError saying why not. False: always the jax.numpy ops.
            The fused path has reverse-mode gradients only (a custom_vjp): forward mode (jax.jvp,
            jax.jacfwd, optimistix's Levenberg-Marquardt with jac="fwd") needs fused=False.

    Returns:
        (B, C, H, W), color's dtype. Splats beyond the border are lost. On the jax.numpy ops points
        are splatted in chunks of about 2^18 pixel-points; with several chunks the backward
        recomputes each chunk (activation checkpointing), so its memory is O(pixels), not
        O(pixels x samples).

    >>> import jax.numpy as jnp
    >>> color = jnp.zeros((1, 1, 1, 5)).at[..., 2].set(1.0)
    >>> offset = jnp.zeros((1, 2, 1, 5)).at[:, 0, :, 2].set(1.0)
    >>> depth = jnp.ones((1, 1, 1, 5))
    >>> bezier_scatter(color, depth, -offset, offset, samples=3, shutter="box", background=jnp.zeros_like(color)).round(4).tolist()
    [[[[0.0, 0.2222, 0.5556, 0.2222, 0.0]]]]
    >>> bezier_scatter(color, depth, -offset, offset, samples=3, shutter="box", fill="color").round(4).tolist()  # fills with its own colour
    [[[[0.0, 0.2222, 1.0, 0.2222, 0.0]]]]
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
        _checks.same_dtype(name, value, "color", color)
    if background is not None:
        background = _checks.image("background", background)
        _checks.same_shape("background", background, "color", color)
    fill = checks.require_choice("fill", fill, FILLS)
    composite = checks.require_choice("composite", composite, COMPOSITES)
    relative, band = checks.depth_band(soft_z_extent, relative_z_extent)
    extent = _extent(band, depth, "relative_z_extent" if relative else "soft_z_extent")
    window = get_shutter(shutter)
    depth = _checks.finite_values("depth", _checks.positive_values("depth", depth))
    if relative:  # the band relative to depth: compare log depths (`diffblur.checks.depth_band`)
        depth, extent = jnp.log(depth), jnp.log1p(extent)
    given = {name: _checks.finite_values(name, value) for name, value in given.items()}
    depth = _checks.finite_values("color", color, carry=depth)
    if background is not None:
        depth = _checks.finite_values("background", background, carry=depth)

    if fused is not False:
        from diffblur.kernels.shared import use_fused
        from jax_impl._fused_scatter import unfused_reason

        fused = use_fused("bezier_scatter", fused, unfused_reason(color))

    # Positions, offsets, splat weights and the sums in float32 for a half image (its dtype else).
    wide = position_dtype(color.dtype)
    given = {name: value.astype(wide) for name, value in given.items()}
    if samples is None:
        x, y = pixel_grid(color.shape[2], color.shape[3], color.dtype)
        samples = point_count(_longest(kind, _terms(kind, degree, given), x[None], y[None]), max_samples)
    if fill == "still" and background is None:
        _warn_without_still(kind, degree, given, color.shape[2], color.shape[3])
    if has_constant_parameters(window):
        masses = jnp.asarray(constant_masses(window, samples), dtype=wide)
    else:  # a shape parameter being fitted: the masses carry its gradient
        times = jnp.asarray(point_times(samples), dtype=wide)
        masses = point_masses(widen_window(window, wide), times, samples, jnp).astype(wide)
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


def _moved_by(kind: str, degree: int, given: dict) -> tuple:
    """What `moving_mask` reads: the offsets given, or the arc's (center, angle)."""
    if kind == "arc":
        return (given["arc_center"], given["arc_angle"])
    return (given["offset_prev"], given["offset_next"]) + ((given["offset_mid_prev"],) if degree == 3 else ())


def _warn_without_still(kind: str, degree: int, given: dict, height: int, width: int) -> None:
    """fill="still"'s warning when an image has no still pixel; eager only (concrete arrays)."""
    if any(isinstance(v, jax.core.Tracer) for v in given.values()):
        return
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    moved = tuple(np.asarray(v, dtype=np.float64) for v in _moved_by(kind, degree, given))
    warn_without_still(moving_mask(kind, moved, x[None], y[None]), stacklevel=4)  # + the public wrapper (checks.lists_options)


def _terms(kind: str, degree: int, given: dict[str, Array]) -> tuple:
    if kind == "arc":
        return (given["arc_center"], given["arc_angle"])
    return _bezier_terms(degree, given["offset_prev"], given["offset_next"], given.get("offset_mid_prev"))


def _splat_sums(color: Array, depth: Array, terms: tuple, masses: Array, extent: Array, moving: Array, x: Array, y: Array, *, kind: str, paper: bool, passes: int = 1) -> Array:
    """The sums (B, C + 1, H, W) of omega * [color, 1] over every moving pixel's points, by
    jax.numpy ops (one scatter-add per chunk of points), cropped to the image."""
    batch, channels, height, width = color.shape
    wide = position_dtype(color.dtype)
    samples = masses.shape[0]
    # Rows of [color, 1] per source pixel: one scatter-add per point sums colour and weight together.
    rows = jnp.concatenate([color, jnp.ones_like(depth)], axis=1).transpose(0, 2, 3, 1).reshape(-1, channels + 1).astype(wide)
    times = jnp.asarray(point_times(samples), dtype=wide)
    # composite="layers" runs `passes` (3) of these in one call: they share the chunk budget.
    chunk = max(1, _CHUNK_PIXEL_POINTS // (passes * rows.shape[0]))
    splat = functools.partial(_splat, paper, kind)
    fixed = (terms, x[None], y[None], rows, depth, extent, moving)
    if chunk >= samples:
        accumulated = splat(times, masses, *fixed)
    else:
        # A loop (scan) over the chunks runs them one after the other, so that XLA keeps one chunk's
        # buffers at a time; each is recomputed in the backward, which keeps only the loop's inputs.
        # The last chunk is padded with points of mass 0.
        count = -(-samples // chunk)
        pad = count * chunk - samples
        times = jnp.concatenate([times, jnp.zeros(pad, dtype=times.dtype)]).reshape(count, chunk)
        masses = jnp.concatenate([masses, jnp.zeros(pad, dtype=masses.dtype)]).reshape(count, chunk)
        step = jax.checkpoint(lambda total, part: (total + splat(*part, *fixed), None))
        start = jnp.zeros((batch * (height + 2) * (width + 2), channels + 1), dtype=wide)
        accumulated, _ = jax.lax.scan(step, start, (times, masses))
    return accumulated.reshape(batch, height + 2, width + 2, channels + 1)[:, 1:-1, 1:-1].transpose(0, 3, 1, 2)


@functools.partial(jax.jit, static_argnames=("kind", "degree", "paper", "background_weight", "fill", "layers", "fused"))
def _scatter(
    color: Array,
    depth: Array,
    given: dict[str, Array],
    masses: Array,
    extent: Array,
    background: Array | None,
    *,
    kind: str,
    degree: int,
    paper: bool,
    background_weight: float,
    fill: str,
    layers: bool,
    fused: bool,
) -> Array:
    """The scatter after the checks (jitted, so that eager calls run one compiled program); `given`
    and `masses` in `position_dtype(color.dtype)`, as the sums; the splats on the fused kernel
    (`jax_impl._fused_scatter`) if `fused`."""
    _, channels, height, width = color.shape
    wide = position_dtype(color.dtype)
    x, y = pixel_grid(height, width, color.dtype)
    terms = _terms(kind, degree, given)
    moving = moving_mask(kind, _moved_by(kind, degree, given), x, y)

    def sums(depth):
        if fused:
            from jax_impl._fused_scatter import fused_splat

            return fused_splat(color, depth, kind, terms, masses, extent, moving, paper)
        return _splat_sums(color, depth, terms, masses, extent, moving, x, y, kind=kind, paper=paper, passes=3 if layers and not paper else 1)

    def split(accumulated):
        # alpha copied per channel rather than broadcast: the gradient of a broadcast over the channel
        # axis is a reduce over that leading axis, two of which took 72 ms of the backward at 1280x720
        # (XLA:CPU).
        return accumulated[:, :channels], jnp.concatenate([accumulated[:, channels:]] * channels, axis=1)

    accumulated = sums(depth)
    splatted, alpha = split(accumulated)
    still_fill = background is None and fill == "still"
    if background is None:
        background = color if fill == "color" else _still_fill(color, jnp.logical_not(moving)[:, None].astype(color.dtype))
    fill = jnp.where(moving[:, None], background, color).astype(wide)
    if paper:
        return ((splatted + background_weight * fill) / (alpha + background_weight)).astype(color.dtype)
    summed = _over(splatted, alpha, fill)
    if not layers:
        return summed.astype(color.dtype)
    # The same splats with the depths negated pass where the source is level or behind, so their
    # complement is the nearer ones; with equal depths every splat passes.
    every = sums(jnp.zeros_like(depth))
    near = every - sums(-depth)
    level, behind = accumulated - near, every - accumulated
    back = _over(*split(behind), fill)
    if still_fill:  # where an image has no still pixel, what passes behind a pixel is what it uncovers
        mass = 1.0 / masses.shape[0]
        behind_splatted, behind_alpha = split(behind)
        unknown = (behind_splatted + mass * fill) / (behind_alpha + mass)
        back = jnp.where(jnp.all(moving, axis=(1, 2))[:, None, None, None], unknown, back)
    layered = _over(*split(near), _over(*split(level), back))
    return jnp.where(moving[:, None], layered, summed).astype(color.dtype)


def _over(splatted: Array, alpha: Array, behind: Array) -> Array:
    """A layer of splats over what is behind it, by coverage (`_scatter_options.COMPOSITES`)."""
    uncovered = jnp.where(alpha < 1, 1.0 - alpha, 0.0)
    return (splatted + uncovered * behind) / jnp.where(alpha > 1, alpha, 1.0)
