"""Pyramid (texture-space, seed 001) blur for large motion, framework-neutral pieces and the NumPy
reference reads.

Where a pixel's taps are farther apart than a pixel (spacing d = 2 |v| / S for `gather_blur`'s S
taps along its path of length 2 |v|, 2 |v| / (S + 1) for `reconstruct`), point taps skip image
content and the blur breaks into copies. With `pyramid=True` the taps read colour from a
pre-filtered pyramid instead: level 0 is the image, level k + 1 averages 2 x 2 pixels of level k (a
last odd row or column is repeated), so level k holds the image averaged over 2^k pixels. A tap
reads level lod = log2(d) (0 where d <= 1), trilinearly: bilinear within the levels floor(lod)
and floor(lod) + 1, then linear between them, so the result is continuous, and differentiable, in
the velocity. Level k's pixel (i, j) covers the image pixels 2^k i ... 2^k (i + 1) - 1, so the image
point (x, y) is at ((x + 0.5) / 2^k - 0.5, (y + 0.5) / 2^k - 0.5) in it. With d <= 1 everywhere the
result is the one without the pyramid. Depth and velocity (reconstruct's classification) are read
at full resolution.

The pre-filter is isotropic: it also blurs across the motion, by up to the tap spacing, which seed 001
accepts ("non-anisotropic texture fetches ... augmented with image space vector motion blur").
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["level_of_detail", "level_sizes", "numpy_levels", "numpy_sample_levels"]


def level_sizes(height: int, width: int) -> list[tuple[int, int]]:
    """(height, width) of each level, from the image down to 1 x 1."""
    sizes = [(height, width)]
    while sizes[-1] != (1, 1):
        h, w = sizes[-1]
        sizes.append((math.ceil(h / 2), math.ceil(w / 2)))
    return sizes


def level_of_detail(spacing: Any, levels: int, xp: Any) -> Any:
    """log2(spacing) where spacing > 1, else 0, capped at the last level (any array type)."""
    above = spacing > 1.0
    lod = xp.where(above, xp.log2(xp.where(above, spacing, 1.0)), 0.0 * spacing)
    return xp.where(lod > levels - 1, 0.0 * lod + (levels - 1), lod)


def numpy_levels(image: np.ndarray) -> list[np.ndarray]:
    """The pyramid of a (C, H, W) image, NumPy."""
    levels = [image]
    for h, w in level_sizes(*image.shape[1:])[1:]:
        previous = levels[-1]
        padded = np.pad(previous, ((0, 0), (0, 2 * h - previous.shape[1]), (0, 2 * w - previous.shape[2])), mode="edge")
        levels.append(0.25 * (padded[:, 0::2, 0::2] + padded[:, 0::2, 1::2] + padded[:, 1::2, 0::2] + padded[:, 1::2, 1::2]))
    return levels


def numpy_sample_levels(levels: list[np.ndarray], x: float, y: float, lod: float) -> np.ndarray:
    """Trilinear read of the pyramid at image point (x, y) and level of detail lod (NumPy)."""
    from diffblur.reference import sample_bilinear

    low = min(int(math.floor(lod)), len(levels) - 1)
    high = min(low + 1, len(levels) - 1)
    fraction = lod - low

    def read(level: int) -> np.ndarray:
        scale = 2.0**level
        return sample_bilinear(levels[level], (x + 0.5) / scale - 0.5, (y + 0.5) / scale - 0.5)

    below = read(low)
    return below + fraction * (read(high) - below)


def pyramid_option(pyramid: object, adaptive: object, sampling: str) -> bool:
    """Check the pyramid option: a bool, with bilinear sampling, not (yet) with adaptive tiles."""
    if not isinstance(pyramid, bool):
        raise TypeError(f"pyramid must be True or False, got {pyramid!r}")
    if pyramid and adaptive not in (None, False):
        raise ValueError(f"pyramid=True does not combine with adaptive sampling yet; got adaptive={adaptive!r}")
    if pyramid and sampling != "bilinear":
        raise ValueError(f"pyramid=True reads the levels trilinearly and needs sampling='bilinear', got {sampling!r}")
    return pyramid


__all__ += ["pyramid_option"]
