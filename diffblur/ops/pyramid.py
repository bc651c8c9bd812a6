"""Pyramid (texture-space, seed 001) blur for large motion: the pre-filtered levels and their
trilinear read, for both frameworks (`Pyramid`) and for the NumPy reference.

Where a pixel's taps are farther apart than a pixel (spacing d = 2 |v| / S for `gather_blur`'s S
taps along its path of length 2 |v|, 2 |v| / (S + 1) for `reconstruct`), point taps skip image
content and the blur breaks into copies. With `sampling="pyramid"` the taps read colour from a
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

__all__ = ["Pyramid", "level_of_detail", "level_sizes", "numpy_levels", "numpy_sample_levels"]


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


class Pyramid:
    """The levels of a (B, C, H, W) image, flattened into one (B, C, N) atlas, and their trilinear
    read, in a backend's ops."""

    def __init__(self, be: Any, image: Any):
        self.be = be
        sizes = level_sizes(*image.shape[2:])
        levels = [image]
        for h, w in sizes[1:]:
            previous = levels[-1]
            padded = be.pad(previous, ((0, 0), (0, 0), (0, 2 * h - previous.shape[2]), (0, 2 * w - previous.shape[3])), mode="edge")
            levels.append(0.25 * (padded[:, :, 0::2, 0::2] + padded[:, :, 0::2, 1::2] + padded[:, :, 1::2, 0::2] + padded[:, :, 1::2, 1::2]))
        self.count = len(sizes)
        self.atlas = be.concat([level.reshape(*level.shape[:2], -1) for level in levels], 2)
        offsets = [0]
        for h, w in sizes[:-1]:
            offsets.append(offsets[-1] + h * w)
        self.heights = be.asarray([h for h, _ in sizes], be.integer, image)
        self.widths = be.asarray([w for _, w in sizes], be.integer, image)
        self.offsets = be.asarray(offsets, be.integer, image)

    def _read(self, level: Any, x: Any, y: Any) -> Any:
        """Bilinear at level `level`, in x's dtype (float32 positions for a half image)."""
        be, xp = self.be, self.be.xp
        width, height, offset = self.widths[level], self.heights[level], self.offsets[level]
        dtype = x.dtype
        scale = xp.exp2(be.astype(level, dtype))
        x = xp.where(level == 0, x, (x + 0.5) / scale - 0.5)
        y = xp.where(level == 0, y, (y + 0.5) / scale - 0.5)
        high_x, high_y = be.astype(width - 1, dtype), be.astype(height - 1, dtype)
        x = be.astype(xp.where(x < 0, 0.0, xp.where(x > high_x, high_x, x)), dtype)
        y = be.astype(xp.where(y < 0, 0.0, xp.where(y > high_y, high_y, y)), dtype)
        x0, y0 = be.stop_gradient(xp.floor(x)), be.stop_gradient(xp.floor(y))
        fx, fy = (x - x0)[:, None], (y - y0)[:, None]
        # Clamped as integers at both ends (a NaN position: `diffblur.ops.sampling`).
        column0 = xp.where(be.index(x0) > width - 1, width - 1, be.index(x0))
        row0 = xp.where(be.index(y0) > height - 1, height - 1, be.index(y0))
        column0, row0 = xp.where(column0 < 0, 0, column0), xp.where(row0 < 0, 0, row0)
        column1 = xp.where(column0 + 1 > width - 1, width - 1, column0 + 1)
        row1 = xp.where(row0 + 1 > height - 1, height - 1, row0 + 1)
        read = lambda index: be.astype(be.read_pixels(self.atlas, index), dtype)  # noqa: E731
        top_left = read(offset + row0 * width + column0)
        bottom_left = read(offset + row1 * width + column0)
        top = top_left + fx * (read(offset + row0 * width + column1) - top_left)
        bottom = bottom_left + fx * (read(offset + row1 * width + column1) - bottom_left)
        return top + fy * (bottom - top)

    def sample(self, x: Any, y: Any, lod: Any) -> Any:
        """(B, C, H', W') at image points x, y (B, H', W') and levels of detail lod (B, H', W'), in
        x's dtype."""
        be, xp = self.be, self.be.xp
        low = be.index(be.stop_gradient(xp.floor(lod)))
        low = xp.where(low < 0, 0, xp.where(low > self.count - 1, self.count - 1, low))
        high = xp.where(low + 1 > self.count - 1, self.count - 1, low + 1)
        fraction = (lod - be.astype(low, lod.dtype))[:, None]
        below = self._read(low, x, y)
        return below + fraction * (self._read(high, x, y) - below)

    def level_of_detail(self, spacing: Any) -> Any:
        return self.be.astype(level_of_detail(spacing, self.count, self.be.xp), spacing.dtype)
