"""Framework-neutral pieces of the Bezier scatter (seed 003): defaults, option checks, where the
points of a curve sit in the exposure, and the curves' positions and lengths in either backend's ops
(`curve_position`, `curve_point`, `polyline_length`, given torch or jax.numpy).

The NumPy reference and both backends resolve their options here, so the three accept the same
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
does (`diffblur.taps`). The automatic count is one point per pixel of the longest curve, capped.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import warnings
from typing import Any

import numpy as np

from diffblur import checks, conventions
from diffblur.shutters import ShutterWindow
from diffblur.taps import stratum_weights

__all__ = [
    "COMPOSITES",
    "DEFAULT_COMPOSITE",
    "DEFAULT_BACKGROUND_WEIGHT",
    "DEFAULT_MAX_SAMPLES",
    "DEFAULT_NORMALIZATION",
    "DEFAULT_SHUTTER",
    "DEFAULT_RELATIVE_Z_EXTENT",
    "DEGREES",
    "DEFAULT_FILL",
    "FILLS",
    "LENGTH_SEGMENTS",
    "MID_PREV_TIME",
    "NORMALIZATIONS",
    "constant_masses",
    "curve_point",
    "curve_position",
    "has_constant_parameters",
    "length_times",
    "moving_mask",
    "no_still_message",
    "warn_without_still",
    "point_count",
    "point_masses",
    "point_times",
    "polyline_length",
    "resolve_options",
    "resolve_path",
    "traced_count_message",
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
#: What a moving pixel shows for the part of the exposure nothing covers it, when no `background` is
#: given. "still": an estimate of the scene behind it from the pixels that do not move, filled in by
#: push-pull (Gortler et al. 1996: sums of colour and weight pooled 2 x 2 down to one pixel, then each
#: level's mean where it has weight, blended with the coarser level bilinearly upsampled where it has
#: less than one pixel's weight). Where the image has no still pixel (a moving camera), with
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
#: How normalization="coverage" composites a moving pixel's splats. "layers": front to back, each
#: layer over what is behind it by its coverage (A + (1 - alpha) behind where alpha <= 1, A / alpha
#: where alpha > 1): the splats from sources nearer than the depth band in front, those level with
#: the pixel (within the band), those from behind it (which the depth test of seed 003 drops: they
#: are what the pixel shows once its own surface has moved off it), then the fill. "sum": seed 003's
#: one sum of the splats the depth test passes (no depth write), over the fill. Still pixels are their
#: own level layer, in front of what passes behind them, and keep the sum in both.
COMPOSITES = ("layers", "sum")
DEFAULT_COMPOSITE = "layers"
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


def resolve_options(
    *, samples: object, max_samples: object, normalization: object, background_weight: object
) -> tuple[int | None, int, str, float]:
    """(samples or None, max_samples, normalization, background_weight), checked."""
    if samples is not None:
        samples = checks.require_positive_int("samples", samples)
    max_samples = checks.require_positive_int("max_samples", max_samples)
    normalization = checks.require_choice("normalization", normalization, NORMALIZATIONS)
    background_weight = checks.require_positive_number("background_weight", background_weight)
    if math.isinf(background_weight):
        raise ValueError(f"background_weight must be finite, got {background_weight}")
    return samples, max_samples, normalization, background_weight


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


def warn_without_still(moving: np.ndarray, stacklevel: int) -> None:
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
        warnings.warn(message, UserWarning, stacklevel=stacklevel + 1)


def no_still_message(moving: np.ndarray) -> str | None:
    """The warning for fill="still" when an image of the batch has no still pixel, else None; moving is
    the (B, H, W) `moving_mask` as NumPy."""
    images = [b for b in range(moving.shape[0]) if moving[b].all()]
    if not images:
        return None
    return (
        f"bezier_scatter(fill='still') found no still pixel (one that moves at most "
        f"STILL_SPEED={conventions.STILL_SPEED} px) in image(s) {images} of the batch: every moving pixel "
        f"there fills its uncovered time with what passes behind it (composite='layers'), else with its "
        f"own colour, as fill='color'. Pass fill='color' to say so, or a `background` (warned once per process)"
    )


def point_count(max_length: float, max_samples: int) -> int:
    """One point per pixel of the longest curve (`max_length` pixels), at least 1, at most max_samples."""
    if not math.isfinite(max_length):
        return max_samples
    return int(min(max(math.ceil(max_length), 1), max_samples))


def traced_count_message(framework: str) -> str:
    """The error for samples=None while tracing: the count sets shapes and must be a Python int."""
    return (
        f"samples=None measures the curves to choose the point count, which needs concrete arrays; "
        f"under {framework} pass samples=<int> (a static count, e.g. max_samples)"
    )
