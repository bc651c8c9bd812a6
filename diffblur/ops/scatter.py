"""`bezier_scatter`: the curve scatter of seed 003 (Guertin & Nowrouzezahrai 2015), every moving pixel
splatting its colour along a Bezier curve (or a circular arc) through its positions over the
exposure. Options, docstring and math, for both frameworks; the NumPy reference
(`diffblur.reference.bezier_scatter`) resolves its options here too, so the three accept the same
arguments, count points the same way and place them at the same instants.

Paths. Each moving pixel X follows a path p(t) over the exposure t in [-1, 1], in image coordinates:

| path | given | p(t) |
|---|---|---|
| degree 1 | offset_prev, offset_next | the segment from X + offset_prev to X + offset_next |
| degree 2 | offset_prev, offset_next | the quadratic Bezier through X + offset_prev, X, X + offset_next at t = -1, 0, 1 |
| degree 3 | + offset_mid_prev | the cubic through those and X + offset_mid_prev at t = MID_PREV_TIME = -1/2 |
| arc | arc_center, arc_angle | c + R(angle t) (X - c): a rotation about c by `angle` radians at t = 1 |

Points. A curve carries `count` points at the midpoints t_k of `count` equal strata of the exposure;
point k carries the shutter's exact mass m_k on its stratum (renormalised to sum to 1), as the gather
does (`diffblur.ops.taps`). The automatic count is one point per pixel of the longest curve, capped.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import warnings
from typing import Any

import numpy as np

from diffblur import checks, conventions
from diffblur.conventions import DEPTH_CHANNELS, VECTOR_CHANNELS
from diffblur.ops._options import OpOptions, impl_option, takes_kernel
from diffblur.ops.primitives import soft_depth_compare
from diffblur.ops.sampling import pixel_grid, position_dtype, sample
from diffblur.ops.taps import stratum_weights
from diffblur.shutters import ShutterWindow, get_shutter

__all__ = [
    "COMPOSITES",
    "DEFAULT_BACKGROUND_WEIGHT",
    "DEFAULT_COMPOSITE",
    "DEFAULT_FILL",
    "DEFAULT_MAX_SAMPLES",
    "DEFAULT_NORMALIZATION",
    "DEFAULT_RELATIVE_Z_EXTENT",
    "DEFAULT_SHUTTER",
    "DEGREES",
    "DOC",
    "FILLS",
    "LENGTH_SEGMENTS",
    "MID_PREV_TIME",
    "NORMALIZATIONS",
    "ScatterOptions",
    "bezier_scatter",
    "constant_masses",
    "curve_point",
    "curve_position",
    "has_constant_parameters",
    "length_times",
    "moving_mask",
    "no_still_message",
    "point_count",
    "point_masses",
    "point_times",
    "polyline_length",
    "resolve_path",
    "traced_count_message",
    "warn_without_still",
]

#: "coverage": every moving point spreads total weight 1 over its exposure (its time density); a pixel
#: keeps its own colour for the fraction of the exposure nothing covers it, and where coverage exceeds
#: 1 the sum is normalised. "paper": seed 003 eq. 4, (A + w_b c) / (alpha + w_b), with weights per
#: pixel of path length (as rasterised lines deposit them) and a constant background weight w_b.
NORMALIZATIONS = ("coverage", "paper")
#: Measured on the translate, propeller and gears presets (128 x 128, box shutter, degree 2):
#: "coverage" is 1.6, 1.0 and 0.25 dB (PSNR) closer to the ground truth than "paper", and 21, 19 and
#: 14 dB closer with the background layer.
DEFAULT_NORMALIZATION = "coverage"
#: What a moving pixel shows for the part of the exposure nothing covers it (an array: the static
#: scene behind the moving objects, seed 003 sec. 5.1's two-layer extension). "still": an estimate of the scene behind it from the pixels that do not move, filled in by
#: push-pull (Gortler et al. 1996: sums of colour and weight pooled 2 x 2 down to one pixel, then each
#: level's mean where it has weight, blended with the coarser level bilinearly upsampled where it has
#: less than one pixel's weight). Where the image has no still pixel (a moving camera), with
#: composite="instants": each instant's own push-pull (`COMPOSITES`); with
#: composite="layers": the splats that pass behind the pixel, weighed against its own colour as
#: (A_behind + m color) / (alpha_behind + m), m = 1 / samples (one point's mean mass), so that
#: wherever something passes behind it, that is what it uncovers; with "sum", its own colour.
#: "color": the moving pixel's own colour (it fills its uncovered time with itself).
FILLS = ("still", "color")
#: Measured (box shutter, degree 2, coverage normalisation, PSNR against the accumulation ground
#: truth): "still" is 3.4 to 7.8 dB closer than "color" (and 3.8 to 7.5 dB closer than the linear
#: gather) on propeller (48 x 48 at 0.3, 0.6, 0.9, 1.4 rad; 128 x 128), translate, gears and crossing
#: (128 x 128), SSIM higher on each; equal on pan, which has no still pixel. It removes 55 to 89 % of
#: the squared error that the true background removes.
DEFAULT_FILL = "still"
#: How normalization="coverage" composites the splats. "instants": every point time on its own, as a
#: camera sees it: at instant t_k each pixel shows the nearest of the moving points that land on it
#: at t_k (a splat counts where its source is within the depth band behind the nearest one there
#: with bilinear weight above NEAREST_SPLAT_WEIGHT; on a still pixel only where seed 003's depth
#: test against it passes, the still pixel being the layer behind), the other splats in the part of
#: the pixel those leave, then what passes behind the pixel over the exposure (the behind splats of
#: "layers") over the fill, unless the pixel's object goes on there behind a nearer surface: where
#: the point of its own path at -t (the point that reaches the pixel at t) lies more than the depth
#: band behind the sharp frame's surface there, the pixel shows its own colour (`_going_on_behind`);
#: the instants summed by the shutter's masses. With fill="still"
#: in an image without a still pixel (a moving camera), each instant's uncovered pixels take a
#: push-pull of that instant's own picture, its pixels weighted by coverage x (depth / farthest
#: depth)^UNCOVERED_DEPTH_POWER: what an instant uncovers lies behind what surrounds it.
#: "layers": front to back, each layer over what is behind it by its coverage (A + (1 - alpha) behind
#: where alpha <= 1, A / alpha where alpha > 1): the splats from sources nearer than the depth band in
#: front, those level with the pixel (within the band), those from behind it (which the depth test
#: of seed 003 drops: they are what the pixel shows once its own surface has moved off it), then the
#: fill. "sum": seed 003's one sum of the splats the depth test passes (no depth write), over the
#: fill. In "layers" and "sum" still pixels are their own level layer, in front of what passes behind
#: them, and keep the sum.
COMPOSITES = ("instants", "layers", "sum")
DEFAULT_COMPOSITE = "instants"
#: composite="instants": the bilinear weight above which a splat sets the nearest depth of the pixel
#: it lands on (a corner's faint share of a point from a nearer surface does not hide the surface
#: that covers the pixel).
NEAREST_SPLAT_WEIGHT = 0.25
#: composite="instants" with fill="still" and no still pixel: the power of depth / farthest depth
#: that weighs an instant's pixels in the push-pull of what it uncovers.
UNCOVERED_DEPTH_POWER = 3.0
#: Bezier degrees: 1 (segment), 2 (seed 003's quadratic), 3 (seed 003 sec. 5.1's cubic).
DEGREES = (1, 2, 3)
#: The project's one default shutter (`diffblur.conventions.DEFAULT_SHUTTER`, the box), as the other
#: ops. Seed 003 weighs the points of a curve with a Gaussian; pass shutter="gaussian" for that.
DEFAULT_SHUTTER = conventions.DEFAULT_SHUTTER
#: Cap of the automatic point count (one point per pixel of the longest curve).
DEFAULT_MAX_SAMPLES = 32
#: A splat counts fully where its source is in front of the destination or level with it, fading to
#: nothing a fraction DEFAULT_RELATIVE_Z_EXTENT of the destination's depth behind (or
#: `soft_z_extent` depth units behind when that is given); the same default as reconstruct's.
DEFAULT_RELATIVE_Z_EXTENT = conventions.DEFAULT_RELATIVE_Z_EXTENT
#: Seed 003's w_b (sec. 4), used by normalization="paper".
DEFAULT_BACKGROUND_WEIGHT = 5.0
#: The instant of the cubic's extra position (seed 003 sec. 5.1 names t = -1/2 or t = -2).
MID_PREV_TIME = -0.5
#: Segments of the polyline that measures a curve's length for the automatic point count.
LENGTH_SEGMENTS = 16


def resolve_path(
    degree: object,
    *,
    offset_prev: bool,
    offset_next: bool,
    offset_mid_prev: bool,
    arc_center: bool,
    arc_angle: bool,
) -> str:
    """'bezier' or 'arc', from the degree and which of the optional fields were given (True = given)."""
    degree = checks.require_int_choice("degree", degree, DEGREES)
    if arc_center or arc_angle:
        if not (arc_center and arc_angle):
            missing = "arc_angle" if arc_center else "arc_center"
            raise ValueError(f"arc_center and arc_angle must be given together, got {missing}=None")
        given = [n for n, g in (("offset_prev", offset_prev), ("offset_next", offset_next), ("offset_mid_prev", offset_mid_prev)) if g]
        if given:
            raise ValueError(
                f"{given[0]} must be None with arc_center and arc_angle (the arc is the path), got an array"
            )
        if degree != 2:
            raise ValueError(f"degree applies to Bezier paths and must stay 2 with arc_center and arc_angle, got {degree}")
        return "arc"
    for name, given_field in (("offset_prev", offset_prev), ("offset_next", offset_next)):
        if not given_field:
            raise ValueError(f"{name} must be a (B, 2, H, W) array (or pass arc_center and arc_angle), got None")
    if degree == 3 and not offset_mid_prev:
        raise ValueError(
            "offset_mid_prev must be a (B, 2, H, W) array with degree=3 (where the point is at t = -1/2, "
            "relative to X), got None"
        )
    if degree != 3 and offset_mid_prev:
        raise ValueError(f"offset_mid_prev is used only with degree=3, got degree={degree}")
    return "bezier"


@dataclasses.dataclass(frozen=True)
class ScatterOptions(OpOptions):
    """bezier_scatter's options, checked; the window and the background (an array fill) resolved."""

    degree: int = 2
    samples: int | None = None
    max_samples: int = DEFAULT_MAX_SAMPLES
    shutter: str | ShutterWindow = DEFAULT_SHUTTER
    normalization: str = DEFAULT_NORMALIZATION
    fill: str | Any = DEFAULT_FILL
    background_weight: float = DEFAULT_BACKGROUND_WEIGHT
    soft_z_extent: float | Any | None = None
    relative_z_extent: float | Any = DEFAULT_RELATIVE_Z_EXTENT
    composite: str = DEFAULT_COMPOSITE
    impl: str = "auto"
    window: ShutterWindow = dataclasses.field(init=False, repr=False)
    #: The array given as `fill` (the static scene behind), or None for fill="still" / "color".
    background: Any = dataclasses.field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._resolve("degree", checks.require_int_choice("degree", self.degree, DEGREES))
        if self.samples is not None:
            self._resolve("samples", checks.require_positive_int("samples", self.samples))
        self._resolve("max_samples", checks.require_positive_int("max_samples", self.max_samples))
        self._resolve("normalization", checks.require_choice("normalization", self.normalization, NORMALIZATIONS))
        background_weight = checks.require_positive_number("background_weight", self.background_weight)
        if math.isinf(background_weight):
            raise ValueError(f"background_weight must be finite, got {background_weight}")
        self._resolve("background_weight", background_weight)
        self._resolve("composite", checks.require_choice("composite", self.composite, COMPOSITES))
        if isinstance(self.fill, str):
            self._resolve("fill", checks.require_choice("fill", self.fill, FILLS))
            self._resolve("background", None)
        else:
            self._resolve("background", self.fill)
        self._resolve("window", get_shutter(self.shutter))
        self._resolve("impl", impl_option(self.impl))


