"""Tiled adaptive sampling (seed 001) with the still-tile early-out (seed 000), framework-neutral.

The image is cut into tiles; each tile's speed r (the largest |V| in the tile for `gather_blur`,
the tile's |NeighborMax| for `reconstruct`) picks one of a few sample-count classes: the smallest
class with at least 2 r taps (one tap per pixel travelled along the path X - V ... X + V), or the
full rate `samples` when no smaller class is enough. Still tiles (r <= STILL_SPEED, or below the
early-out's EARLY_OUT_SPEED, 0.5 px more, when `reconstruct`'s early_out is on) take 0 taps: they return the
image. A tile whose class is the full rate gets exactly the full-rate filter's result.

The ops make the saving real by grouping the tiles of each class and running that class's filter
on the compacted pixels of its tiles only (eager mode): images are read as (B * H * W, K) tables, a
pixel is its flat index b * H * W + y * W + x (`table`, `class_rows`, `sample_rows`). Under `torch.compile` / `jax.jit`
the classes are data the compiler cannot size, so the backends compute every class on every pixel
and select per tile: the same result, no saving (`ADAPTIVE_COMPILED_NOTE`). The fused CPU paths of
`reconstruct` and `gather_blur` (`diffblur.kernels.reconstruct`, `diffblur.kernels.gather`) take the per-tile counts into their kernels
instead, which saves the work eagerly and under `jax.jit` alike.
"""

from __future__ import annotations

import numbers
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from diffblur.conventions import EARLY_OUT_SPEED, STILL_SPEED
from diffblur.ops.sampling import bilinear_read, position_dtype

__all__ = [
    "ADAPTIVE_TILE",
    "JIT_MIN_PIXELS",
    "ClassRows",
    "class_rows",
    "compiled_if_worth",
    "coordinates",
    "pixel_counts",
    "sample_rows",
    "select",
    "table",
    "tile_index",
    "untable",
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


# -- the compacted filters' tables, in a backend's ops -------------------------------------------------

#: With fewer moving pixels than this, a backend that compiles (JAX) runs the compacted filter op by
#: op: compiling it would cost more than it saves.
JIT_MIN_PIXELS = 4096


def table(be: Any, image: Any) -> Any:
    """(B, K, H, W) -> (B * H * W, K), one row per pixel."""
    batch, channels, height, width = image.shape
    return be.permute(image, (0, 2, 3, 1)).reshape(batch * height * width, channels)


def untable(be: Any, rows: Any, batch: int, height: int, width: int) -> Any:
    return be.contiguous(be.permute(rows.reshape(batch, height, width, -1), (0, 3, 1, 2)))


def sample_rows(be: Any, rows: Any, base: Any, x: Any, y: Any, height: int, width: int, mode: str) -> Any:
    """rows (B * H * W, K) at positions x, y (P,) of the images starting at rows `base` (P,), read as
    `diffblur.ops.sampling.sample` reads an image, in x's dtype."""
    return bilinear_read(be, lambda row, column: rows[base + row * width + column], x, y, height, width, mode)


def coordinates(be: Any, index: Any, height: int, width: int, dtype: Any) -> tuple[Any, Any, Any]:
    """Row base b * H * W, and x, y (P,) in `position_dtype(dtype)`, of flat pixel indices."""
    plane = height * width
    within = index % plane
    dtype = position_dtype(be, dtype)
    return index - within, be.astype(within % width, dtype), be.astype(within // width, dtype)


def tile_index(index: Any, height: int, width: int, tile: int, tiles_y: int, tiles_x: int) -> Any:
    """The flat index b * TH * TW + ty * TW + tx of each flat pixel index's tile, in integers."""
    plane = height * width
    within = index % plane
    return (index // plane) * (tiles_y * tiles_x) + (within // width // tile) * tiles_x + (within % width) // tile


def pixel_counts(be: Any, counts: Any, tile: int, height: int, width: int) -> Any:
    """(B, TH, TW) tile counts -> (B, 1, H, W) per pixel."""
    return be.repeat(be.repeat(counts, tile, 1), tile, 2)[:, None, :height, :width]


def select(be: Any, color: Any, by_count: dict[int, Any], counts: Any) -> Any:
    """Per pixel, the output of its tile's class (`counts` per pixel), color where the tile is still."""
    out = color
    for count, filtered in by_count.items():
        out = be.xp.where(counts == count, filtered, out)
    return out


class ClassRows(NamedTuple):
    """A class's pixels: its tap count, the rows to read and to write (`Backend.row_indices`), and how
    many pixels it has."""

    count: int
    read: Any
    write: Any
    size: int


def class_rows(be: Any, counts: np.ndarray, classes: tuple[int, ...], tile: int, color: Any) -> list[ClassRows]:
    """For each class with tiles, its pixels (counts: (B, TH, TW) NumPy tap counts per tile)."""
    batch, _, height, width = color.shape
    found = []
    for count in classes:
        pixels = class_pixels(counts, count, tile, height, width)
        if pixels.size:
            found.append(ClassRows(count, *be.row_indices(pixels, batch * height * width, color), pixels.size))
    return found


def compiled_if_worth(be: Any, function: Callable, found: list[ClassRows], static_argnames: tuple[str, ...], *, hashable: bool = True) -> Callable:
    """`function` compiled whole by the backend (`Backend.compiled`) when the classes have
    JIT_MIN_PIXELS pixels or more and its static arguments can key a cache, else as it is."""
    if hashable and sum(rows.size for rows in found) >= JIT_MIN_PIXELS:
        return be.compiled(function, static_argnames)
    return function
