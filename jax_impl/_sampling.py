"""Reading an image at per-pixel positions, bilinear or nearest, clamped to the border."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import Array


def _clamp(x: Array, high: float) -> Array:
    # where, not clip: jnp.clip halves the gradient at a tie; this keeps the inside's, as in PyTorch.
    return jnp.where(x < 0, 0.0, jnp.where(x > high, high, x)).astype(x.dtype)


def _gather(flat: Array, row: Array, column: Array, width: int) -> Array:
    """flat (B, C, H*W) at integer (row, column) of shape (B, H', W') -> (B, C, H', W').

    Reads whole pixels (C values) channels-last: one index per pixel, not one per value. The same
    values as a per-channel take_along_axis, but XLA's CPU scatter-add (the gradient) and gather
    then move C-vectors: measured 1.6x faster forward+backward and 3x faster forward for
    reconstruct at 640x360, S=15 (diffblur bench).
    """
    batch, channels, _ = flat.shape
    index = (row * width + column).reshape(batch, -1, 1)
    pixels = jnp.take_along_axis(jnp.swapaxes(flat, 1, 2), index, axis=1)  # (B, H'W', C)
    return jnp.swapaxes(pixels, 1, 2).reshape(batch, channels, *row.shape[1:])


def sample(image: Array, x: Array, y: Array, mode: str) -> Array:
    """image (B, C, H, W) at positions x, y (B, H', W') in pixels (centres at integers).

    "bilinear" is differentiable in image, x and y; "nearest" rounds halves up (seed 000's
    [p + 0.5]) and is differentiable in image only. Positions beyond the border read the border.
    """
    batch, channels, height, width = image.shape
    flat = image.reshape(batch, channels, height * width)
    x = _clamp(x, width - 1.0)
    y = _clamp(y, height - 1.0)
    if mode == "nearest":
        column = jnp.minimum(jnp.floor(x + 0.5).astype(jnp.int32), width - 1)
        row = jnp.minimum(jnp.floor(y + 0.5).astype(jnp.int32), height - 1)
        return _gather(flat, row, column, width)
    x0 = jax.lax.stop_gradient(jnp.floor(x))
    y0 = jax.lax.stop_gradient(jnp.floor(y))
    fx = (x - x0)[:, None]
    fy = (y - y0)[:, None]
    # Clamped again as integers: in bfloat16 the border W - 1 itself rounds up past the image
    # beyond 256 px (float16 beyond 2048 px).
    column0, row0 = jnp.minimum(x0.astype(jnp.int32), width - 1), jnp.minimum(y0.astype(jnp.int32), height - 1)
    column1 = jnp.minimum(column0 + 1, width - 1)
    row1 = jnp.minimum(row0 + 1, height - 1)
    # a + f (b - a), not (1 - f) a + f b: equal neighbours give exactly their value, so equal depths
    # stay tied (soft_depth_compare has a kink there) whatever the rounding of each framework.
    top_left = _gather(flat, row0, column0, width)
    bottom_left = _gather(flat, row1, column0, width)
    top = top_left + fx * (_gather(flat, row0, column1, width) - top_left)
    bottom = bottom_left + fx * (_gather(flat, row1, column1, width) - bottom_left)
    return top + fy * (bottom - top)


def pixel_grid(height: int, width: int, dtype) -> tuple[Array, Array]:
    """Column (x) and row (y) coordinates of the pixel centres, (1, H, W) each."""
    y = jnp.broadcast_to(jnp.arange(height, dtype=dtype).reshape(1, height, 1), (1, height, width))
    x = jnp.broadcast_to(jnp.arange(width, dtype=dtype).reshape(1, 1, width), (1, height, width))
    return x, y
