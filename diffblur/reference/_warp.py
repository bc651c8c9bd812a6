"""NumPy references of the image-warping methods of seed 002: the accumulation baseline
(`accumulate_warps`) and the iterative warp-and-blend (`warp_blend`). Pixel by pixel, for clarity;
the definitions are in `diffblur.ops.warp`."""

from __future__ import annotations

import numpy as np

from diffblur.ops.warp import (
    DEFAULT_ALPHA,
    DEFAULT_BACKWARD_SCALE,
    DEFAULT_INSTANTS,
    DEFAULT_ITERATIONS,
    AccumulateOptions,
    WarpBlendOptions,
    instant_masses,
    lookup_offset,
    require_path,
)
from diffblur.conventions import DEFAULT_SHUTTER
from diffblur.shutters import ShutterWindow

__all__ = ["accumulate_warps", "warp_blend"]


def _sampler(sampling: str):
    from diffblur.reference import sample_bilinear, sample_nearest

    return sample_bilinear if sampling == "bilinear" else sample_nearest


def accumulate_warps(
    color: np.ndarray,
    velocity: np.ndarray | None,
    *,
    instants: int = DEFAULT_INSTANTS,
    shutter: str | ShutterWindow = DEFAULT_SHUTTER,
    sampling: str = "bilinear",
    offset_prev: np.ndarray | None = None,
    offset_next: np.ndarray | None = None,
) -> np.ndarray:
    """The accumulation buffer on the image: sum_k m_k C[X + p(-t_k)[X]] over `instants` instants
    t_k (stratum midpoints), m_k the shutter's mass on stratum k, p the path of the point seen at X
    (t V, or the parabola through offset_prev, 0, offset_next)."""
    o = AccumulateOptions(instants=instants, shutter=shutter, sampling=sampling)
    require_path(velocity, offset_prev, offset_next)
    masses = [float(m) for m in instant_masses(o.window, np.asarray(o.times), np)]
    sample = _sampler(o.sampling)
    batch, _, height, width = color.shape
    out = np.zeros_like(color)
    for b in range(batch):
        for i in range(height):
            for j in range(width):
                for t, mass in zip(o.times, masses):
                    v = None if velocity is None else velocity[b, :, i, j]
                    prev = None if offset_prev is None else offset_prev[b, :, i, j]
                    nxt = None if offset_next is None else offset_next[b, :, i, j]
                    px, py = lookup_offset(t, v, prev, nxt)
                    out[b, :, i, j] += mass * sample(color[b], j + px, i + py)
    return out


def warp_blend(
    color: np.ndarray,
    velocity: np.ndarray,
    *,
    iterations: int = DEFAULT_ITERATIONS,
    backward_scale: float = DEFAULT_BACKWARD_SCALE,
    alpha: float | tuple[float, float] = DEFAULT_ALPHA,
    sampling: str = "bilinear",
) -> np.ndarray:
    """Seed 002's iterative warp-and-blend: for each (s, a) of the schedule, largest warp first,
    R <- (1 - a) R + a / 2 (R[X + s V[X]] + R[X - backward_scale s V[X]]), starting from R = color."""
    o = WarpBlendOptions(iterations=iterations, backward_scale=backward_scale, alpha=alpha, sampling=sampling)
    sample = _sampler(o.sampling)
    batch, _, height, width = color.shape
    result = color.copy()
    for scale, a in o.schedule:
        blended = np.zeros_like(result)
        for b in range(batch):
            for i in range(height):
                for j in range(width):
                    vx, vy = velocity[b, 0, i, j], velocity[b, 1, i, j]
                    along = sample(result[b], j + scale * vx, i + scale * vy)
                    against = sample(result[b], j - o.backward_scale * scale * vx, i - o.backward_scale * scale * vy)
                    blended[b, :, i, j] = (1.0 - a) * result[b, :, i, j] + 0.5 * a * (along + against)
        result = blended
    return result
