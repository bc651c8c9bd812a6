"""Where the filters take their taps in the exposure, and how much of the shutter each one carries.

Framework-neutral: the functions take the array namespace `xp` (numpy, torch or jax.numpy) so the
shutter's parameters may be tensors being fitted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from diffblur import checks
from diffblur.conventions import SAMPLING_MODES, TAP_DIRECTIONS
from diffblur.shutters import ShutterWindow, get_shutter

__all__ = [
    "ReconstructOptions",
    "gather_tap_times",
    "reconstruct_options",
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


@dataclass(frozen=True)
class ReconstructOptions:
    """reconstruct's options, checked and resolved (tile from max_radius, the window, early_out)."""

    tile: int
    samples: int
    #: The band of soft_depth_compare in the depths compared: depth units, or log(1 + r) when
    #: `log_depth` (the band relative to depth, `diffblur.checks.depth_band`).
    soft_z_extent: float
    sampling: str
    window: ShutterWindow
    early_out: bool
    directions: str
    min_radius: float
    #: Sample-count classes of tiled adaptive sampling (`diffblur._adaptive`), None when off.
    classes: tuple[int, ...] | None = None
    #: Taps read colour from a pre-filtered pyramid where they are farther apart than a pixel.
    pyramid: bool = False
    #: The depths are compared as log depth (a band relative to depth).
    log_depth: bool = False


def reconstruct_options(
    *,
    max_radius: float,
    samples: int,
    soft_z_extent: float | None,
    relative_z_extent: float,
    sampling: str,
    shutter: Any,
    early_out: bool | None,
    directions: str,
    min_radius: float,
    adaptive: object = False,
    pyramid: object = False,
) -> ReconstructOptions:
    """Check reconstruct's options once for every backend and the reference. early_out=None
    means on for "nearest" (the paper) and off for "bilinear" (the differentiable path);
    adaptive: see `diffblur._adaptive.adaptive_classes`; pyramid: `diffblur._pyramid`."""
    from diffblur._adaptive import adaptive_classes
    from diffblur._pyramid import pyramid_option

    sampling = checks.require_choice("sampling", sampling, SAMPLING_MODES)
    samples = checks.require_odd_int("samples", samples)
    relative, extent = checks.depth_band(soft_z_extent, relative_z_extent)
    extent = checks.require_positive_number("relative_z_extent" if relative else "soft_z_extent", extent)
    return ReconstructOptions(
        tile=math.ceil(checks.require_positive_number("max_radius", max_radius)),
        samples=samples,
        soft_z_extent=math.log1p(extent) if relative else extent,
        sampling=sampling,
        window=get_shutter(shutter),
        early_out=sampling == "nearest" if early_out is None else bool(early_out),
        directions=checks.require_choice("directions", directions, TAP_DIRECTIONS),
        min_radius=checks.require_positive_number("min_radius", min_radius),
        classes=adaptive_classes(adaptive, samples),
        pyramid=pyramid_option(pyramid, adaptive, sampling),
        log_depth=relative,
    )
