"""The image-warping methods: the accumulation baseline (`accumulate_warps`, seed 002 sec. 1) and the
iterative warp-and-blend (`warp_blend`, seed 002 sec. 3-4). Options (checked once for both
frameworks and the NumPy reference, with the instants and the warp schedule), docstrings and math.

accumulate_warps. The accumulation buffer renders the scene at N instants of the exposure and
averages the renderings. Done on the image, rendering at instant t is a warp: pixel X shows the
point that is there at t. That point, seen at Y at t = 0, satisfies Y + p_Y(t) = X; with the paths
of neighbouring points alike (p_Y ~ p_X) it is where X's own path is at -t, Y = X + p(-t), and the
warp reads C[X + p(-t)] (a backward lookup, as a texture-offset warp does). Along a curved path this
keeps the curve's bend; C[X - p(t)] would mirror it (the same for a straight path, p(-t) = -p(t)).
The instants are the midpoints of N equal strata and each carries
the shutter's exact mass on its stratum, so with a linear path (p(t) = t V) and an odd N this is
`gather_blur(samples=N)`; the difference is that N may be any count (an accumulation buffer takes
as many renderings as it can afford, 2, 4, ...) and the path may be curved (offsets). With few
instants and fast motion the N copies separate: the ghosting of seed 002 Figure 1.

Paths: velocity V gives p(t) = t V; offset_prev and offset_next (where the point is at t = -1 and
t = +1 relative to X) give the parabola through them and 0 at t = 0:
p(t) = t (next - prev) / 2 + t^2 (next + prev) / 2.

warp_blend. Seed 002 warps the image by a scaled offset lookup and alpha-blends the warped image
into the running result, which is warped again at the next iteration ("this blended object is used
as the original object in the next iteration"): a line integral convolution along the velocity
field, iterated. Here iteration i (0, 1, ..., n - 1) warps the running result R by a fraction
s_i = 2 / 3^(i + 1) of the velocity, along it (trailing side, full scale) and against it (leading
side, scaled by `backward_scale`), and blends both into R:

    R <- (1 - a_i) R + a_i / 2 (R[X + s_i V[X]] + R[X - backward_scale s_i V[X]]).

The warp starts at its largest (2/3 V) and shrinks by 3 each iteration towards the pixel's own
position, as the document moves "from the maximum warp towards the actual position". With
backward_scale = 1 and a_i = 2/3 (the default), a uniform translation gets exactly the box filter
of 3^n equally spaced taps over X - V ... X + V (balanced ternary digits), i.e. gather_blur with
3^n samples from 2 n lookups. The alpha ramp a_i runs linearly from alpha[0] (first, largest
warp) to alpha[1] (last, smallest warp); the document lets alpha grow as the warp shrinks, e.g.
alpha=(0.5, 0.8), which concentrates the blur near the sharp position (a tapered trail).
backward_scale < 1 is the document's shorter leading blur: it suits a sharp frame taken at the end
of the exposure; this project's sharp frame is mid-exposure, so the default is symmetric.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from typing import Any

from diffblur import checks
from diffblur.conventions import DEFAULT_SHUTTER, VECTOR_CHANNELS, WARP_SAMPLING_MODES
from diffblur.ops._options import OpOptions
from diffblur.ops.sampling import pixel_grid, position_dtype, sample
from diffblur.ops.taps import stratum_weights
from diffblur.shutters import ShutterWindow, get_shutter

__all__ = [
    "ACCUMULATE_DOC",
    "DEFAULT_ALPHA",
    "DEFAULT_BACKWARD_SCALE",
    "DEFAULT_INSTANTS",
    "DEFAULT_ITERATIONS",
    "WARP_BLEND_DOC",
    "AccumulateOptions",
    "WarpBlendOptions",
    "accumulate_warps",
    "instant_masses",
    "lookup_offset",
    "path_offset",
    "require_path",
    "warp_blend",
]

#: Default number of renderings of accumulate_warps.
DEFAULT_INSTANTS = 8
#: Default iterations of warp_blend: 3 iterations = the 27-tap box on a uniform translation.
DEFAULT_ITERATIONS = 3
#: Default scale of the warp against the velocity (1 = symmetric, the mid-exposure convention).
DEFAULT_BACKWARD_SCALE = 1.0
#: Default alpha ramp (first iteration, last iteration): flat 2/3 gives the box filter.
DEFAULT_ALPHA = (2.0 / 3.0, 2.0 / 3.0)
#: Each iteration's warp is this fraction of the previous one.
WARP_RATIO = 1.0 / 3.0


@dataclasses.dataclass(frozen=True)
class AccumulateOptions(OpOptions):
    """accumulate_warps' options, checked; the window and the instants resolved."""

    instants: int = DEFAULT_INSTANTS
    shutter: str | ShutterWindow = DEFAULT_SHUTTER
    sampling: str = "bilinear"
    window: ShutterWindow = dataclasses.field(init=False, repr=False)
    #: The instants: midpoints of `instants` equal strata of the exposure.
    times: tuple[float, ...] = dataclasses.field(init=False, repr=False)

    def __post_init__(self) -> None:
        instants = checks.require_positive_int("instants", self.instants)
        self._resolve("instants", instants)
        self._resolve("window", get_shutter(self.shutter))
        self._resolve("sampling", checks.require_choice("sampling", self.sampling, WARP_SAMPLING_MODES))
        self._resolve("times", tuple((2.0 * k + 1.0) / instants - 1.0 for k in range(instants)))