def point_times(count: int) -> tuple[float, ...]:
    """Midpoints of `count` equal strata of [-1, 1], as Python floats (constants to a compiler)."""
    return tuple((2.0 * k + 1.0) / count - 1.0 for k in range(count))


def point_masses(window: ShutterWindow, times: Any, count: int, xp: Any) -> Any:
    """The shutter's mass on each point's stratum, renormalised to sum to 1 (differentiable in the
    window's parameters when they are `xp` arrays)."""
    masses = stratum_weights(window, times, 1.0 / count, xp)
    return masses / masses.sum()


def has_constant_parameters(window: ShutterWindow) -> bool:
    """Whether every parameter of the window is a Python or NumPy number (none is a tensor to fit).

    Such a window's masses are constants, best computed once in NumPy float64: the Gaussian's erf is a
    160-term series in the backends, which compilers unroll at great cost."""
    parameters = [getattr(window, f.name) for f in dataclasses.fields(window)] if dataclasses.is_dataclass(window) else []
    return all(isinstance(p, (numbers.Real, np.ndarray)) for p in parameters)


def constant_masses(window: ShutterWindow, count: int) -> tuple[float, ...]:
    """point_masses of a window with constant parameters, as Python floats (float64 arithmetic)."""
    masses = point_masses(window, np.asarray(point_times(count)), count, np)
    return tuple(float(m) for m in masses)


def length_times() -> tuple[float, ...]:
    """The instants of the polyline that measures a curve's length: LENGTH_SEGMENTS + 1 from -1 to 1."""
    return tuple(-1.0 + 2.0 * k / LENGTH_SEGMENTS for k in range(LENGTH_SEGMENTS + 1))


def curve_position(kind: str, terms: tuple, x: Any, y: Any, t: Any, xp: Any) -> tuple[Any, Any]:
    """Positions (px, py) at the times t, in `xp` ops (torch or jax.numpy): t (K, 1, 1, 1) gives
    (K, B, H, W) each; a float, (1, B, H, W).

    x, y: (1, 1, H, W) pixel centres. kind "bezier": terms = (constant, linear, quadratic, cubic), each
    (B, 2, H, W) or None (the power-basis coefficients of the offset p(t) - X); "arc": terms =
    (center, angle)."""
    if kind == "arc":
        center, angle = terms
        cx, cy, a = center[None, :, 0], center[None, :, 1], angle[None, :, 0]
        rx, ry = x - cx, y - cy
        cos, sin = xp.cos(a * t), xp.sin(a * t)
        return cx + cos * rx - sin * ry, cy + sin * rx + cos * ry
    constant, linear, quadratic, cubic = terms
    positions = []
    for axis, start in ((0, x), (1, y)):
        offset = linear[None, :, axis] * t
        if quadratic is not None:
            offset = offset + quadratic[None, :, axis] * (t * t)
        if cubic is not None:
            offset = offset + cubic[None, :, axis] * (t * t * t)
        if constant is not None:
            offset = offset + constant[None, :, axis]
        positions.append(start + offset)
    return positions[0], positions[1]


