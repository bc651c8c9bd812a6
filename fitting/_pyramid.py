"""Coarse-to-fine: an image pyramid of the fitting problem (NumPy).

Level k halves the previous level's size k times: colours, target and background are averaged over
2 x 2 blocks (a box prefilter), depth, IDs and masks are subsampled (they must stay consistent with
each other, and an ID cannot be averaged), velocities are averaged and halved (they are in pixels).
"""

from __future__ import annotations

import numpy as np


def _average(x: np.ndarray) -> np.ndarray:
    b, c, h, w = x.shape
    h2, w2 = h // 2, w // 2
    return x[:, :, : 2 * h2, : 2 * w2].reshape(b, c, h2, 2, w2, 2).mean(axis=(3, 5))


def _subsample(x: np.ndarray) -> np.ndarray:
    b, c, h, w = x.shape
    return x[:, :, : 2 * (h // 2) : 2, : 2 * (w // 2) : 2]


#: How each named array goes down one level.
_HOW = {"color": "average", "target": "average", "background": "average", "velocity": "velocity", "depth": "subsample", "ids": "subsample", "layer_ids": "subsample", "mask": "subsample", "weight": "subsample"}


def pyramid(arrays: dict[str, np.ndarray | None], levels: int) -> list[dict[str, np.ndarray | None]]:
    """[finest, ..., coarsest]: `levels` dicts of the same names (None stays None)."""
    out = [dict(arrays)]
    for _ in range(levels - 1):
        down = {}
        for name, x in out[-1].items():
            if x is None:
                down[name] = None
            elif _HOW[name] == "average":
                down[name] = _average(x)
            elif _HOW[name] == "velocity":
                down[name] = 0.5 * _average(x)
            else:
                down[name] = _subsample(x)
        out.append(down)
    return out


def max_levels(height: int, width: int, smallest: int = 8) -> int:
    """How many levels keep every level at least `smallest` pixels on each side."""
    levels = 1
    while min(height, width) // 2 ** levels >= smallest:
        levels += 1
    return levels