def instant_masses(window: ShutterWindow, times: Any, xp: Any) -> list[Any]:
    """The shutter's mass on the stratum of each instant of `times` (the options' `times` as an `xp`
    array), renormalised to sum to 1 (differentiable in the window's parameters when they are `xp`
    arrays). Returns one scalar per instant."""
    instants = times.shape[0]
    masses = stratum_weights(window, times, 1.0 / instants, xp)
    masses = masses / masses.sum()
    return [masses[k] for k in range(instants)]


def lookup_offset(t: float, velocity: Any, offset_prev: Any, offset_next: Any) -> Any:
    """Where `accumulate_warps` reads pixel X at instant t, relative to X: p(-t), the position of
    X's own path at -t (module docstring). Arithmetic only, so any array type works."""
    return path_offset(-t, velocity, offset_prev, offset_next)


def path_offset(t: float, velocity: Any, offset_prev: Any, offset_next: Any) -> Any:
    """p(t) (module docstring) for a velocity, or for the offsets when velocity is None. Arithmetic
    only, so any array type works."""
    if velocity is not None:
        return t * velocity
    return (0.5 * t) * (offset_next - offset_prev) + (0.5 * t * t) * (offset_next + offset_prev)


def require_path(velocity: Any, offset_prev: Any, offset_next: Any) -> str:
    """"velocity" or "offsets": exactly one way of giving accumulate_warps its paths."""
    has_offsets = offset_prev is not None or offset_next is not None
    if velocity is not None and has_offsets:
        raise ValueError("accumulate_warps takes velocity or (offset_prev, offset_next), not both; pass velocity=None with offsets")
    if velocity is None and (offset_prev is None or offset_next is None):
        raise ValueError("accumulate_warps needs velocity, or both offset_prev and offset_next; got "
                         f"offset_prev={'given' if offset_prev is not None else None}, offset_next={'given' if offset_next is not None else None}")
    return "velocity" if velocity is not None else "offsets"


__all__ += ["require_path"]


