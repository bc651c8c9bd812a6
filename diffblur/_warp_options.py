"""Framework-neutral pieces of the image-warping methods: the accumulation baseline
(`accumulate_warps`, seed 002 sec. 1) and the iterative warp-and-blend (`warp_blend`, seed 002
sec. 3-4). Defaults, option checks, the instants and the warp schedule live here, so the NumPy
reference and both backends resolve them the same way.

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

import math
import numbers
from dataclasses import dataclass
from typing import Any

from diffblur import checks
from diffblur.conventions import SAMPLING_MODES
from diffblur.shutters import ShutterWindow, get_shutter
from diffblur.taps import stratum_weights

__all__ = [
    "DEFAULT_ALPHA",
    "DEFAULT_BACKWARD_SCALE",
    "DEFAULT_INSTANTS",
    "DEFAULT_ITERATIONS",
    "AccumulateOptions",
    "WarpBlendOptions",
    "accumulate_options",
    "instant_masses",
    "lookup_offset",
    "path_offset",
    "warp_blend_options",
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


@dataclass(frozen=True)
class AccumulateOptions:
    instants: int
    window: ShutterWindow
    sampling: str
    times: tuple[float, ...]


def accumulate_options(*, instants: int, shutter: Any, sampling: str) -> AccumulateOptions:
    """Check accumulate_warps' options once for every backend and the reference."""
    instants = checks.require_positive_int("instants", instants)
    return AccumulateOptions(
        instants=instants,
        window=get_shutter(shutter),
        sampling=checks.require_choice("sampling", sampling, SAMPLING_MODES),
        times=tuple((2.0 * k + 1.0) / instants - 1.0 for k in range(instants)),
    )


def instant_masses(options: AccumulateOptions, xp: Any, dtype: Any = None) -> list[Any]:
    """The shutter's mass on each instant's stratum, renormalised to sum to 1 (differentiable in the
    window's parameters when they are `xp` arrays). Returns one scalar per instant."""
    times = xp.asarray(options.times, dtype=dtype) if dtype is not None else xp.asarray(options.times)
    masses = stratum_weights(options.window, times, 1.0 / options.instants, xp)
    masses = masses / masses.sum()
    return [masses[k] for k in range(options.instants)]


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


@dataclass(frozen=True)
class WarpBlendOptions:
    iterations: int
    backward_scale: float
    alpha: tuple[float, float]
    sampling: str
    #: (s_i, a_i) for each iteration, largest warp first.
    schedule: tuple[tuple[float, float], ...]


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


def warp_blend_options(*, iterations: int, backward_scale: float, alpha: object, sampling: str) -> WarpBlendOptions:
    """Check warp_blend's options once for every backend and the reference; resolve the schedule."""
    iterations = checks.require_positive_int("iterations", iterations)
    backward_scale = checks.require_in_interval("backward_scale", backward_scale, 0.0, 1.0)
    first, last = _alpha_pair(alpha)
    schedule = []
    for i in range(iterations):
        ramp = i / (iterations - 1) if iterations > 1 else 0.0
        schedule.append((2.0 * WARP_RATIO ** (i + 1), first + (last - first) * ramp))
    return WarpBlendOptions(
        iterations=iterations,
        backward_scale=backward_scale,
        alpha=(first, last),
        sampling=checks.require_choice("sampling", sampling, SAMPLING_MODES),
        schedule=tuple(schedule),
    )
