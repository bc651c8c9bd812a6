"""Pyramid (texture-space, seed 001) blur for large motion: the pre-filtered levels in one flat atlas
and their trilinear read (definitions in `diffblur._pyramid`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import Array

from diffblur._pyramid import level_of_detail, level_sizes


class Pyramid:
    """The levels of a (B, C, H, W) image, flattened into one (B, C, N) atlas."""

    def __init__(self, image: Array):
        sizes = level_sizes(*image.shape[2:])
        levels = [image]
        for h, w in sizes[1:]:
            previous = levels[-1]
            padded = jnp.pad(previous, ((0, 0), (0, 0), (0, 2 * h - previous.shape[2]), (0, 2 * w - previous.shape[3])), mode="edge")
            levels.append(0.25 * (padded[:, :, 0::2, 0::2] + padded[:, :, 0::2, 1::2] + padded[:, :, 1::2, 0::2] + padded[:, :, 1::2, 1::2]))
        self.count = len(sizes)
        self.atlas = jnp.concatenate([level.reshape(*level.shape[:2], -1) for level in levels], axis=2)
        offsets = [0]
        for h, w in sizes[:-1]:
            offsets.append(offsets[-1] + h * w)
        self.heights = jnp.asarray([h for h, _ in sizes], dtype=jnp.int32)
        self.widths = jnp.asarray([w for _, w in sizes], dtype=jnp.int32)
        self.offsets = jnp.asarray(offsets, dtype=jnp.int32)

    def _gather(self, index: Array) -> Array:
        batch, channels, _ = self.atlas.shape
        flat = jnp.broadcast_to(index.reshape(batch, 1, -1), (batch, channels, index[0].size))
        return jnp.take_along_axis(self.atlas, flat, axis=2).reshape(batch, channels, *index.shape[1:])

    def _read(self, level: Array, x: Array, y: Array) -> Array:
        """Bilinear at level `level`, in x's dtype (float32 positions for a half image)."""
        width, height, offset = self.widths[level], self.heights[level], self.offsets[level]
        dtype = x.dtype
        scale = jnp.exp2(level.astype(dtype))
        x = jnp.where(level == 0, x, (x + 0.5) / scale - 0.5)
        y = jnp.where(level == 0, y, (y + 0.5) / scale - 0.5)
        high_x, high_y = (width - 1).astype(dtype), (height - 1).astype(dtype)
        x = jnp.where(x < 0, 0.0, jnp.where(x > high_x, high_x, x)).astype(dtype)
        y = jnp.where(y < 0, 0.0, jnp.where(y > high_y, high_y, y)).astype(dtype)
        x0 = jax.lax.stop_gradient(jnp.floor(x))
        y0 = jax.lax.stop_gradient(jnp.floor(y))
        fx, fy = (x - x0)[:, None], (y - y0)[:, None]
        column0, row0 = jnp.minimum(x0.astype(jnp.int32), width - 1), jnp.minimum(y0.astype(jnp.int32), height - 1)
        column1 = jnp.minimum(column0 + 1, width - 1)
        row1 = jnp.minimum(row0 + 1, height - 1)
        read = lambda index: self._gather(index).astype(dtype)  # noqa: E731
        top_left = read(offset + row0 * width + column0)
        bottom_left = read(offset + row1 * width + column0)
        top = top_left + fx * (read(offset + row0 * width + column1) - top_left)
        bottom = bottom_left + fx * (read(offset + row1 * width + column1) - bottom_left)
        return top + fy * (bottom - top)

    def sample(self, x: Array, y: Array, lod: Array) -> Array:
        """(B, C, H', W') at image points x, y (B, H', W') and levels of detail lod (B, H', W'), in
        x's dtype."""
        low = jnp.minimum(jax.lax.stop_gradient(jnp.floor(lod)).astype(jnp.int32), self.count - 1)
        high = jnp.minimum(low + 1, self.count - 1)
        fraction = (lod - low.astype(lod.dtype))[:, None]
        below = self._read(low, x, y)
        return below + fraction * (self._read(high, x, y) - below)

    def level_of_detail(self, spacing: Array) -> Array:
        return level_of_detail(spacing, self.count, jnp).astype(spacing.dtype)
