"""Pyramid (texture-space, seed 001) blur for large motion: the pre-filtered levels in one flat atlas
and their trilinear read (definitions in `diffblur._pyramid`)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from diffblur._pyramid import level_of_detail, level_sizes


class Pyramid:
    """The levels of a (B, C, H, W) image, flattened into one (B, C, N) atlas."""

    def __init__(self, image: Tensor):
        sizes = level_sizes(*image.shape[2:])
        levels = [image]
        for h, w in sizes[1:]:
            previous = levels[-1]
            padded = F.pad(previous, (0, 2 * w - previous.shape[3], 0, 2 * h - previous.shape[2]), mode="replicate")
            levels.append(0.25 * (padded[:, :, 0::2, 0::2] + padded[:, :, 0::2, 1::2] + padded[:, :, 1::2, 0::2] + padded[:, :, 1::2, 1::2]))
        self.count = len(sizes)
        self.atlas = torch.cat([level.flatten(2) for level in levels], dim=2)
        offsets = [0]
        for h, w in sizes[:-1]:
            offsets.append(offsets[-1] + h * w)
        device = image.device
        self.heights = torch.tensor([h for h, _ in sizes], device=device)
        self.widths = torch.tensor([w for _, w in sizes], device=device)
        self.offsets = torch.tensor(offsets, device=device)

    def _gather(self, index: Tensor) -> Tensor:
        batch, channels, _ = self.atlas.shape
        flat = index.reshape(batch, 1, -1).expand(batch, channels, -1)
        return torch.gather(self.atlas, 2, flat).reshape(batch, channels, *index.shape[1:])

    def _read(self, level: Tensor, x: Tensor, y: Tensor) -> Tensor:
        """Bilinear at level `level`, in x's dtype (float32 positions for a half image)."""
        width, height, offset = self.widths[level], self.heights[level], self.offsets[level]
        scale = torch.exp2(level.to(x.dtype))
        x = torch.where(level == 0, x, (x + 0.5) / scale - 0.5)
        y = torch.where(level == 0, y, (y + 0.5) / scale - 0.5)
        high_x, high_y = (width - 1).to(x.dtype), (height - 1).to(y.dtype)
        x = torch.where(x < 0, 0.0, torch.where(x > high_x, high_x, x))
        y = torch.where(y < 0, 0.0, torch.where(y > high_y, high_y, y))
        x0, y0 = torch.floor(x), torch.floor(y)
        fx, fy = (x - x0).unsqueeze(1), (y - y0).unsqueeze(1)
        column0, row0 = torch.minimum(x0.long(), width - 1).clamp(min=0), torch.minimum(y0.long(), height - 1).clamp(min=0)  # (NaN: `_sampling`)
        column1 = torch.minimum(column0 + 1, width - 1)
        row1 = torch.minimum(row0 + 1, height - 1)
        read = lambda index: self._gather(index).to(x.dtype)  # noqa: E731
        top_left = read(offset + row0 * width + column0)
        bottom_left = read(offset + row1 * width + column0)
        top = top_left + fx * (read(offset + row0 * width + column1) - top_left)
        bottom = bottom_left + fx * (read(offset + row1 * width + column1) - bottom_left)
        return top + fy * (bottom - top)

    def sample(self, x: Tensor, y: Tensor, lod: Tensor) -> Tensor:
        """(B, C, H', W') at image points x, y (B, H', W') and levels of detail lod (B, H', W'), in
        x's dtype."""
        low = torch.floor(lod).long().clamp(0, self.count - 1)
        high = (low + 1).clamp(max=self.count - 1)
        fraction = (lod - low.to(lod.dtype)).unsqueeze(1)
        below = self._read(low, x, y)
        return below + fraction * (self._read(high, x, y) - below)

    def level_of_detail(self, spacing: Tensor) -> Tensor:
        return level_of_detail(spacing, self.count, torch)
