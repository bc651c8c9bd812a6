"""Tiled adaptive sampling (seed 001) with the still-tile early-out (seed 000), framework-neutral.

The image is cut into tiles; each tile's speed r (the largest |V| in the tile for `gather_blur`,
the tile's |NeighborMax| for `reconstruct`) picks one of a few sample-count classes: the smallest
class with at least 2 r taps (one tap per pixel travelled along the path X - V ... X + V), or the
full rate `samples` when no smaller class is enough. Still tiles (r <= STILL_SPEED, or below the
early-out's EARLY_OUT_SPEED, 0.5 px more, when `reconstruct`'s early_out is on) take 0 taps: they return the
image. A tile whose class is the full rate gets exactly the full-rate filter's result.

The backends make the saving real by grouping the tiles of each class and running that class's
filter on the compacted pixels of its tiles only (eager mode). Under `torch.compile` / `jax.jit`
the classes are data the compiler cannot size, so the backends compute every class on every pixel
and select per tile: the same result, no saving (`ADAPTIVE_COMPILED_NOTE`). The fused CPU paths of
`reconstruct` and `gather_blur` (`diffblur.kernels.reconstruct`, `diffblur.kernels.gather`) take the per-tile counts into their kernels
instead, which saves the work eagerly and under `jax.jit` alike.
"""

from __future__ import annotations

import numbers
from typing import Any

import numpy as np

from diffblur.conventions import EARLY_OUT_SPEED, STILL_SPEED

__all__ = [
    "ADAPTIVE_TILE",
    "STILL_SPEED",
    "adaptive_classes",
    "class_pixels",
    "still_speed",
    "tile_sample_counts",
]

#: Tile size, in pixels, of gather_blur's adaptive classification (reconstruct uses its own tiles).
ADAPTIVE_TILE = 16

ADAPTIVE_COMPILED_NOTE = (
    "under torch.compile / jax.jit the tile classes are data-dependent sizes, so every class runs on "
    "every pixel and the result is selected per tile: the same output as eager mode, without the saving"
)


def adaptive_classes(adaptive: object, samples: int) -> tuple[int, ...] | None:
    """The sample-count classes, ascending and ending with `samples` (the full rate), or None when
    adaptive sampling is off. adaptive: False (off), True (3, 7, 15, 31, ... below samples, then
    samples) or a sequence of odd counts <= samples."""
    if adaptive is False or adaptive is None:
        return None
    if adaptive is True:
        classes = []
        count = 3
        while count < samples:
            classes.append(count)
            count = 2 * count + 1
        return (*classes, samples)
    if not isinstance(adaptive, (tuple, list)) or not adaptive:
        raise TypeError(f"adaptive must be a bool or a non-empty sequence of odd sample counts, got {adaptive!r}")
    for count in adaptive:
        if not isinstance(count, numbers.Integral) or isinstance(count, bool) or count < 1 or count % 2 == 0 or count > samples:
            raise ValueError(f"adaptive classes must be odd integers in [1, samples={samples}], got {tuple(adaptive)!r}")
    return tuple(sorted({int(c) for c in adaptive} | {samples}))


def still_speed(early_out: bool) -> float:
    """The speed up to which a tile is still (`diffblur.conventions.STILL_SPEED`), or the early-out's
    EARLY_OUT_SPEED."""
    return EARLY_OUT_SPEED if early_out else STILL_SPEED


def tile_sample_counts(speed: Any, classes: tuple[int, ...], still: float, xp: Any) -> Any:
    """Per tile, the taps its class takes (0 for a still tile), from the tile speed (any shape);
    numpy, torch and jax.numpy arrays alike (where and comparisons only)."""
    counts = xp.where(speed <= still, 0, classes[-1])
    for count in reversed(classes[:-1]):
        counts = xp.where((speed > still) & (2.0 * speed <= count), count, counts)
    return counts


def class_pixels(counts: np.ndarray, count: int, tile: int, height: int, width: int) -> np.ndarray:
    """Flat indices b * H * W + y * W + x (int64, ascending) of the pixels of the tiles whose count is
    `count`; counts is (B, TH, TW) NumPy. Partial tiles at the border keep their pixels inside."""
    batch_index, tile_y, tile_x = np.nonzero(counts == count)
    offsets = np.arange(tile)
    y = tile_y[:, None, None] * tile + offsets[None, :, None]
    x = tile_x[:, None, None] * tile + offsets[None, None, :]
    y, x = np.broadcast_arrays(y, x)
    b = np.broadcast_to(batch_index[:, None, None], y.shape)
    inside = (y < height) & (x < width)
    return np.sort((b * height * width + y * width + x)[inside].astype(np.int64))


def select_by_tile(color: np.ndarray, by_count: dict[int, np.ndarray], counts: np.ndarray, tile: int) -> np.ndarray:
    """NumPy: per pixel, the output of its tile's class (color where the tile is still)."""
    _, _, height, width = color.shape
    pixel_counts = np.repeat(np.repeat(counts, tile, axis=1), tile, axis=2)[:, None, :height, :width]
    out = color.copy()
    for count, filtered in by_count.items():
        out = np.where(pixel_counts == count, filtered, out)
    return out


__all__ += ["select_by_tile"]
