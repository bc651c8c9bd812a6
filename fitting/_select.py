"""`select_model`: the simplest model that explains the target, tried from the simplest up."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from diffblur import checks
from fitting._models import MODELS, Layers, MotionIds, Rotation, Tiles, away_from_boundaries, depth_layers
from fitting._recover import FitResult, recover

#: Tried in this order among models of equal size; `dense` is left out unless asked for, `layers`
#: is tried only with depth and `motion_ids` only with ids.
DEFAULT_CANDIDATES = ("global", "rotation", "layers", "motion_ids", "camera", "tiles")


@dataclass
class Selection:
    """choice: the model picked; reason: why, in words; table: per model tried, its parameter count,
    loss, criterion and verdict; fits: the FitResult of every model tried."""

    choice: str
    reason: str
    table: list[dict[str, Any]]
    fits: dict[str, FitResult] = field(repr=False)


def _size(model: str, palette_size: int, layer_count: int, grid: tuple[int, int]) -> int:
    return {"global": 2, "rotation": 3, "camera": 4, "motion_ids": 2 * palette_size, "layers": 2 * layer_count, "tiles": 2 * grid[0] * grid[1]}.get(model, 10**9)


def bic(result: FitResult) -> float:
    """Bayesian information criterion of a fit with Gaussian residuals: n log(mse) + k log(n)."""
    n = max(result.pixels, 1)
    return n * math.log(max(result.loss, 1e-300)) + result.n_params * math.log(n)


def select_model(
    sharp: Any,
    target: Any,
    *,
    depth: Any = None,
    ids: Any = None,
    boundary: float = 0,
    background: Any = None,
    candidates: tuple[str, ...] | None = None,
    min_gain: float = 0.05,
    floor: float = 1e-5,
    patience: int = 2,
    grid: tuple[int, int] = (3, 3),
    **options: Any,
) -> Selection:
    """Fit candidate models from the fewest parameters up; keep a richer one only when it pays.

    A richer model pays when it lowers the Bayesian information criterion (n log(mse) + k log(n),
    n residuals, k parameters) and also lowers the loss by at least `min_gain` (5 %): the renderer's
    own error is correlated across pixels, which the criterion assumes independent, so a few extra
    parameters always shave a little off it. Losses below `floor` (a mean squared error of 1e-5,
    about the renderers' own error on a translation) count as equal: there a gain is the solvers'
    convergence, not the model. The search stops after `patience` richer models in a row
    that do not pay, except that `layers` is always tried when the depth has layers (a scene of
    several moving depth layers explains little through the smaller models, which would stop the
    search before it). `motion_ids` is a candidate only with `ids` (`fitting.MotionIds(ids)`), `layers`
    (a velocity per depth layer, `fitting.depth_layers`) only with `depth` that has more than one
    layer. With `ids`, every candidate leaves out the pixels within `boundary` pixels of a change of
    ID, so that all are scored on the same pixels. `background` goes to `rotation`
    (`fitting.Rotation(background=...)`), `grid` to `tiles`. Other keyword options go to `recover`
    (backend, method, solver, iterations, levels, ...).

    Returns a `Selection` (choice, reason, table, fits).
    """
    layer_count = int(depth_layers(np.asarray(depth, dtype=np.float64))[0].max()) + 1 if depth is not None else 0
    candidates = tuple(c for c in (DEFAULT_CANDIDATES if candidates is None else candidates) if (c != "motion_ids" or ids is not None) and (c != "layers" or layer_count > 1))
    for name in candidates:
        checks.require_choice("candidates", name, MODELS)
        if name in ("exposure", "shutter"):
            raise ValueError(f"candidates must be motion models that need no known motion, got {name!r}")
    if not candidates:
        raise ValueError("candidates must name at least one model")
    patience = checks.require_positive_int("patience", patience)
    min_gain = checks.require_in_interval("min_gain", min_gain, 0.0, 1.0)
    floor = checks.require_nonnegative_number("floor", floor)
    palette_size = int(np.max(ids)) + 1 if ids is not None else 0
    weight = away_from_boundaries(np.asarray(ids), checks.require_nonnegative_number("boundary", boundary)) if ids is not None else None
    order = sorted(candidates, key=lambda m: (_size(m, palette_size, layer_count, grid), candidates.index(m)))

    fits: dict[str, FitResult] = {}
    table: list[dict[str, Any]] = []
    best: str | None = None
    misses = 0
    for name in order:
        model = {"motion_ids": lambda: MotionIds(ids), "layers": Layers, "rotation": lambda: Rotation(background=background), "tiles": lambda: Tiles(grid)}.get(name, lambda: name)()
        with warnings.catch_warnings():  # a candidate that cannot explain the scene is expected here
            warnings.simplefilter("ignore", UserWarning)
            fits[name] = fit = recover(sharp, target, model=model, depth=depth, weight=weight, **options)
        row = {"model": name, "n_params": fit.n_params, "loss": fit.loss, "bic": bic(fit)}
        if best is None:
            row["verdict"] = "baseline"
            best = name
        else:
            gain = 1.0 - max(fit.loss, floor) / max(fits[best].loss, floor)
            pays = row["bic"] < bic(fits[best]) and gain >= min_gain
            row["verdict"] = f"{'pays' if pays else 'does not pay'}: loss {gain:+.1%} vs {best}, BIC {row['bic'] - bic(fits[best]):+.0f}"
            if pays:
                best, misses = name, 0
            else:
                misses += 1
        table.append(row)
        if misses >= patience and "layers" not in order[order.index(name) + 1 :]:
            break
    chosen = fits[best]
    others = [r for r in table if r["model"] != best]
    reason = f"{best} ({chosen.n_params} parameters, loss {chosen.loss:.3g}): " + (
        "; ".join(f"{r['model']} ({r['n_params']} parameters, loss {r['loss']:.3g}) {r['verdict']}" for r in others) if others else "the only candidate"
    )
    return Selection(best, reason, table, fits)
