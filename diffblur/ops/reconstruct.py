"""`reconstruct`: seed 000's reconstruction filter (Listing 1), batched and differentiable. Options,
docstring and math, for both frameworks."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from diffblur import checks
from diffblur.conventions import (
    DEFAULT_MAX_RADIUS,
    DEFAULT_MIN_RADIUS,
    DEFAULT_RELATIVE_Z_EXTENT,
    DEFAULT_SAMPLES,
    DEFAULT_SHUTTER,
    DEPTH_CHANNELS,
    EARLY_OUT_SPEED,
    JITTER_MODES,
    SAMPLING_MODES,
    TAP_DIRECTIONS,
    VECTOR_CHANNELS,
)
from diffblur.ops import adaptive
from diffblur.ops._options import OpOptions, impl_option, takes_kernel
from diffblur.ops.primitives import at_least, cone, cylinder, neighbor_max_of_velocity, safe_length, soft_depth_compare
from diffblur.ops.pyramid import Pyramid
from diffblur.ops.sampling import pixel_grid, position_dtype, sample
from diffblur.ops.taps import reconstruct_tap_time, shutter_factor
from diffblur.shutters import ShutterWindow, get_shutter

__all__ = ["DOC", "ReconstructOptions", "reconstruct"]


@dataclasses.dataclass(frozen=True)
class ReconstructOptions(OpOptions):
    """reconstruct's options, checked; the tile, the depth band compared, the window, the early-out
    and the adaptive classes resolved from them."""

    max_radius: float = DEFAULT_MAX_RADIUS
    samples: int = DEFAULT_SAMPLES
    soft_z_extent: float | None = None
    relative_z_extent: float = DEFAULT_RELATIVE_Z_EXTENT
    jitter: str | Any = "noise"
    sampling: str = "bilinear"
    shutter: str | ShutterWindow = DEFAULT_SHUTTER
    early_out: bool | None = None
    directions: str = "neighbor"
    min_radius: float = DEFAULT_MIN_RADIUS
    adaptive: bool | tuple[int, ...] = False
    impl: str = "auto"
    #: Tiles of TileMax and NeighborMax: ceil(max_radius) pixels.
    tile: int = dataclasses.field(init=False, repr=False)
    #: The band of soft_depth_compare in the depths compared: depth units, or log(1 + r) when
    #: `log_depth` (the band relative to depth, `diffblur.checks.depth_band`).
    band: float = dataclasses.field(init=False, repr=False)
    #: The depths are compared as log depth (a band relative to depth).
    log_depth: bool = dataclasses.field(init=False, repr=False)
    window: ShutterWindow = dataclasses.field(init=False, repr=False)
    #: Sample-count classes of tiled adaptive sampling (`diffblur.ops.adaptive`), None when off.
    classes: tuple[int, ...] | None = dataclasses.field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._resolve("sampling", checks.require_choice("sampling", self.sampling, SAMPLING_MODES))
        self._resolve("samples", checks.require_odd_int("samples", self.samples))
        relative, extent = checks.depth_band(self.soft_z_extent, self.relative_z_extent)
        extent = checks.require_positive_number("relative_z_extent" if relative else "soft_z_extent", extent)
        self._resolve("tile", math.ceil(checks.require_positive_number("max_radius", self.max_radius)))
        self._resolve("band", math.log1p(extent) if relative else extent)
        self._resolve("log_depth", relative)
        self._resolve("window", get_shutter(self.shutter))
        # None: on for "nearest" (the paper), off on the differentiable paths.
        self._resolve("early_out", self.sampling == "nearest" if self.early_out is None else bool(self.early_out))
        self._resolve("directions", checks.require_choice("directions", self.directions, TAP_DIRECTIONS))
        self._resolve("min_radius", checks.require_positive_number("min_radius", self.min_radius))
        self._resolve("classes", adaptive.adaptive_classes(self.adaptive, self.samples))
        self._resolve("impl", impl_option(self.impl))
        if isinstance(self.jitter, str):
            checks.require_choice("jitter", self.jitter, JITTER_MODES)
        if self.sampling == "pyramid" and self.classes is not None:
            raise ValueError(f"sampling='pyramid' does not combine with adaptive sampling yet; got adaptive={self.adaptive!r}")


DOC = """Seed 000's reconstruction filter: plausible motion blur from color, velocity and depth.

    TileMax and NeighborMax over tiles of ceil(max_radius) pixels give each pixel X the dominant
    velocity v_N of its neighbourhood; S - 1 taps Y = X + v_N t, t = mix(-1, 1, (i + j + 1) / (S + 1)),
    with the whole filter jittered by j, are classified by soft_depth_compare, cone and cylinder
    (blurry Y in front of X; Y behind blurry X; both blurry) and averaged with X itself, whose
    weight is 1 / |V[X]|. Each tap also carries the shutter's weight at exposure time -t (1 for
    the box, which reproduces the paper).

    Args:
        color: (B, C, H, W) linear intensities, any C.
        velocity: (B, 2, H, W) half-spread velocity in pixels, usually `velocity_from_motion`'s
            output (lengths in [0.5, max_radius]); longer vectors are not clamped here, but
            neighbours farther than one tile are not gathered.
        depth: (B, 1, H, W) positive depth, larger = farther.
        max_radius: the largest blur radius k in pixels; tiles are ceil(k) pixels.
        samples: taps S, an odd integer >= 1.
        soft_z_extent: depth band of soft_depth_compare in depth units, a number > 0; None
            (default): the band relative to depth, `relative_z_extent`.
        relative_z_extent: with soft_z_extent=None, the band as a fraction of depth, > 0: Y counts
            as in front of X up to z_Y = z_X (1 + relative_z_extent), fading linearly in log depth,
            so that the output does not depend on the scene's depth units.
        jitter: "noise" (interleaved gradient noise, deterministic), "none", or a (B, 1, H, W)
            array with values in [-0.5, 0.5].
        sampling: how a tap reads C, V and Z. "bilinear" (default; differentiable through the tap
            positions), "nearest" (the paper), or "pyramid": bilinear, but where the taps are
            farther apart than a pixel (2 |v| / (samples + 1) > 1 along the tap direction v) the
            colour from a pre-filtered pyramid level (seed 001's texture-space blur), trilinearly;
            depth and velocity stay full resolution. Not with adaptive.
        shutter: a window name or `ShutterWindow` (its parameters may be arrays to fit).
        early_out: return C[X] where |v_N| <= EARLY_OUT_SPEED (0.501 px), as the paper does. None (default)
            turns it on for "nearest" only: on the differentiable path it would zero the gradient
            of a velocity that starts small.
        directions: "neighbor" (the paper) or "neighbor_and_own": odd taps along V[X] instead
            (seed 000 sec. 4.3), for neighbourhoods with more than one motion.
        min_radius: speeds |V| below it count as min_radius px (seed 000 sec. 2.2 clamps the
            velocity buffer to at least 0.5 px), so a still pixel has centre weight 1 / min_radius
            rather than an infinite one that would keep blurry foregrounds from covering it.
        adaptive: tiled adaptive sampling (seed 001) with the still-tile early-out: each tile's
            |NeighborMax| picks the fewest taps among a few classes that give one tap per pixel
            travelled (True: 3, 7, 15, ... up to samples; or a tuple of odd counts), and still
            tiles (|NeighborMax| <= 0.001 px, or the early-out's 0.5 px when early_out is on)
            return the image. Tiles of the full-rate class get the full-rate result. On the fused
            kernel each tile takes its class's taps inside the kernel, eagerly and compiled. On the
            tensor ops each class runs on its tiles' pixels only in eager mode; under torch.compile
            or jax.jit every class runs on every pixel and is selected per tile (same result, no
            saving).
        impl: "auto" (default): the fused CPU kernel (`diffblur.kernels.reconstruct`, numba: the
            filter and its backward in one parallel loop each) where it applies, the tensor ops
            elsewhere. "fused": the kernel, or a ValueError naming what it does not cover.
            "tensor": always the tensor ops. The kernel covers CPU float32/float64 images, bilinear
            sampling, the box shutter, a jitter without gradient, adaptive sampling; in PyTorch
            eagerly and under torch.compile (custom operators, one opaque call each in the graph),
            in JAX under jax.jit too (a host callback; reverse mode only: jax.jvp and jax.jacfwd
            need impl="tensor"). Same result and gradients either way (tested); the kernel's
            backward is not differentiable again. Timings: docs/fused.md.

    Returns:
        (B, C, H, W), color's dtype and device.
    """


def reconstruct(be: Any, color: Any, velocity: Any, depth: Any, **options: Any) -> Any:
    """The op: its arguments checked, then the fused kernel or the tensor ops."""
    o = ReconstructOptions.take("reconstruct", options)
    color = checks.image_array(be, "color", color)
    velocity = checks.image_array(be, "velocity", velocity, channels=VECTOR_CHANNELS)
    depth = checks.image_array(be, "depth", depth, channels=DEPTH_CHANNELS)
    checks.require_same_batch_and_size("color", color.shape, [("velocity", velocity.shape), ("depth", depth.shape)])
    checks.same_dtype_and_device(be, "velocity", velocity, "color", color)
    checks.same_dtype_and_device(be, "depth", depth, "color", color)
    velocity = be.check_finite("velocity", velocity)
    depth = be.check_finite("depth", be.check_positive("depth", depth))
    velocity = be.check_finite("color", color, carry=velocity)
    jitter = _jitter(be, o.jitter, color)
    if o.log_depth:  # the band relative to depth: compare log depths (`diffblur.checks.depth_band`)
        depth = be.xp.log(depth)
    if o.impl != "tensor" and takes_kernel("reconstruct", o.impl, be.kernel_reason("reconstruct", color, o, jitter)):
        return be.run_kernel("reconstruct", color, velocity, depth, jitter, o)
    if o.classes is not None:
        return _adaptive_reconstruct(be, color, velocity, depth, jitter, o)
    return _reconstruct(be, color, velocity, depth, jitter, o, o.samples)


def _jitter(be: Any, jitter: str | Any, color: Any) -> Any:
    """The per-pixel jitter j in [-0.5, 0.5), (B or 1, 1, H, W), in color's dtype."""
    _, _, height, width = color.shape
    if isinstance(jitter, str):
        if jitter == "none":
            return be.zeros((1, 1, height, width), color.dtype, color)
        return be.noise_jitter(height, width, color)
    jitter = checks.image_array(be, "jitter", jitter, channels=1)
    checks.require_same_batch_and_size("color", color.shape, [("jitter", jitter.shape)])
    checks.same_dtype_and_device(be, "jitter", jitter, "color", color)
    return jitter


def _choose(be: Any, flag: bool | Any, a: Any, b: Any) -> Any:
    """a where flag, else b: a Python flag picks, a traced one (a scanned tap index) selects."""
    if isinstance(flag, bool):
        return a if flag else b
    return be.xp.where(flag, a, b)


def _tap(be: Any, o: ReconstructOptions, samples: int, read: Any, levels: Pyramid | None, x: Any, y: Any, k: int | Any, *arrays: Any) -> tuple[Any, Any]:
    """Tap k's weight alpha and alpha * C[Y] for every pixel: full images ((B, 1, H, W) positions and
    weights) or a flat list of pixels ((P, 1)); `read(px, py)` gives [C, V, Z] at the taps."""
    xp = be.xp
    z_x, v_n, speed_n, v_x, length_x, speed_x, jitter = arrays
    wide = jitter.dtype
    t = reconstruct_tap_time(k if isinstance(k, int) else be.astype(k, wide), jitter, samples)
    if o.directions == "neighbor_and_own":
        own = k % 2 == 1
        direction, speed = _choose(be, own, v_x, v_n), _choose(be, own, length_x, speed_n)
    else:
        direction, speed = v_n, speed_n
    tap_x = x + direction[:, :1] * t
    tap_y = y + direction[:, 1:] * t
    values = read(tap_x[:, 0], tap_y[:, 0])
    if o.sampling == "nearest":
        distance = xp.hypot(xp.floor(tap_x + 0.5) - x, xp.floor(tap_y + 0.5) - y)
    else:
        distance = xp.abs(t) * speed
    channels = values.shape[1] - 3
    c_y, v_y, z_y = values[:, :channels], values[:, channels : channels + 2], values[:, channels + 2 :]
    if levels is not None:  # the colour from the pyramid level that matches the tap spacing
        c_y = levels.sample(tap_x[:, 0], tap_y[:, 0], levels.level_of_detail(2.0 * speed[:, 0] / (samples + 1)))
    speed_y = at_least(be, safe_length(be, v_y), o.min_radius)
    alpha = (
        soft_depth_compare(be, z_x, z_y, o.band) * cone(be, distance, speed_y)  # blurry Y in front of any X
        + soft_depth_compare(be, z_y, z_x, o.band) * cone(be, distance, speed_x)  # any Y behind blurry X
        + cylinder(be, distance, speed_y) * cylinder(be, distance, speed_x) * 2.0  # both blurry
    ) * shutter_factor(be.widen_window(o.window, wide), -t, samples, xp)
    return be.astype(alpha, wide), be.astype(alpha * c_y, wide)


def _filter(be: Any, o: ReconstructOptions, samples: int, read: Any, levels: Pyramid | None, x: Any, y: Any, c_x: Any, arrays: tuple, *, recompute: bool) -> Any:
    """The filter's normalised sum over the centre and the S - 1 taps, early-out applied. `arrays`:
    z_x, v_n, speed_n, v_x, length_x, speed_x, jitter, all in the wide dtype. recompute: recompute
    each tap in the backward pass (the tap loop of `Backend.sum_taps`) instead of keeping its
    intermediates, so that the backward's memory stays O(pixels), not O(pixels x taps)."""
    speed_n, speed_x, wide = arrays[2], arrays[5], arrays[6].dtype
    center = shutter_factor(be.widen_window(o.window, wide), be.zeros((), wide, c_x), samples, be.xp)
    weight = be.astype(center / speed_x, wide)
    total = weight * c_x

    def tap(k: int | Any, *tap_arrays: Any) -> tuple[Any, Any]:
        return _tap(be, o, samples, read, levels, x, y, k, *tap_arrays)

    taps = [k for k in range(samples) if k != (samples - 1) // 2]
    weight, total = be.sum_taps(tap, taps, (weight, total), arrays, recompute=recompute)
    # In float32 for the half types (weight and total are): the backward divides by weight**2, and
    # a weight of 1 / |V| (1e-4 at 1e4 px) squares to 0 in float16, an infinite gradient.
    out = total / weight
    if o.early_out:
        out = be.xp.where(speed_n <= EARLY_OUT_SPEED, c_x, out)
    return out


def _reconstruct(be: Any, color: Any, velocity: Any, depth: Any, jitter: Any, o: ReconstructOptions, samples: int) -> Any:
    """The filter on full images, by tensor ops. Positions, tap offsets, the classifiers' weights and
    the sums in float32 for a half image (in its dtype else); the buffers read stay in the image's
    dtype, the values read are widened."""
    _, _, height, width = color.shape
    wide = position_dtype(be, color.dtype)
    neighbors = neighbor_max_of_velocity(be, velocity, o.tile)
    v_n = be.astype(be.repeat(be.repeat(neighbors, o.tile, 2), o.tile, 3)[:, :, :height, :width], wide)
    v_x = be.astype(velocity, wide)
    length_x = safe_length(be, v_x)  # the tap offset along V[X] is |t| |V[X]|
    speed_x = at_least(be, length_x, o.min_radius)  # the classifiers' speed, floored as the paper's buffer
    x, y = pixel_grid(be, height, width, color)
    buffers = be.concat([color, velocity, depth], 1)  # read C, V and Z at a tap in one gather
    mode = "bilinear" if o.sampling == "pyramid" else o.sampling
    levels = Pyramid(be, color) if o.sampling == "pyramid" else None
    arrays = (be.astype(depth, wide), v_n, safe_length(be, v_n), v_x, length_x, speed_x, be.astype(jitter, wide))
    read = lambda px, py: sample(be, buffers, px, py, mode)  # noqa: E731
    recompute = be.needs_gradient(color, velocity, depth)
    out = _filter(be, o, samples, read, levels, x[:, None], y[:, None], be.astype(color, wide), arrays, recompute=recompute)
    return be.astype(out, color.dtype)


def _adaptive_reconstruct(be: Any, color: Any, velocity: Any, depth: Any, jitter: Any, o: ReconstructOptions) -> Any:
    """reconstruct with tiled adaptive sampling: its tiles (ceil(max_radius)), speed = |NeighborMax|."""
    _, _, height, width = color.shape
    speed = safe_length(be, neighbor_max_of_velocity(be, be.stop_gradient(velocity), o.tile))[:, 0]
    still = adaptive.still_speed(o.early_out)
    concrete = be.values(speed)
    if concrete is None:  # compiled: every class on every pixel, selected per tile
        counts = adaptive.tile_sample_counts(speed, o.classes, still, be.xp)
        full = {c: _reconstruct(be, color, velocity, depth, jitter, o, c) for c in o.classes}
        return adaptive.select(be, color, full, adaptive.pixel_counts(be, counts, o.tile, height, width))
    found = adaptive.class_rows(be, adaptive.tile_sample_counts(concrete, o.classes, still, np), o.classes, o.tile, color)
    if not found:
        return color
    o = dataclasses.replace(o, jitter="none")  # the jitter array goes in as an argument: `o` keys a cache
    run = adaptive.compiled_if_worth(be, _reconstruct_compacted, found, ("be", "o", "counts"), hashable=_hashable(o))
    return run(be, color, velocity, depth, jitter, tuple(r.read for r in found), tuple(r.write for r in found), o=o, counts=tuple(r.count for r in found))


def _hashable(o: ReconstructOptions) -> bool:
    """Whether the options can key a compiled function's cache (a window whose parameters are
    arrays being fitted cannot)."""
    try:
        hash(o)
    except TypeError:
        return False
    return True


def _reconstruct_compacted(be: Any, color: Any, velocity: Any, depth: Any, jitter: Any, reads: tuple, writes: tuple, *, o: ReconstructOptions, counts: tuple[int, ...]) -> Any:
    """Each class's filter on its pixels only, written into the image: the full-image filter's
    arithmetic on a flat list of pixels, so a full-rate tile gets the same values. The backward
    keeps each tap's intermediates (no per-tap recompute): memory O(moving pixels x taps), which
    the saving usually pays for."""
    batch, channels, height, width = color.shape
    wide = position_dtype(be, color.dtype)
    neighbors = neighbor_max_of_velocity(be, velocity, o.tile)
    buffers = adaptive.table(be, be.concat([color, velocity, depth], 1))
    neighbor_table, jitter_table = adaptive.table(be, neighbors), adaptive.table(be, jitter)
    tiles_y, tiles_x = neighbors.shape[2:]
    out = adaptive.table(be, color)
    for count, read, write in zip(counts, reads, writes):
        base, x, y = adaptive.coordinates(be, read, height, width, color.dtype)
        v_n = be.astype(neighbor_table[adaptive.tile_index(read, height, width, o.tile, tiles_y, tiles_x)], wide)
        own = be.astype(buffers[read], wide)
        c_x, v_x, z_x = own[:, :channels], own[:, channels : channels + 2], own[:, channels + 2 :]
        length_x = safe_length(be, v_x)
        j = be.astype(jitter_table[read if jitter.shape[0] == batch else read % (height * width)], wide)
        arrays = (z_x, v_n, safe_length(be, v_n), v_x, length_x, at_least(be, length_x, o.min_radius), j)
        rows = lambda px, py, base=base: adaptive.sample_rows(be, buffers, base, px, py, height, width, o.sampling)  # noqa: E731
        values = _filter(be, o, count, rows, None, x[:, None], y[:, None], c_x, arrays, recompute=False)
        out = be.write_rows(out, write, be.astype(values, color.dtype))
    return adaptive.untable(be, out, batch, height, width)
