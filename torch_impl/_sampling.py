"""Reading an image at per-pixel positions, bilinear or nearest, clamped to the border."""

from __future__ import annotations

import torch
from torch import Tensor


#: The half types, whose positions, offsets and interpolation weights are held in float32: in them
#: pixel coordinates round to 0.25 px at 256 px (float16) or to 2 px (bfloat16).
HALF = (torch.float16, torch.bfloat16)


def position_dtype(dtype: torch.dtype) -> torch.dtype:
    """The dtype of positions and of the arithmetic on values read: float32 for the half types,
    else `dtype` (float32 and float64 compute as before)."""
    return torch.float32 if dtype in HALF else dtype


def _clamp(x: Tensor, high: float) -> Tensor:
    # where, not clamp: the gradient at the border is the inside's, as in the JAX backend.
    return torch.where(x < 0, 0.0, torch.where(x > high, high, x))


# The integer indices are clamped at both ends although the positions already are: a NaN position
# (reachable under torch.compile, which skips the data checks) passes `_clamp` and converts to an
# arbitrary integer. Eagerly torch.gather raised; inductor's generated code aborted the process
# ("index out of bounds: 0 <= tmp50 < 272", issue 25). Clamped, the reads stay in the image (and a
# bilinear read at a NaN position gives NaN).


def _gather(flat: Tensor, row: Tensor, column: Tensor, width: int) -> Tensor:
    """flat (B, C, H*W) at integer (row, column) of shape (B, H', W') -> (B, C, H', W')."""
    batch, channels, _ = flat.shape
    index = (row * width + column).reshape(batch, 1, -1).expand(batch, channels, -1)
    return torch.gather(flat, 2, index).reshape(batch, channels, *row.shape[1:])


def sample(image: Tensor, x: Tensor, y: Tensor, mode: str) -> Tensor:
    """image (B, C, H, W) at positions x, y (B, H', W') in pixels (centres at integers).

    "bilinear" is differentiable in image, x and y; "nearest" rounds halves up (seed 000's
    [p + 0.5]) and is differentiable in image only. Positions beyond the border read the border.
    x and y may be wider than the image (float32 positions for a half image): the values read are
    interpolated, and returned, in x's dtype.
    """
    batch, channels, height, width = image.shape
    flat = image.reshape(batch, channels, height * width)
    x = _clamp(x, width - 1.0)
    y = _clamp(y, height - 1.0)
    if mode == "nearest":
        column = torch.floor(x + 0.5).long().clamp(0, width - 1)
        row = torch.floor(y + 0.5).long().clamp(0, height - 1)
        return _gather(flat, row, column, width).to(x.dtype)
    x0 = torch.floor(x)
    y0 = torch.floor(y)
    fx = (x - x0).unsqueeze(1)
    fy = (y - y0).unsqueeze(1)
    # Clamped again as integers: should positions be held in bfloat16, the border W - 1 itself
    # rounds up past the image beyond 256 px (float16 beyond 2048 px).
    column0, row0 = x0.long().clamp(0, width - 1), y0.long().clamp(0, height - 1)
    column1 = (column0 + 1).clamp(max=width - 1)
    row1 = (row0 + 1).clamp(max=height - 1)
    # a + f (b - a), not (1 - f) a + f b: equal neighbours give exactly their value, so equal depths
    # stay tied (soft_depth_compare has a kink there) whatever the rounding of each framework.
    read = lambda row, column: _gather(flat, row, column, width).to(x.dtype)  # noqa: E731
    top_left = read(row0, column0)
    bottom_left = read(row1, column0)
    top = top_left + fx * (read(row0, column1) - top_left)
    bottom = bottom_left + fx * (read(row1, column1) - bottom_left)
    return top + fy * (bottom - top)


def pixel_grid(height: int, width: int, like: Tensor) -> tuple[Tensor, Tensor]:
    """Column (x) and row (y) coordinates of the pixel centres, (1, H, W) each, on like's device, in
    `position_dtype(like.dtype)` (float32 for a half image)."""
    dtype = position_dtype(like.dtype)
    y = torch.arange(height, dtype=dtype, device=like.device).reshape(1, height, 1).expand(1, height, width)
    x = torch.arange(width, dtype=dtype, device=like.device).reshape(1, 1, width).expand(1, height, width)
    return x, y
