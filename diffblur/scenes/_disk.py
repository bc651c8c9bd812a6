"""Seed 004's exact time-integrated density of an orbiting disk: an analytic ground truth for
rotational blur under any shutter window with an antiderivative.

A disk of radius a whose centre orbits `center` at distance R, at angle phase + angle * t at time t
(radians; positive turns +x towards +y, clockwise on screen). In polar coordinates (r, theta) about
the orbit centre the disk at t = 0 covers |wrap(theta - phase)| < h(r), with (seed 004)

    h(r) = arccos((R^2 + r^2 - a^2) / (2 r R)),

h = pi where the argument is below -1 (the whole circle of radius r is inside: the disk covers the
orbit centre) and 0 where it exceeds 1. The point is covered at time t when theta - phase - angle t
lies in (-h, h) + 2 pi k, i.e. for t in the intervals I_k = [(delta - h + 2 pi k) / angle,
(delta + h + 2 pi k) / angle], delta = wrap(theta - phase). The shutter-weighted density is
sum_k S(max I_k) - S(min I_k) with S the window's antiderivative (clamped to [-1, 1]). Seed 004
writes the k = 0 term; the others matter once the disk sweeps past theta = +-pi (fast orbits, long
trails), which this sums exactly.
"""

from __future__ import annotations

import math

import numpy as np

from diffblur import checks
from diffblur.scenes._motion import Rotation
from diffblur.scenes._render import Layer, Scene
from diffblur.scenes._textures import FunctionTexture
from diffblur.shutters import ShutterWindow, get_shutter

__all__ = ["orbiting_disk_density", "orbiting_disk_scene"]


def _check(height: int, width: int, center, orbit_radius: float, disk_radius: float, angle: float, phase: float):
    checks.require_positive_int("height", height)
    checks.require_positive_int("width", width)
    try:
        cx, cy = (float(v) for v in center)
    except (TypeError, ValueError):
        raise TypeError(f"center must be a pair of numbers (x, y) in pixels, got {center!r}") from None
    checks.require_nonnegative_number("orbit_radius", orbit_radius)
    checks.require_positive_number("disk_radius", disk_radius)
    checks.require_finite_number("angle", angle)
    checks.require_finite_number("phase", phase)
    return cx, cy


def orbiting_disk_density(
    height: int,
    width: int,
    *,
    center: tuple[float, float],
    orbit_radius: float,
    disk_radius: float,
    angle: float,
    phase: float = 0.0,
    shutter: str | ShutterWindow = "box",
) -> np.ndarray:
    """The exact shutter-weighted coverage of the orbiting disk at each pixel centre: (1, 1, H, W).

    center: orbit centre (x, y), pixels; orbit_radius R and disk_radius a in pixels; angle: rotation
    at t = 1, radians; phase: the disk centre's angle at t = 0. Values in [0, 1] (1 = covered during
    the whole exposure).
    """
    cx, cy = _check(height, width, center, orbit_radius, disk_radius, angle, phase)
    window = get_shutter(shutter)
    big_r, a = float(orbit_radius), float(disk_radius)
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    dx, dy = x - cx, y - cy
    r = np.hypot(dx, dy)
    if big_r == 0.0:
        # A disk centred on its orbit does not move.
        return (r < a).astype(np.float64)[None, None]
    r_safe = np.where(r > 0, r, 1.0)
    argument = (big_r * big_r + r * r - a * a) / (2.0 * r_safe * big_r)
    h = np.arccos(np.clip(argument, -1.0, 1.0))
    at_center = np.pi if big_r < a else 0.0
    h = np.where(r > 0, h, at_center)
    delta = np.angle(np.exp(1j * (np.arctan2(dy, dx) - phase)))  # wrapped to (-pi, pi]
    if angle == 0.0:
        return ((np.abs(delta) < h) | (h >= np.pi)).astype(np.float64)[None, None]
    total = np.zeros_like(r)
    k_max = math.ceil((abs(angle) + 2 * math.pi) / (2 * math.pi))
    for k in range(-k_max, k_max + 1):
        ends_a = (delta - h + 2 * math.pi * k) / angle
        ends_b = (delta + h + 2 * math.pi * k) / angle
        lo, hi = np.minimum(ends_a, ends_b), np.maximum(ends_a, ends_b)
        total += window.antiderivative(hi) - window.antiderivative(lo)
    return total[None, None]


def orbiting_disk_scene(
    height: int,
    width: int,
    *,
    center: tuple[float, float],
    orbit_radius: float,
    disk_radius: float,
    angle: float,
    phase: float = 0.0,
) -> Scene:
    """The same disk as a renderable scene: a white, hard-edged (point-sampled) disk on black, rotating
    about `center`. Its accumulation converges to `orbiting_disk_density` (every channel)."""
    cx, cy = _check(height, width, center, orbit_radius, disk_radius, angle, phase)
    a = float(disk_radius)
    dcx = cx + orbit_radius * math.cos(phase)
    dcy = cy + orbit_radius * math.sin(phase)

    def disk(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        inside = (x - dcx) ** 2 + (y - dcy) ** 2 < a * a
        return np.ones(x.shape + (3,)), inside.astype(np.float64)

    # Points of the disk, for the instant rule (consecutive instants move each < 1/4 px).
    grid = np.arange(-a, a + 0.25, 0.5)
    gx, gy = np.meshgrid(grid, grid)
    keep = gx**2 + gy**2 <= a * a
    support = (gx[keep] + dcx, gy[keep] + dcy)
    texture = FunctionTexture(disk, support)
    layer = Layer(texture, depth=1.0, motion=Rotation((cx, cy), float(angle)), name="disk")
    return Scene(int(height), int(width), (layer,))