def curve_point(kind: str, terms: tuple, x: Any, y: Any, t: Any, xp: Any) -> tuple[Any, Any, Any, Any]:
    """`curve_position` and the velocities dp/dt: (px, py, vx, vy), a velocity constant in t
    (1, B, H, W)."""
    px, py = curve_position(kind, terms, x, y, t, xp)
    if kind == "arc":
        center, angle = terms
        a = angle[None, :, 0]
        return px, py, -a * (py - center[None, :, 1]), a * (px - center[None, :, 0])
    _, linear, quadratic, cubic = terms
    velocities = []
    for axis in (0, 1):
        velocity = linear[None, :, axis]
        if quadratic is not None:
            velocity = velocity + quadratic[None, :, axis] * (2.0 * t)
        if cubic is not None:
            velocity = velocity + cubic[None, :, axis] * (3.0 * t * t)
        velocities.append(velocity)
    return px, py, velocities[0], velocities[1]


def polyline_length(kind: str, terms: tuple, x: Any, y: Any, xp: Any, hypot: Any) -> Any:
    """Each curve's length in pixels (1, B, H, W) along the polyline through its positions at
    `length_times`, in `xp` ops, `hypot(dx, dy)` per piece. The pieces are added one at a time, on
    positions alone: all LENGTH_SEGMENTS + 1 points at once, with velocities, took 5x longer at 720p.
    The instants are multiples of 1/8, so t, t^2 and t^3 are exact as floats in any dtype."""
    length, previous = None, None
    for time in length_times():
        px, py = curve_position(kind, terms, x, y, time, xp)
        if previous is not None:
            piece = hypot(px - previous[0], py - previous[1])
            length = piece if length is None else length + piece
        previous = (px, py)
    return length


def moving_mask(kind: str, offsets: tuple, x: Any, y: Any) -> Any:
    """(B, H, W) bool, in the arrays' own ops (NumPy, torch or jax.numpy): the pixels whose point moves
    more than `diffblur.conventions.STILL_SPEED` px. The rest are still: they splat nothing and, with
    fill="still", are the scene behind the moving ones. Float leftovers of a renderer (1e-6 px) on a
    static surface leave it still.

    kind "bezier": offsets = the (B, 2, H, W) offsets given (t = -1, +1 and, for the cubic, -1/2);
    moving where any is longer than STILL_SPEED. "arc": offsets = (center (B, 2, H, W), angle
    (B, 1, H, W)); moving where |angle| * radius, the arc length to t = 1, exceeds it. x, y: pixel
    centres broadcasting against (B, H, W)."""
    limit = conventions.STILL_SPEED**2
    if kind == "arc":
        center, angle = offsets
        dx, dy = x - center[:, 0], y - center[:, 1]
        return angle[:, 0] * angle[:, 0] * (dx * dx + dy * dy) > limit
    moving = None
    for offset in offsets:
        far = offset[:, 0] * offset[:, 0] + offset[:, 1] * offset[:, 1] > limit
        moving = far if moving is None else moving | far
    return moving


#: Whether `warn_without_still` has warned in this process.
_warned_without_still = False


def warn_without_still(moving: np.ndarray) -> None:
    """Warn that fill="still" found no still pixel in an image of the batch (it then fills with what
    passes behind each pixel, weighed against its own colour, or as fill="color"); moving is the (B, H, W) `moving_mask` as NumPy. Once per process: a fit calls
    the scatter hundreds of times on the same images (`fitting`'s global model moves every pixel),
    and one warning says what there is to say."""
    global _warned_without_still
    if _warned_without_still:
        return
    message = no_still_message(moving)
    if message is not None:
        _warned_without_still = True
        warnings.warn(message, UserWarning, stacklevel=checks.caller_stacklevel())


def no_still_message(moving: np.ndarray) -> str | None:
    """The warning for fill="still" when an image of the batch has no still pixel, else None; moving is
    the (B, H, W) `moving_mask` as NumPy."""
    images = [b for b in range(moving.shape[0]) if moving[b].all()]
    if not images:
        return None
    return (
        f"bezier_scatter(fill='still') found no still pixel (one that moves at most "
        f"STILL_SPEED={conventions.STILL_SPEED} px) in image(s) {images} of the batch: every moving pixel "
        f"there fills its uncovered time from the rest of the picture (composite='instants': each instant's "
        f"own splats, the farther first; 'layers': what passes behind it), else with its own colour, as "
        f"fill='color'. Pass fill='color' to say so, or the scene behind as fill=<array> (warned once per process)"
    )


def point_count(max_length: float, max_samples: int) -> int:
    """One point per pixel of the longest curve (`max_length` pixels), at least 1, at most max_samples."""
    if not math.isfinite(max_length):
        return max_samples
    return int(min(max(math.ceil(max_length), 1), max_samples))


def traced_count_message(where: str) -> str:
    """The error for samples=None where the values are not known (`where`: "under jax.jit", "on meta
    arrays"): the count sets shapes and must be a Python int."""
    return (
        f"samples=None measures the curves to choose the point count, which needs concrete arrays; "
        f"{where} pass samples=<int> (a static count, e.g. max_samples)"
    )


