"""Where the filters take their taps in the exposure, and how much of the shutter each one carries.

Framework-neutral: the functions take the array namespace `xp` (numpy, torch or jax.numpy) so the
shutter's parameters may be tensors being fitted.
"""

from __future__ import annotations

from typing import Any

from diffblur import checks
from diffblur.shutters import ShutterWindow

__all__ = [
    "gather_tap_times",
    "reconstruct_tap_time",
    "shutter_factor",
    "stratum_weights",
]


def gather_tap_times(samples: int) -> tuple[float, ...]:
    """Midpoints of `samples` equal strata of the exposure [-1, 1], as Python floats (constants to
    a compiler, not arrays it would trace).

    With an odd count the middle tap is t = 0, the sharp frame's instant.
    """
    samples = checks.require_odd_int("samples", samples)
    return tuple((2.0 * k + 1.0) / samples - 1.0 for k in range(samples))


def stratum_weights(window: ShutterWindow, times: Any, half_width: float, xp: Any) -> Any:
    """The shutter's mass on [t - half_width, t + half_width] for each time t (any shape).

    This is W(t + h) - W(t - h) with W the window's antiderivative: exact for any window, and
    differentiable in the window's parameters when they are `xp` arrays. A box window gives
    half_width for every stratum inside the exposure.
    """
    return window.antiderivative(times + half_width, xp=xp) - window.antiderivative(times - half_width, xp=xp)


def reconstruct_tap_time(index: int, jitter: Any, samples: int) -> Any:
    """Seed 000 Listing 1: tap `index` of `samples` sits at t = mix(-1, 1, (index + j + 1) / (S + 1))
    along the tap direction, j in [-0.5, 0.5) the pixel's jitter (a number or an array)."""
    return -1.0 + 2.0 * (index + jitter + 1.0) / (samples + 1.0)


def shutter_factor(window: ShutterWindow, tau: Any, samples: int, xp: Any) -> Any:
    """The weight a reconstruct tap at exposure time tau carries: the shutter's mean density on the
    tap's stratum (half-width 1 / (S + 1)) times 2, which is exactly 1 for the box (the paper)."""
    half_width = 1.0 / (samples + 1.0)
    return stratum_weights(window, tau, half_width, xp) / half_width
