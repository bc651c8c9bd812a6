"""Reading an image at per-pixel positions, bilinear or nearest, clamped to the border; the pixel grid.

Written once for both frameworks against a `Backend` (`diffblur.ops.backend`); the NumPy oracle's
reads are `diffblur.reference.sample_bilinear` and `sample_nearest`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

__all__ = ["bilinear_read", "clamp", "pixel_grid", "position_dtype", "sample"]


def position_dtype(be: Any, dtype: Any) -> Any:
    """The dtype of positions and of the arithmetic on values read: float32 for the half types (in
    them pixel coordinates round to 0.25 px at 256 px in float16, to 2 px in bfloat16), else `dtype`."""
    return be.xp.float32 if dtype in be.half else dtype


def clamp(be: Any, x: Any, high: float) -> Any:
    """x clamped to [0, high] with `where`, not clip: the gradient at the border is the inside's
    (jnp.clip halves it at a tie)."""
    xp = be.xp
    return be.astype(xp.where(x < 0, 0.0, xp.where(x > high, high, x)), x.dtype)


def _clamp_index(be: Any, index: Any, high: int) -> Any:
    # Integer indices are clamped at both ends although the positions already are: a NaN position
    # (reachable under torch.compile, which skips the data checks) passes `clamp` and converts to an
    # arbitrary integer, which inductor's generated code would read out of bounds.
    xp = be.xp
    return xp.where(index < 0, 0, xp.where(index > high, high, index))


def bilinear_read(be: Any, read: Callable[[Any, Any], Any], x: Any, y: Any, height: int, width: int, mode: str) -> Any:
    """The values at positions x, y (any shape, in pixels, centres at integers) of an image of
    height x width pixels, given `read(row, column)`, which returns the values at integer positions
    with a new axis 1 for the values (e.g. (B, C, H', W') for x of shape (B, H', W')).

    "bilinear" is differentiable in the values and the positions; "nearest" rounds halves up (seed
    000's [p + 0.5]) and is differentiable in the values only. Positions beyond the border read the
    border. The values are interpolated, and returned, in x's dtype (x may be wider than the image:
    float32 positions for a half image)."""
    xp = be.xp
    x = clamp(be, x, width - 1.0)
    y = clamp(be, y, height - 1.0)
    if mode == "nearest":
        column = _clamp_index(be, be.index(xp.floor(x + 0.5)), width - 1)
        row = _clamp_index(be, be.index(xp.floor(y + 0.5)), height - 1)
        return be.astype(read(row, column), x.dtype)
    x0 = be.stop_gradient(xp.floor(x))
    y0 = be.stop_gradient(xp.floor(y))
    fx = (x - x0)[:, None]
    fy = (y - y0)[:, None]
    # Clamped again as integers: should positions be held in bfloat16, the border W - 1 itself
    # rounds up past the image beyond 256 px (float16 beyond 2048 px).
    column0, row0 = _clamp_index(be, be.index(x0), width - 1), _clamp_index(be, be.index(y0), height - 1)
    column1 = _clamp_index(be, column0 + 1, width - 1)
    row1 = _clamp_index(be, row0 + 1, height - 1)
    # a + f (b - a), not (1 - f) a + f b: equal neighbours give exactly their value, so equal depths
    # stay tied (soft_depth_compare has a kink there) whatever the rounding of each framework.
    top_left = be.astype(read(row0, column0), x.dtype)
    bottom_left = be.astype(read(row1, column0), x.dtype)
    top = top_left + fx * (be.astype(read(row0, column1), x.dtype) - top_left)
    bottom = bottom_left + fx * (be.astype(read(row1, column1), x.dtype) - bottom_left)
    return top + fy * (bottom - top)


def sample(be: Any, image: Any, x: Any, y: Any, mode: str) -> Any:
    """image (B, C, H, W) at positions x, y (B, H', W') -> (B, C, H', W'), as `bilinear_read`."""
    batch, channels, height, width = image.shape
    flat = image.reshape(batch, channels, height * width)
    return bilinear_read(be, lambda row, column: be.read_pixels(flat, row * width + column), x, y, height, width, mode)


def pixel_grid(be: Any, height: int, width: int, like: Any) -> tuple[Any, Any]:
    """Column (x) and row (y) coordinates of the pixel centres, (1, H, W) each, where `like` is (its
    device), in `position_dtype(like.dtype)` (float32 for a half image)."""
    xp = be.xp
    dtype = position_dtype(be, like.dtype)
    y = xp.broadcast_to(be.arange(height, dtype, like).reshape(1, height, 1), (1, height, width))
    x = xp.broadcast_to(be.arange(width, dtype, like).reshape(1, 1, width), (1, height, width))
    return x, y