DOC = """Scatter every moving pixel's colour along its curved path over the exposure (seed 003).

    Each pixel X whose point moves follows a path p(t), t in [-1, 1]: a Bezier curve through its
    positions X + offset_prev (t = -1), X (t = 0) and X + offset_next (t = 1), with the control point
    B1 = 2 p(0) - (p(-1) + p(1)) / 2 so that B(1/2) = p(0) (seed 003's erratum fixed); or a circular
    arc. `samples` points at the midpoints t_k of equal strata of the exposure, each carrying the
    shutter's mass m_k on its stratum, are splatted bilinearly (differentiable in the positions) onto
    the pixels around them, where the source is in front of or within the depth band behind the
    destination's depth (seed 000's softDepthCompare; no depth write), and summed into A (colour)
    and alpha (weight). Still pixels, whose point moves at most `diffblur.conventions.STILL_SPEED`
    px (a renderer's float leftovers included), splat nothing (a mask: shapes never depend on data).

    Normalisation, with f = color where the pixel is still and, where it moves, the `fill`:

    - "coverage" (default): every moving point spreads total weight 1 over its exposure, so alpha is
      the fraction of the exposure something covers the pixel; out = A + (1 - alpha) f where
      alpha <= 1, A / alpha where alpha > 1. Closer to the ground truth than "paper" on the
      presets measured, with every fill (docs/methods.md). That is composite="sum"; the default
      composite="instants" instead depth-tests each instant on its own, see `composite`.
    - "paper": seed 003 eq. 4, out = (A + w_b f) / (alpha + w_b), with the points weighted per
      pixel of path length (2 m_k |p'(t_k)|, 1 per pixel for the box shutter), as rasterised lines
      deposit them, and w_b = `background_weight`.

    Args:
        color: (B, C, H, W) the sharp frame (t = 0), linear intensities, any C.
        depth: (B, 1, H, W) positive depth, larger = farther.
        offset_prev, offset_next: (B, 2, H, W) pixels, where the point seen at X is at t = -1 and
            t = +1, relative to X (channel 0 = x); linear motion is (-V, +V). None with an arc.
        offset_mid_prev: (B, 2, H, W) pixels, where the point is at t = -1/2 relative to X; required
            by degree=3 (seed 003 sec. 5.1's extra motion pass), refused otherwise.
        arc_center, arc_angle: (B, 2, H, W) image coordinates (pixels) of the centre of rotation and
            (B, 1, H, W) radians at t = 1, given together instead of the offsets: the point follows
            c + R(angle t) (X - c), a rotation by 2 angle over the exposure, positive turning +x
            towards +y (as `diffblur.scenes.Rotation`). No quadratic follows a circle exactly.
        degree: 1 (the segment from X + offset_prev to X + offset_next), 2 (the quadratic Bezier
            through the three positions) or 3 (the cubic through them and X + offset_mid_prev).
        samples: points per curve, an int >= 1, the same for every curve; None picks one per pixel of
            the longest curve, at most `max_samples` (eager only: it measures the data; under
            torch.compile or jax.jit pass an int). Curves longer than the count in pixels are dotted.
        max_samples: the cap of the automatic count, an int >= 1.
        shutter: a name in `diffblur.shutters.SHUTTERS` or a `ShutterWindow` whose parameters may be
            arrays to fit. Default: the box, as every op (`diffblur.conventions.DEFAULT_SHUTTER`);
            seed 003 weighs its curves with a Gaussian (shutter="gaussian").
        normalization: "coverage" or "paper" (above).
        fill: what a moving pixel shows for the part of the exposure nothing covers it. "still"
            (default): an estimate of the scene behind it from the pixels that do not move
            (push-pull: the still pixels' colours averaged over 2 x 2 blocks down to one pixel, then
            filled back in from coarse to fine where a block has no still pixel; the pixel's own
            colour where the image has none, with a UserWarning in eager mode, once per process;
            there composite="instants" fills each instant from its own picture and "layers" with
            what passes behind the pixel, see `composite`). "color": its own colour. A (B, C, H, W) array: the static scene behind the
            moving objects (seed 003 sec. 5.1's two-layer extension). "still" is the default because
            a moving object uncovers what is behind it, which the still pixels show better than the
            object's own colour does (measured on the presets: docs/methods.md). Still pixels in
            front of moving ones count as background too.
        background_weight: seed 003's w_b, a number > 0 (used by "paper").
        soft_z_extent: the depth band in depth units, a number > 0 or a 0-d array (differentiable);
            None (default): the band relative to depth, `relative_z_extent`.
        relative_z_extent: with soft_z_extent=None, the band as a fraction of the destination's
            depth, a number > 0 or a 0-d array: a splat counts fully up to level with the
            destination, fading linearly in log depth to nothing at z_source = z_dest (1 + r), so
            that the output does not depend on the scene's depth units.
        composite: how "coverage" composites the splats. "instants" (default): each point time on
            its own, as the camera sees it: at instant t_k every moving pixel's point lands where
            it is then, each pixel shows the nearest of the points on it (within the depth band
            behind the nearest splat weighing more than NEAREST_SPLAT_WEIGHT = 1/4; on a still
            pixel, the layer behind, only those that pass seed 003's depth test against it), the
            part of the pixel they leave shows the others up to their coverage, and the rest what
            passes behind the pixel over the exposure (the behind splats of "layers") over the fill
            (a still pixel: itself); but where the point of the pixel's own path at -t (the one
            that reaches it at t) lies more than the depth band behind a nearer surface of the
            sharp frame, its object goes on behind that surface and the pixel shows its own colour
            (by the soft depth compare, the depth read bilinearly); the instants are summed by the
            shutter's masses.
            Where fill="still" finds no still pixel in an image (a moving camera), an instant's
            uncovered pixels take a push-pull of that instant's own picture, its pixels weighted by
            coverage x (depth / farthest depth)^3: what a moving camera uncovers lies behind what
            surrounds it. "layers": front to back over the whole exposure, each layer over what is
            behind it by its coverage: the splats from sources nearer than the depth band in front,
            those level with the pixel, those from behind it (which a depth test without depth
            write drops; they are what the pixel shows once its own surface has moved off it), then
            the fill; without a still pixel the behind splats are weighed against the pixel's own
            colour as (A_behind + m C) / (alpha_behind + m), m = 1 / samples. "sum": seed 003's one
            sum of the splats the depth test passes, over the fill, where splats that overlap in the
            exposure are averaged whatever their depth. Still pixels keep the sum in "layers" and
            "sum" (their own level layer, in front of what passes behind them); "paper" has no
            composite. "instants" splats twice on the kernel (what passes behind), then each instant's
            nearest layer and splats once; "layers" three times. Measured in docs/defaults.md.
        impl: "auto" (default): the splats and their backward on the fused CPU kernel
            (`diffblur.kernels.scatter`, numba: one parallel loop each, O(pixels) memory) where it
            applies, the tensor ops elsewhere; the normalisation, the fill and composite="instants"'s
            composite of each instant (and its push-pull where an image lacks a still pixel) stay
            tensor ops.
            "fused": the kernel, or a ValueError naming what it does not cover. "tensor": always
            the tensor ops. The kernel covers CPU float32/float64 images, every path and shutter;
            in PyTorch eagerly and under torch.compile (custom operators), in JAX under jax.jit and
            jax.vmap too (a host callback; reverse mode only: jax.jvp and jax.jacfwd need
            impl="tensor"). Same result and gradients either way (tested); the kernel's backward is
            not differentiable again. Timings: docs/fused.md.

    Returns:
        (B, C, H, W), color's dtype. Splats beyond the border are lost. On the tensor ops points are
        splatted in chunks of about 2^18 pixel-points; with several chunks the backward recomputes
        each chunk (activation checkpointing), so its memory is O(pixels), not O(pixels x samples).
    """

#: Points are splatted in chunks of about this many pixel-points (B H W x points of the chunk): one
#: scatter-add per chunk. With more than one chunk the backward recomputes each chunk's splats
#: (activation checkpointing), so it keeps O(pixels) memory, not O(pixels x samples).
CHUNK_PIXEL_POINTS = 1 << 18

#: composite="instants" takes instants in chunks of CHUNK_PIXEL_POINTS // (share x padded pixels):
#: the share is in proportion to the numbers an instant keeps per pixel for the backward (`_instants`).
INSTANT_SHARE_TENSOR = 16
INSTANT_SHARE_FUSED = 5

#: The static arguments of the scatter's core (`_scatter`), which JAX compiles whole.
CORE_STATIC = ("be", "kind", "degree", "paper", "background_weight", "fill", "composite", "fill_from_instants", "log_depth", "fused")


def bezier_scatter(
    be: Any, color: Any, depth: Any, offset_prev: Any, offset_next: Any, *, offset_mid_prev: Any = None, arc_center: Any = None, arc_angle: Any = None, **options: Any
) -> Any:
    """The op, for a backend: its arguments checked, then the splats and their composite."""
    o = ScatterOptions.take("bezier_scatter", options)
    color = checks.image_array(be, "color", color)
    depth = checks.image_array(be, "depth", depth, channels=DEPTH_CHANNELS)
    paths = {"offset_prev": offset_prev, "offset_next": offset_next, "offset_mid_prev": offset_mid_prev, "arc_center": arc_center, "arc_angle": arc_angle}
    kind = resolve_path(o.degree, **{name: value is not None for name, value in paths.items()})
    given = {}
    for name, value in paths.items():
        if value is not None:
            given[name] = checks.image_array(be, name, value, channels=1 if name == "arc_angle" else VECTOR_CHANNELS)
    checks.require_same_batch_and_size("color", color.shape, [("depth", depth.shape), *((n, v.shape) for n, v in given.items())])
    for name, value in (("depth", depth), *given.items()):
        checks.same_dtype_and_device(be, name, value, "color", color)
    background = o.background
    if background is not None:
        background = checks.image_array(be, "fill", background)
        checks.same_shape(be, "fill", background, "color", color)
    relative, band = checks.depth_band(o.soft_z_extent, o.relative_z_extent)
    extent = _extent(be, band, depth, "relative_z_extent" if relative else "soft_z_extent")
    depth = be.check_finite("depth", be.check_positive("depth", depth))
    if relative:  # the band relative to depth: compare log depths (`diffblur.checks.depth_band`)
        depth = be.xp.log(depth)
        extent = be.xp.log1p(extent) if be.is_array(extent) else math.log1p(extent)
    given = {name: be.check_finite(name, value) for name, value in given.items()}
    depth = be.check_finite("color", color, carry=depth)
    if background is not None:
        depth = be.check_finite("fill", background, carry=depth)
    fused = o.impl != "tensor" and takes_kernel("bezier_scatter", o.impl, be.kernel_reason("bezier_scatter", color, o))
    # Positions, offsets, splat weights and the sums in float32 for a half image (its dtype else).
    wide = position_dtype(be, color.dtype)
    given = {name: be.astype(value, wide) for name, value in given.items()}
    samples = o.samples if o.samples is not None else point_count(_longest(be, kind, _terms(kind, o.degree, given), color), o.max_samples)
    # Whether composite="instants" needs each instant's own fill (an image without a still pixel).
    fill_from_instants = o.fill == "still" and background is None and _warn_without_still(be, kind, o.degree, given, color)
    if has_constant_parameters(o.window):
        masses = be.asarray(be.constant(constant_masses, o.window, samples), wide, color)
    else:  # a shape parameter being fitted: the masses carry its gradient
        times = be.asarray(point_times(samples), wide, color)
        masses = be.astype(point_masses(be.widen_window(o.window, wide), times, samples, be.xp), wide)
    core = be.compiled(_scatter, CORE_STATIC)
    return core(
        be,
        color,
        depth,
        given,
        masses,
        extent,
        background,
        kind=kind,
        degree=o.degree,
        paper=o.normalization == "paper",
        background_weight=o.background_weight,
        fill=o.fill if background is None else "array",
        composite=o.composite,
        fill_from_instants=fill_from_instants,
        log_depth=relative,
        fused=fused,
    )


