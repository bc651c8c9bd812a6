"""Where the filters take their taps in the exposure, and how much of the shutter each one carries.

Framework-neutral: the functions take the array namespace `xp` (numpy, torch or jax.numpy) so the
shutter's parameters may be tensors being fitted.
"""

from __future__ import annotations

from typing import Any

from diffblur import checks
from diffblur.shutters import ShutterWindow

__all__ = ["gather_tap_times", "stratum_weights"]


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