@dataclasses.dataclass(frozen=True)
class WarpBlendOptions(OpOptions):
    """warp_blend's options, checked; the schedule resolved."""

    iterations: int = DEFAULT_ITERATIONS
    backward_scale: float = DEFAULT_BACKWARD_SCALE
    alpha: float | tuple[float, float] = DEFAULT_ALPHA
    sampling: str = "bilinear"
    #: (s_i, a_i) for each iteration, largest warp first.
    schedule: tuple[tuple[float, float], ...] = dataclasses.field(init=False, repr=False)

    def __post_init__(self) -> None:
        iterations = checks.require_positive_int("iterations", self.iterations)
        first, last = _alpha_pair(self.alpha)
        schedule = []
        for i in range(iterations):
            ramp = i / (iterations - 1) if iterations > 1 else 0.0
            schedule.append((2.0 * WARP_RATIO ** (i + 1), first + (last - first) * ramp))
        self._resolve("iterations", iterations)
        self._resolve("backward_scale", checks.require_in_interval("backward_scale", self.backward_scale, 0.0, 1.0))
        self._resolve("alpha", (first, last))
        self._resolve("sampling", checks.require_choice("sampling", self.sampling, WARP_SAMPLING_MODES))
        self._resolve("schedule", tuple(schedule))


def _alpha_pair(alpha: object) -> tuple[float, float]:
    if isinstance(alpha, numbers.Real) and not isinstance(alpha, bool):
        alpha = (alpha, alpha)
    if not isinstance(alpha, (tuple, list)) or len(alpha) != 2:
        raise TypeError(f"alpha must be a number or a pair (first, last) of numbers in (0, 1], got {alpha!r}")
    pair = []
    for value in alpha:
        if not isinstance(value, numbers.Real) or isinstance(value, bool):
            raise TypeError(f"alpha must be a number or a pair (first, last) of numbers in (0, 1], got {alpha!r}")
        if not 0.0 < value <= 1.0 or math.isnan(value):
            raise ValueError(f"alpha must be in (0, 1], got {tuple(alpha)!r}")
        pair.append(float(value))
    return pair[0], pair[1]


def _vector_field(be: Any, name: str, value: object, color: Any) -> Any:
    value = checks.image_array(be, name, value, channels=VECTOR_CHANNELS)
    checks.require_same_batch_and_size("color", color.shape, [(name, value.shape)])
    checks.same_dtype_and_device(be, name, value, "color", color)
    return be.check_finite(name, value)


ACCUMULATE_DOC = """The accumulation-buffer baseline on the image (seed 002 sec. 1): `instants` warped copies of
    the image, one per instant of the exposure, weighted by the shutter.

    Copy k shows pixel X the point that is there at instant t_k: C[X + p(-t_k)], where X's own path
    p (p(t) = t V[X], or the parabola through offset_prev, 0 and offset_next at t = -1, 0, 1) is at
    -t_k, so a curved path keeps its bend (`diffblur.ops.warp`). The instants are the midpoints of
    `instants` equal strata, each weighted by the shutter's mass on its stratum. With few instants
    and fast motion the copies separate (ghosting, seed 002 Figure 1); the brute-force reference of
    the trade. With a velocity and an odd count it equals `gather_blur(samples=instants)`.

    Args:
        color: (B, C, H, W) linear intensities, any C.
        velocity: (B, 2, H, W) half-spread velocity in pixels, or None when offsets are given.
        offset_prev, offset_next: (B, 2, H, W) where the point seen at X is at t = -1 and t = +1,
            relative to X, in pixels; instead of velocity.
        instants: number of renderings N, an integer >= 1 (1 returns the image).
        shutter: a window name or `ShutterWindow` (its parameters may be arrays to fit).
        sampling: "bilinear" (differentiable in the path) or "nearest".

    Returns:
        (B, C, H, W), color's dtype. Positions beyond the border read the border pixel.
    """