def _extent(be: Any, value: object, like: Any, name: str) -> Any:
    """The depth band (soft_z_extent or relative_z_extent, `name`): a number > 0 (in the form the
    backend computes with, `Backend.band`) or a 0-d array > 0 (kept, so that it gets a gradient)."""
    if be.is_array(value):
        value = checks.floating_array(be, name, value)
        if value.ndim != 0:
            raise ValueError(f"{name} must be a number or a 0-d {be.array_word}, got shape {tuple(value.shape)}")
        checks.same_dtype_and_device(be, name, value, "depth", like)
        return be.check_positive(name, value)
    return be.band(checks.require_positive_number(name, value), like)


def _bezier_terms(degree: int, prev: Any, nxt: Any, mid: Any) -> tuple:
    """Power-basis coefficients (constant, linear, quadratic, cubic) of the Bezier through the given
    positions: the offset p(t) - X is their polynomial in t."""
    half_sum, half_difference = 0.5 * (nxt + prev), 0.5 * (nxt - prev)
    if degree == 1:
        return (half_sum, half_difference, None, None)
    if degree == 2:  # p(-1) = X + prev, p(0) = X, p(1) = X + next
        return (None, half_difference, half_sum, None)
    # The cubic also meets X + mid at tau: c (tau^3 - tau) = mid - h tau - b tau^2 with a = h - c.
    tau = MID_PREV_TIME
    cubic = (mid - half_difference * tau - half_sum * (tau * tau)) / (tau**3 - tau)
    return (None, half_difference - cubic, half_sum, cubic)


def _terms(kind: str, degree: int, given: dict) -> tuple:
    if kind == "arc":
        return (given["arc_center"], given["arc_angle"])
    return _bezier_terms(degree, given["offset_prev"], given["offset_next"], given.get("offset_mid_prev"))


def _moved_by(kind: str, degree: int, given: dict) -> tuple:
    """What `moving_mask` reads: the offsets given, or the arc's (center, angle)."""
    if kind == "arc":
        return (given["arc_center"], given["arc_angle"])
    return (given["offset_prev"], given["offset_next"]) + ((given["offset_mid_prev"],) if degree == 3 else ())


def _safe_hypot(be: Any, a: Any, b: Any) -> Any:
    xp = be.xp
    squared = a * a + b * b
    positive = squared > 0
    return xp.where(positive, xp.sqrt(xp.where(positive, squared, 1.0)), 0.0)


def _longest(be: Any, kind: str, terms: tuple, like: Any) -> float:
    """Length in pixels of the longest curve (`polyline_length`), measured on the data: concrete
    arrays only."""
    x, y = pixel_grid(be, like.shape[2], like.shape[3], like)
    terms = tuple(None if term is None else be.stop_gradient(term) for term in terms)
    longest = be.values(polyline_length(kind, terms, x[None], y[None], be.xp, be.xp.hypot).max())
    if longest is None:  # traced, on a device without values (PyTorch's meta device), or not to be read
        if be.is_tracing(like):
            where = f"under {be.compiler}"
        elif not checks.host_reads_allowed():
            where = "inside diffblur.without_host_reads()"
        else:
            where = f"on {like.device} arrays"
        raise ValueError(traced_count_message(where))
    return float(longest)


def _warn_without_still(be: Any, kind: str, degree: int, given: dict, like: Any) -> bool:
    """fill="still"'s warning when an image has no still pixel, eager only (concrete arrays); whether
    an image may have none (True where the arrays are not concrete)."""
    moved = [be.values(value) for value in _moved_by(kind, degree, given)]
    if any(value is None for value in moved):
        return True
    y, x = np.mgrid[0 : like.shape[2], 0 : like.shape[3]].astype(np.float64)
    moving = moving_mask(kind, tuple(np.asarray(m, dtype=np.float64) for m in moved), x[None], y[None])
    warn_without_still(moving)
    return bool(moving.reshape(moving.shape[0], -1).all(1).any())


def _splat(be: Any, paper: bool, kind: str, times: Any, masses: Any, terms: tuple, x: Any, y: Any, rows: Any, depth: Any, extent: Any, moving: Any) -> Any:
    """The splats of every curve's points at `times` (K,) with `masses` (K,), one scatter-add for the
    K points: (B * (H + 2) * (W + 2), C + 1) sums of omega * [color, 1] on the image padded by a ring
    of one pixel, which catches the corners just outside the image (the caller crops it)."""
    xp = be.xp
    px, py, vx, vy = curve_point(kind, terms, x, y, times.reshape(-1, 1, 1, 1), xp)
    points = px.shape[0]
    weight = xp.where(moving[None], masses.reshape(-1, 1, 1, 1), 0.0)
    if paper:  # weight per pixel of path length: |dp| = |dp/dt| dt, with dt = 2 / count ~ 2 mass
        weight = weight * (2.0 * _safe_hypot(be, vx, vy))
    index, bilinear, near = _padded_corners(be, px, py, per_point=False, like=rows)
    weight = xp.where(near, weight, 0.0)
    padded_depth = be.pad(depth, ((0, 0), (0, 0), (1, 1), (1, 1)), mode="edge")
    destination_depth = padded_depth.reshape(-1)[index].reshape(bilinear.shape)
    in_front = be.astype(soft_depth_compare(be, destination_depth, depth[None, None, :, 0], extent), bilinear.dtype)
    omega = bilinear * in_front * weight[None]
    values = (omega.reshape(4 * points, -1, 1) * rows[None]).reshape(-1, rows.shape[1])
    return be.scatter_add(math.prod(padded_depth.shape), index, values)


def _padded_corners(be: Any, px: Any, py: Any, *, per_point: bool, like: Any) -> tuple[Any, Any, Any]:
    """The four pixels around each point at (px, py) (K, B, H, W) on images padded by a ring of one
    pixel, which catches the corners just outside the image: their flat indices (4 K B H W,) into
    one padded image per batch item, or per point and batch item (`per_point`), their bilinear
    weights (4, K, B, H, W), and whether the point has a corner in the image (K, B, H, W)."""
    xp = be.xp
    points, batch, height, width = px.shape
    x0, y0 = be.stop_gradient(xp.floor(px)), be.stop_gradient(xp.floor(py))
    fx, fy = px - x0, py - y0
    # Points with a corner in the image have their top-left corner in the padded image.
    near = (x0 >= -1) & (x0 <= width - 1) & (y0 >= -1) & (y0 <= height - 1)
    stride = width + 2
    images = points * batch if per_point else batch
    first = (be.arange(images, be.integer, like) * ((height + 2) * stride)).reshape(-1 if per_point else 1, batch, 1, 1)
    top_left = first + (be.index(xp.where(near, y0, -1.0)) + 1) * stride + be.index(xp.where(near, x0, -1.0)) + 1
    index = xp.stack([top_left, top_left + 1, top_left + stride, top_left + stride + 1]).reshape(-1)
    bilinear = xp.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy])
    return index, bilinear, near


def _splat_sums(be: Any, color: Any, depth: Any, terms: tuple, masses: Any, extent: Any, moving: Any, x: Any, y: Any, *, kind: str, paper: bool, passes: int) -> Any:
    """The sums (B, C + 1, H, W) of omega * [color, 1] over every moving pixel's points, by tensor
    ops (one scatter-add per chunk of points, `Backend.sum_chunks`), cropped to the image."""
    batch, channels, height, width = color.shape
    wide = position_dtype(be, color.dtype)
    # Rows of [color, 1] per source pixel: one scatter-add per point sums colour and weight together.
    rows = be.astype(be.permute(be.concat([color, be.xp.ones_like(depth)], 1), (0, 2, 3, 1)).reshape(-1, channels + 1), wide)
    times = be.asarray(point_times(masses.shape[0]), wide, color)
    # composite="layers" runs `passes` (3) of these in one call: they share the chunk budget.
    chunk = max(1, CHUNK_PIXEL_POINTS // (passes * rows.shape[0]))

    def splat(chunk_times: Any, chunk_masses: Any, *fixed: Any) -> Any:
        return _splat(be, paper, kind, chunk_times, chunk_masses, *fixed)

    start = be.zeros((batch * (height + 2) * (width + 2), channels + 1), wide, color)
    accumulated = be.sum_chunks(splat, times, masses, chunk, (terms, x[None], y[None], rows, depth, extent, moving), start)
    return be.permute(accumulated.reshape(batch, height + 2, width + 2, channels + 1)[:, 1:-1, 1:-1], (0, 3, 1, 2))


def _scatter(
    be: Any,
    color: Any,
    depth: Any,
    given: dict,
    masses: Any,
    extent: Any,
    background: Any,
    *,
    kind: str,
    degree: int,
    paper: bool,
    background_weight: float,
    fill: str,
    composite: str,
    fill_from_instants: bool,
    log_depth: bool,
    fused: bool,
) -> Any:
    """The scatter after the checks (compiled whole where the backend compiles, `CORE_STATIC`):
    `given` and `masses` in `position_dtype(color.dtype)`; the splats on the fused kernel if
    `fused`; fill "array": `background` given; `fill_from_instants`: with composite="instants", an
    image may lack a still pixel (fill="still"); `log_depth`: `depth` holds log depths (the relative
    band)."""
    xp = be.xp
    _, channels, height, width = color.shape
    wide = position_dtype(be, color.dtype)
    x, y = pixel_grid(be, height, width, color)
    terms = _terms(kind, degree, given)
    moving = moving_mask(kind, _moved_by(kind, degree, given), x, y)
    layers = composite == "layers"

    def sums(depth: Any) -> Any:
        if fused:
            return be.run_kernel("bezier_scatter", color, depth, kind, terms, masses, extent, moving, paper)
        return _splat_sums(be, color, depth, terms, masses, extent, moving, x, y, kind=kind, paper=paper, passes=1 if paper or composite == "sum" else 3)

    def split(accumulated: Any) -> tuple[Any, Any]:
        return accumulated[:, :channels], be.per_channel(accumulated[:, channels:], channels)

    if background is None:
        background = color if fill == "color" else _still_fill(be, color, be.astype(xp.logical_not(moving)[:, None], color.dtype))
    if composite == "instants" and not paper:
        # A moving pixel's uncovered time: what passes behind it over the exposure, over the fill; a
        # still pixel shows itself behind what passes in front of it, as in the other composites.
        passing = sums(xp.zeros_like(depth)) - sums(depth)
        behind = xp.where(moving[:, None], _over(be, *split(passing), be.astype(background, wide)), be.astype(color, wide))
        return _instants(be, color, depth, terms, masses, extent, moving, x, y, behind, kind=kind, unknown=fill_from_instants, log_depth=log_depth, fused=fused)

    accumulated = sums(depth)
    splatted, alpha = split(accumulated)
    behind = be.astype(xp.where(moving[:, None], background, color), wide)
    if paper:
        return be.astype((splatted + background_weight * behind) / (alpha + background_weight), color.dtype)
    summed = _over(be, splatted, alpha, behind)
    if not layers:
        return be.astype(summed, color.dtype)
    # The same splats with the depths negated pass where the source is level or behind, so their
    # complement is the nearer ones; with equal depths every splat passes.
    every = sums(xp.zeros_like(depth))
    near = every - sums(-depth)
    level, passing = accumulated - near, every - accumulated
    back = _over(be, *split(passing), behind)
    if fill == "still":  # where an image has no still pixel, what passes behind a pixel is what it uncovers
        mass = 1.0 / masses.shape[0]
        passing_splatted, passing_alpha = split(passing)
        unknown = (passing_splatted + mass * behind) / (passing_alpha + mass)
        back = xp.where(xp.all(moving.reshape(moving.shape[0], -1), 1)[:, None, None, None], unknown, back)
    layered = _over(be, *split(near), _over(be, *split(level), back))
    return be.astype(xp.where(moving[:, None], layered, summed), color.dtype)


def _instants(
    be: Any, color: Any, depth: Any, terms: tuple, masses: Any, extent: Any, moving: Any, x: Any, y: Any, behind: Any, *, kind: str, unknown: bool, log_depth: bool, fused: bool
) -> Any:
    """composite="instants" (`COMPOSITES`): each point time depth-tested on its own, in chunks of
    instants (`Backend.sum_chunks`: O(pixels) memory with a gradient), the instants summed by their
    masses, over `behind` (B, C, H, W) where nothing covers a pixel; `unknown` (fill="still"): an image without
    a still pixel fills each instant from itself instead. Each instant's splats on the fused kernel
    if `fused` (`Backend.run_kernel`), by tensor ops else (`_instant_sums`); the composite by tensor
    ops."""
    xp = be.xp
    batch, channels, height, width = color.shape
    wide = position_dtype(be, color.dtype)
    log = depth if log_depth else xp.log(depth)
    no_still = xp.all(moving.reshape(batch, -1), 1) if unknown else None
    times = be.asarray(point_times(masses.shape[0]), wide, color)
    # Instants per chunk, by the image padded by its ring (three times a line image's pixels): an
    # instant's intermediates, kept for the backward, come to some 200 numbers per padded pixel by
    # tensor ops (10 MB on 1x4097), some 60 on the fused kernel (its 2 C + 3 sums, the composite
    # and the depth read on the path, `_going_on_behind`). A chunk of CHUNK_PIXEL_POINTS by those
    # shares keeps the peak O(pixels) and small (tests/test_degenerate_memory.py: line images peak
    # at up to 14.9 MB at share 5, 17.8 at 4; docs/robustness.md); the fused share lets a
    # 128 x 128 image take three instants a kernel call, not one.
    share = INSTANT_SHARE_FUSED if fused else INSTANT_SHARE_TENSOR
    chunk = max(1, CHUNK_PIXEL_POINTS // (share * batch * (height + 2) * (width + 2)))
    start = be.zeros((batch, channels, height, width), wide, color)
    depth = be.astype(depth, wide)
    # Each instant reads the depth on the path again (`_going_on_behind`) rather than keep the reads
    # of `_own_surface`: K of them per pixel would break the chunks' O(pixels) memory.
    own = _own_surface(be, kind, times, masses, terms, x[None], y[None], be.astype(color, wide), depth, extent, chunk)
    if fused:

        def fused_instant(chunk_times: Any, chunk_masses: Any, terms: tuple, x: Any, y: Any, moving: Any, color: Any, log: Any, depth: Any, extent: Any, behind: Any, no_still: Any, own: Any) -> Any:
            sums = be.run_kernel("instants", color, log, depth, kind, terms, chunk_times, extent, moving)
            going_on = _going_on_behind(be, kind, chunk_times, terms, x, y, moving, depth, extent)
            return _instant_pictures(be, sums, chunk_masses, behind, no_still, going_on, own)

        fixed = (terms, x[None], y[None], moving, be.astype(color, wide), be.astype(log, wide), depth, extent, behind, no_still, own)
        return be.astype(be.sum_chunks(fused_instant, times, masses, chunk, fixed, start), color.dtype)
    # Rows of [color, 1, log depth] per source pixel: one scatter-add sums colour, coverage and the
    # depth that the uncovered fill weighs.
    rows = be.astype(be.permute(be.concat([color, xp.ones_like(log), log], 1), (0, 2, 3, 1)).reshape(-1, channels + 2), wide)

    def instant(chunk_times: Any, chunk_masses: Any, terms: tuple, x: Any, y: Any, moving: Any, rows: Any, depth: Any, destinations: Any, extent: Any, behind: Any, no_still: Any, own: Any) -> Any:
        sums = _instant_sums(be, kind, chunk_times, terms, x, y, moving, rows, depth, destinations, extent)
        going_on = _going_on_behind(be, kind, chunk_times, terms, x, y, moving, depth, extent)
        return _instant_pictures(be, sums, chunk_masses, behind, no_still, going_on, own)

    # Each destination's depth and whether it is still, on the padded images, flat: (B (H + 2) (W + 2), 2).
    destinations = be.pad(be.concat([depth, be.astype(xp.logical_not(moving)[:, None], wide)], 1), ((0, 0), (0, 0), (1, 1), (1, 1)), mode="edge")
    destinations = be.permute(destinations, (0, 2, 3, 1)).reshape(-1, 2)
    fixed = (terms, x[None], y[None], moving, rows, depth, destinations, extent, behind, no_still, own)
    return be.astype(be.sum_chunks(instant, times, masses, chunk, fixed, start), color.dtype)


def _instant_sums(be: Any, kind: str, times: Any, terms: tuple, x: Any, y: Any, moving: Any, rows: Any, depth: Any, destinations: Any, extent: Any) -> Any:
    """What the camera sees at each of `times` (K,), as sums (K, B, 2 C + 3, H, W): every moving
    pixel's point splatted bilinearly onto the image padded by a ring of one pixel (then cropped);
    on a still pixel only where the depth test against it passes (seed 003's: it is the layer
    behind); per destination the nearest depth among splats weighing more than
    NEAREST_SPLAT_WEIGHT; omega [color, 1, log depth] of the splats within the band behind it (the
    nearest layer), then weight [color, 1] of every splat."""
    xp = be.xp
    px, py = curve_position(kind, terms, x, y, times.reshape(-1, 1, 1, 1), xp)
    count, batch, height, width = px.shape
    channels = rows.shape[1] - 2
    plane = (height + 2) * (width + 2)
    index, bilinear, near = _padded_corners(be, px, py, per_point=True, like=rows)
    bilinear = xp.where((near & moving[None])[None], bilinear, 0.0)
    source = be.astype(depth, bilinear.dtype)[None, None, :, 0]
    extent = be.astype(extent, bilinear.dtype) if be.is_array(extent) else extent
    destination = destinations[index % (batch * plane)]
    destination_depth, destination_still = (destination[:, k].reshape(bilinear.shape) for k in (0, 1))
    bilinear = bilinear * xp.where(destination_still > 0, soft_depth_compare(be, destination_depth, source, extent), 1.0)
    size = count * batch * plane
    nearest = be.scatter_min(size, index, xp.where(bilinear > NEAREST_SPLAT_WEIGHT, source, math.inf).reshape(-1))
    omega = bilinear * be.astype(soft_depth_compare(be, nearest[index].reshape(bilinear.shape), source, extent), bilinear.dtype)
    # Per splat omega x [color, 1, log depth] (the nearest layer) and bilinear x [color, 1] (every
    # splat): where the nearest layer covers a pixel in part, the others show in the rest of it.
    values = be.concat([omega.reshape(4 * count, -1, 1) * rows[None], bilinear.reshape(4 * count, -1, 1) * rows[None, :, : channels + 1]], 2)
    sums = be.scatter_add(size, index, values.reshape(-1, 2 * channels + 3)).reshape(count, batch, height + 2, width + 2, 2 * channels + 3)[:, :, 1:-1, 1:-1]
    return be.permute(sums, (0, 1, 4, 2, 3))


def _on_path(be: Any, kind: str, times: Any, terms: tuple, x: Any, y: Any, image: Any) -> tuple[Any, Any]:
    """image (B, C, H, W) read bilinearly at X + p(-t) for each pixel X and each of `times` (K,):
    (K, B, C, H, W), and whether that point lies in the image, within half a pixel of its border
    pixels' centres, (K, B, 1, H, W) booleans (beyond it the border is read, which says nothing of
    what is there). X + p(-t), the point of X's own path at -t, is where the point that reaches X
    at t was at t = 0 (neighbouring points move alike; the point `accumulate_warps` reads)."""
    px, py = curve_position(kind, terms, x, y, -times.reshape(-1, 1, 1, 1), be.xp)
    count, batch, height, width = px.shape
    # sample() reads (B, H', W') positions: the instants stacked along the rows.
    flat = lambda v: be.permute(v, (1, 0, 2, 3)).reshape(batch, count * height, width)  # noqa: E731
    read = sample(be, image, flat(px), flat(py), "bilinear")
    inside = (px >= -0.5) & (px <= width - 0.5) & (py >= -0.5) & (py <= height - 0.5)
    return be.permute(read.reshape(batch, image.shape[1], count, height, width), (2, 0, 1, 3, 4)), inside[:, :, None]


def _going_on_behind(be: Any, kind: str, times: Any, terms: tuple, x: Any, y: Any, moving: Any, depth: Any, extent: Any) -> Any:
    """(K, B, 1, H, W): at each of `times`, how far the point that reaches a moving pixel X then
    (`_on_path`) lay behind a nearer surface of the sharp frame: 1 - the soft depth compare of X's
    depth against the depth there, i.e. X's depth more than the band behind it. There X's object
    goes on behind that surface (it was hidden at t = 0), so what X uncovers is its own object, not
    the scene behind. 0 where X is still or the depth there is level with X's or farther (an edge
    of its object), or lies outside the image."""
    there, inside = _on_path(be, kind, times, terms, x, y, depth)
    extent = be.astype(extent, there.dtype) if be.is_array(extent) else extent
    nearer = 1.0 - soft_depth_compare(be, there, depth[None], extent)
    return be.xp.where(moving[None, :, None] & inside, nearer, 0.0)


def _own_surface(be: Any, kind: str, times: Any, masses: Any, terms: tuple, x: Any, y: Any, color: Any, depth: Any, extent: Any, chunk: int) -> Any:
    """(B, C, H, W): what each pixel's own object looks like where the sharp frame hides it, the
    colour it shows where it goes on behind a nearer surface (`_going_on_behind`): the mean, by the
    shutter's masses, of the colours along the pixel's path (`_on_path`, every point time) that lie
    on its own surface (depth level with its own both ways, by the soft depth compare) within the
    image; its own colour where none does. A mean of the texture it carries along, as the exposure
    averages the hidden texels; one texel would keep a fine texture's contrast. Summed in chunks of
    `chunk` point times (`Backend.sum_chunks`, O(pixels) memory)."""
    xp = be.xp
    extent = be.astype(extent, depth.dtype) if be.is_array(extent) else extent

    def along(chunk_times: Any, chunk_masses: Any, terms: tuple, x: Any, y: Any, color: Any, depth: Any) -> Any:
        there, inside = _on_path(be, kind, chunk_times, terms, x, y, be.concat([color, depth], 1))
        colors, z = there[:, :, :-1], there[:, :, -1:]
        level = xp.where(inside, soft_depth_compare(be, depth[None], z, extent) * soft_depth_compare(be, z, depth[None], extent), 0.0)
        weight = chunk_masses.reshape(-1, 1, 1, 1, 1) * level
        return be.concat([(weight * colors).sum(0), weight.sum(0)], 1)

    batch, channels, height, width = color.shape
    start = be.zeros((batch, channels + 1, height, width), color.dtype, color)
    sums = be.sum_chunks(along, times, masses, chunk, (terms, x, y, color, depth), start)
    total, mass = sums[:, :channels], sums[:, channels:]
    return xp.where(mass > 0, total / xp.where(mass > 0, mass, 1.0), color)


def _instant_pictures(be: Any, sums: Any, masses: Any, behind: Any, no_still: Any, going_on: Any, own: Any) -> Any:
    """The sum over the instants of masses (K,) x what the camera sees at each, from their sums
    (K, B, 2 C + 3, H, W) (`_instant_sums`): the nearest layer's splats, beside the others, over
    `behind` (a still pixel: itself), which gives way to `own` (B, C, H, W), the pixel's own object
    (`_own_surface`), by `going_on` (`_going_on_behind`)."""
    xp = be.xp
    channels = (sums.shape[2] - 3) // 2
    splatted, alpha, log_sum = sums[:, :, :channels], sums[:, :, channels : channels + 1], sums[:, :, channels + 1 : channels + 2]
    hidden, hidden_alpha = sums[:, :, channels + 2 : 2 * channels + 2] - splatted, sums[:, :, 2 * channels + 2 :] - alpha
    behind = behind[None]
    if no_still is not None:
        behind = xp.where(no_still[None, :, None, None, None], _uncovered(be, splatted, alpha, log_sum, behind), behind)
    behind = behind + going_on * (own[None] - behind)
    pictures = _beside(be, splatted, alpha, hidden, hidden_alpha, behind)
    return (masses.reshape(-1, 1, 1, 1, 1) * pictures).sum(0)


def _beside(be: Any, splatted: Any, alpha: Any, hidden: Any, hidden_alpha: Any, behind: Any) -> Any:
    """An instant's picture: the nearest layer's splats (A, alpha); the part of the pixel they leave,
    1 - alpha, shows the other splats up to their coverage (they lie beside the nearest layer, as at
    an edge, as far as they can), then `behind`. Over 1, A / alpha."""
    xp = be.xp
    gap = xp.where(alpha < 1, 1.0 - alpha, 0.0)
    fits = hidden_alpha <= gap
    shown = xp.where(fits, hidden, hidden * gap / xp.where(fits, 1.0, hidden_alpha))
    return (splatted + shown + xp.where(fits, gap - hidden_alpha, 0.0) * behind) / xp.where(alpha > 1, alpha, 1.0)


def _uncovered(be: Any, splatted: Any, alpha: Any, log_sum: Any, behind: Any) -> Any:
    """What each instant (K, B, C, H, W) uncovers where nothing lands: a push-pull (`_still_fill`) of
    the instant's picture, its pixels covered at least halfway weighted by coverage x (depth /
    farthest such depth)^UNCOVERED_DEPTH_POWER; `behind` at an instant that covers no pixel so."""
    xp = be.xp
    count, batch, channels, height, width = splatted.shape
    covered = alpha >= 0.5
    safe = xp.where(covered, alpha, 1.0)
    mean_log = xp.where(covered, log_sum / safe, -math.inf)
    farthest = xp.amax(mean_log.reshape(count, batch, -1), 2).reshape(count, batch, 1, 1, 1)
    farthest = xp.where(farthest > -math.inf, farthest, 0.0)
    weight = xp.where(covered, xp.where(alpha < 1, alpha, 1.0) * xp.exp(UNCOVERED_DEPTH_POWER * (xp.where(covered, mean_log, farthest) - farthest)), 0.0)
    picture = xp.where(covered, splatted / safe, behind)
    filled = _still_fill(be, picture.reshape(count * batch, channels, height, width), weight.reshape(count * batch, 1, height, width))
    return filled.reshape(splatted.shape)


def _over(be: Any, splatted: Any, alpha: Any, behind: Any) -> Any:
    """A layer of splats over what is behind it, by coverage (`COMPOSITES`)."""
    xp = be.xp
    uncovered = xp.where(alpha < 1, 1.0 - alpha, 0.0)
    return (splatted + uncovered * behind) / xp.where(alpha > 1, alpha, 1.0)


def _upsample_axis(x: Any, size: int, axis: int, be: Any) -> Any:
    """Axis `axis` (-2: rows, -1: columns) doubled by linear interpolation between centres (each new
    element 3/4 of its parent, 1/4 of the parent's neighbour on its side, the border repeated),
    cropped to `size`. Each axis in place: with a transpose around a row pass the push-pull fill's
    jitted value_and_grad took 166 ms at 1280x720 instead of 110 (XLA:CPU)."""
    head = (slice(None),) * (x.ndim + axis)
    part = lambda start, stop: x[(*head, slice(start, stop))]  # noqa: E731
    n = x.shape[axis]
    before = be.concat([part(0, 1), part(0, n - 1)], axis)
    after = be.concat([part(1, n), part(n - 1, n)], axis)
    doubled = be.xp.stack([0.75 * x + 0.25 * before, 0.75 * x + 0.25 * after], axis % x.ndim + 1)
    shape = list(x.shape)
    shape[axis] = 2 * n
    return doubled.reshape(shape)[(*head, slice(0, size))]


def _pool(be: Any, x: Any) -> Any:
    """Sums over 2 x 2 blocks, an odd side padded with zeros. Strided slices, not a reshape and a sum
    over axes: XLA:CPU ran that 2x slower."""
    height, width = x.shape[-2:]
    x = be.pad(x, ((0, 0), (0, 0), (0, height % 2), (0, width % 2)))
    return (x[..., 0::2, 0::2] + x[..., 0::2, 1::2]) + (x[..., 1::2, 0::2] + x[..., 1::2, 1::2])


def _still_fill(be: Any, color: Any, still: Any) -> Any:
    """The colour behind each pixel estimated from the still pixels (`still`, (B, 1, H, W) of 0 and 1)
    by push-pull (see `FILLS`); color where the image has no still pixel."""
    xp = be.xp
    levels = [(color * still, still)]
    while max(levels[-1][1].shape[-2:]) > 1:
        levels.append(tuple(_pool(be, v) for v in levels[-1]))
    total, weight = levels[-1]
    estimate = total / xp.where(weight > 0, weight, 1.0)
    for total, weight in reversed(levels[:-1]):
        mean = xp.where(weight > 0, total / xp.where(weight > 0, weight, 1.0), 0.0)
        share = xp.where(weight > 1.0, 1.0, weight)
        upsampled = _upsample_axis(_upsample_axis(estimate, weight.shape[-2], -2, be), weight.shape[-1], -1, be)
        estimate = share * mean + (1.0 - share) * upsampled
    return xp.where(levels[-1][1] > 0, estimate, color)