def accumulate_warps(be: Any, color: Any, velocity: Any, *, offset_prev: Any = None, offset_next: Any = None, **options: Any) -> Any:
    """The op, for a backend: its arguments checked, then the warped copies summed."""
    o = AccumulateOptions.take("accumulate_warps", options)
    color = checks.image_array(be, "color", color)
    if require_path(velocity, offset_prev, offset_next) == "velocity":
        velocity = be.check_finite("color", color, carry=_vector_field(be, "velocity", velocity, color))
    else:
        offset_prev = be.check_finite("color", color, carry=_vector_field(be, "offset_prev", offset_prev, color))
        offset_next = _vector_field(be, "offset_next", offset_next, color)
    # Positions, offsets, weights and the sum in float32 for a half image (its dtype else).
    _, _, height, width = color.shape
    x, y = pixel_grid(be, height, width, color)
    velocity, offset_prev, offset_next = (None if v is None else be.astype(v, x.dtype) for v in (velocity, offset_prev, offset_next))
    masses = instant_masses(be.widen_window(o.window, x.dtype), be.asarray(o.times, x.dtype, x), be.xp)
    out = be.xp.zeros_like(color, dtype=x.dtype)
    for t, mass in zip(o.times, masses):
        p = lookup_offset(t, velocity, offset_prev, offset_next)
        out = out + be.astype(mass, x.dtype) * sample(be, color, x + p[:, 0], y + p[:, 1], o.sampling)
    return be.astype(out, color.dtype)


WARP_BLEND_DOC = """Seed 002's iterative warp-and-blend line integral convolution.

    Starting from R = color, iteration i warps R by s_i = 2 / 3^(i + 1) of the velocity, along it
    and (scaled by `backward_scale`) against it, and blends both into R with alpha a_i:
    R <- (1 - a_i) R + a_i / 2 (R[X + s_i V] + R[X - backward_scale s_i V]). The blended image is
    warped again at the next, smaller warp, so the blur follows the velocity field. With the
    defaults a uniform translation gets the box filter of 3^iterations taps (gather_blur with
    3^iterations samples) from 2 x iterations lookups.

    Args:
        color: (B, C, H, W) linear intensities, any C.
        velocity: (B, 2, H, W) half-spread velocity in pixels.
        iterations: warp-and-blend passes n, an integer >= 1.
        backward_scale: scale of the warp against the velocity, in [0, 1]; below 1 the leading
            side blurs less than the trailing one (the document's look, for a sharp frame at the
            end of the exposure); 1 (default) is symmetric, as this project's mid-exposure frame.
        alpha: the blend weight of the warped images, a number or a ramp (first, last) run
            linearly from the first (largest) warp to the last (smallest); each in (0, 1]. The
            document lets it grow as the warp shrinks, e.g. (0.5, 0.8); flat 2/3 (default) gives
            the box filter.
        sampling: "bilinear" (differentiable in velocity) or "nearest".

    Returns:
        (B, C, H, W), color's dtype.
    """


def warp_blend(be: Any, color: Any, velocity: Any, **options: Any) -> Any:
    """The op, for a backend: its arguments checked, then the passes."""
    o = WarpBlendOptions.take("warp_blend", options)
    color = checks.image_array(be, "color", color)
    velocity = be.check_finite("color", color, carry=_vector_field(be, "velocity", velocity, color))
    _, _, height, width = color.shape
    # Positions, offsets and the blended image in float32 for a half image (its dtype else).
    x, y = pixel_grid(be, height, width, color)
    vx, vy = be.astype(velocity[:, 0], x.dtype), be.astype(velocity[:, 1], x.dtype)
    # Two or more passes run outside torch.compile's graph: inductor (torch 2.13, CPU) miscompiles
    # the backward of bilinear reads from an image that was itself read that way (the colour's
    # gradient off by up to 0.76, float64, 1x3x8x9, iterations=2; aot_eager was right).
    passes = _passes if len(o.schedule) < 2 else be.outside_compiler(_passes, "warp_blend with iterations >= 2: inductor miscompiles the gradient of its chained bilinear reads")
    return be.astype(passes(be, be.astype(color, x.dtype), x, y, vx, vy, o.schedule, o.backward_scale, o.sampling), color.dtype)


def _passes(be: Any, result: Any, x: Any, y: Any, vx: Any, vy: Any, schedule: tuple, backward_scale: float, sampling: str) -> Any:
    for scale, a in schedule:
        along = sample(be, result, x + scale * vx, y + scale * vy, sampling)
        back = backward_scale * scale
        against = sample(be, result, x - back * vx, y - back * vy, sampling)
        result = be.astype((1.0 - a) * result + (0.5 * a) * (along + against), x.dtype)
    return result
