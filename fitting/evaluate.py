"""The held-out evaluation of recovery: `python -m fitting.evaluate`.

Fits the models each case of the frozen family (`fitting.heldout`) calls for, with the library's
defaults (no init, levels, solver or iterations; only depth=, shutter= and what the model needs are
passed: the point is to measure what a new user gets), and compares the parameters with the truth:

| kind | model | error (unit) |
|---|---|---|
| pan | global, every method | largest component of the velocity error (px) |
| objects | motion_ids (ids = the layer map) | largest per-layer velocity error (px), ID k = layer k |
| objects | layers (when `fitting.MODELS` has it) | the same, each true layer matched to the fitted depth nearest its own |
| objects | exposure (velocity = buffers.velocity / 0.6) | exposure error relative to 0.6 (%) |
| rotation | rotation (background = the still background) | angle error relative to the angle (%) |
| zoom | camera, every method | advance error relative to the first-order advance (%), see `fitting.heldout`; the pan's error (px at the background's depth) is reported too |

Errors are up to sign where the shutter is symmetric (`fitting._models.is_symmetric`), where the blur
cannot tell +v from -v. A fit that raises is kept as a row with its message, error inf, not converged.
`converged` is the fit's own `converged` attribute where `FitResult` has one ("n/a" otherwise).

Which fits, and the cost: `global` and `camera` fit every method of `fitting._recover.METHODS` (reconstruct,
gather, and scatter where it exists; the non-default ones on the first backend only, torch:
`--every-method-backends torch,jax` for both); every other model fits only its default method (recover's
`DEFAULT_METHODS` where it has them, else reconstruct: what `recover` takes when given no method);
rotation always goes through the arc scatter (method "arc"). The model's data (ids, the known
velocity, the still background) goes to `recover` as keywords where it takes them, else on the model
object (`fitting.MotionIds(ids=...)`, ...). Every fit runs noise-free on every backend; the noisy
fits (the case's gaussian noise, sigma 0.01) run through the default method only and on the first
backend only (torch; `--noisy-backends torch,jax` for both). The choice is the cost: the default run is 178 fits, 22.8 min on the shared 2-core machine
(2026-12-02). A torch fit took 0.2-37 s (layers and motion IDs of three objects the slow ones), a
JAX fit about the same where its compiled loss was already there (`recover` compiles each level's
loss once per image size, model options, shutter and speed bucket, and reuses it), and 5-12 s
where it compiled (measured before the one-shot pieces went back to op by op). 64 px rather than 48:
a fit's time hardly depends on the size here, and 48 px leaves no room for large fast objects.
`--threads 1` (the default) runs each framework single-threaded: on a shared 2-core machine that is
several times faster for 64 x 64 images (torch: a gather fit 2.2 s -> 0.23 s under load), and the
parameters found were identical to the last digit in the fits compared.

Targets (DESIGN.md, recovery): velocities within 0.1 px median and 0.25 px at the 90th percentile
noise-free, 0.5 px (median) with noise; per-layer velocities within 0.25 px (0.5 px with noise);
exposure within 1 %; rotation within 2 %. "within" in the table is the fraction of fits within the
median target. The camera's advance has no target.

`main` prints the summary, writes the rows and the summary to --json (docs/heldout.json), and
replaces its section of BENCHMARKS.md (between `<!-- heldout:start -->` and `<!-- heldout:end -->`,
or `<!-- heldout:LABEL:start -->` ... with --label before|after), appending it if missing.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import subprocess
import sys
import time
import warnings
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from diffblur.shutters import get_shutter
from fitting.heldout import DEVELOPMENT_SEED, HELDOUT_SEED, NOISE_SIGMA, Case, family

__all__ = ["TARGETS", "error_of", "evaluate", "main", "markdown_table", "plan", "summarize", "write_section"]

#: The exposure the objects' "exposure" fits must find: they are given velocity = buffers.velocity / 0.6.
TRUE_EXPOSURE = 0.6
#: Models per kind, in the order they are fitted (those missing from fitting.MODELS are skipped).
KIND_MODELS = {"pan": ("global",), "objects": ("motion_ids", "layers", "exposure"), "rotation": ("rotation",), "zoom": ("camera",)}
#: Models fitted through every method; the others use the first method only.
ALL_METHODS_MODELS = ("global", "camera")
MODEL_ORDER = ("global", "motion_ids", "layers", "exposure", "rotation", "camera")
UNITS = {"global": "px", "motion_ids": "px", "layers": "px", "exposure": "%", "rotation": "%", "camera": "%"}
#: (median target, 90th percentile target or None) by model and by noise-free (False) / noisy (True).
TARGETS: dict[str, dict[bool, tuple[float, float | None]]] = {
    "global": {False: (0.1, 0.25), True: (0.5, None)},
    "motion_ids": {False: (0.25, None), True: (0.5, None)},
    "layers": {False: (0.25, None), True: (0.5, None)},
    "exposure": {False: (1.0, None), True: (1.0, None)},
    "rotation": {False: (2.0, None), True: (2.0, None)},
}


def _methods() -> tuple[str, ...]:
    from fitting import _recover

    return tuple(_recover.METHODS)


def default_method(model: str, methods: Sequence[str] | None = None) -> str:
    """The method `recover` takes for `model` when given none (its `DEFAULT_METHODS` where fitting has
    them, else the first of METHODS), or the first of `methods` if that one is not among them."""
    from fitting import _recover

    methods = _methods() if methods is None else tuple(methods)
    default = getattr(_recover, "DEFAULT_METHODS", {}).get(model, _recover.METHODS[0])
    return default if default in methods else methods[0]


def _models() -> tuple[str, ...]:
    import fitting

    return tuple(fitting.MODELS)


def plan(
    cases: Sequence[Case],
    *,
    backends: Sequence[str] = ("torch", "jax"),
    models: Iterable[str] | None = None,
    methods: Iterable[str] | None = None,
    noise: Sequence[float] = (0.0, NOISE_SIGMA),
    noisy_backends: Sequence[str] | None = None,
    every_method_backends: Sequence[str] | None = None,
) -> list[dict[str, Any]]:
    """The fits `evaluate` runs: dicts of case, model, method, noise, backend (see the module
    docstring). Noisy fits (noise > 0) go through each model's default method (`default_method`) and
    `noisy_backends` only (default: the first of `backends`); the other methods of the models that
    fit every method run on `every_method_backends` only (default: the first of `backends`)."""
    noisy_backends = tuple(backends[:1]) if noisy_backends is None else tuple(noisy_backends)
    every_method_backends = tuple(backends[:1]) if every_method_backends is None else tuple(every_method_backends)
    methods = None if methods is None else list(methods)
    available = _models()
    wanted_models = None if models is None else set(models)
    all_methods = _methods()
    chosen = [m for m in all_methods if methods is None or m in set(methods)]
    unknown = [] if methods is None else [m for m in methods if m not in all_methods]
    if unknown:
        raise ValueError(f"unknown method(s) {', '.join(unknown)}; recover knows {', '.join(all_methods)}")
    fits = []
    for case in cases:
        for model in KIND_MODELS[case.kind]:
            if model not in available or (wanted_models is not None and model not in wanted_models):
                continue
            if model == "rotation":
                model_methods, noisy_method = ["arc"], "arc"
            else:
                noisy_method = default_method(model, chosen)
                model_methods = chosen if model in ALL_METHODS_MODELS else [noisy_method]
            for sigma in noise:
                for method in model_methods if sigma == 0 else [noisy_method]:
                    if sigma > 0:
                        method_backends = [b for b in backends if b in noisy_backends]
                    elif method != noisy_method:
                        method_backends = [b for b in backends if b in every_method_backends]
                    else:
                        method_backends = list(backends)
                    for backend in method_backends:
                        fits.append({"case": case, "model": model, "method": method, "noise": float(sigma), "backend": backend})
    return fits


#: The model classes of `fitting` (the API where a model object carries its data).
MODEL_CLASSES = {"global": "Global", "motion_ids": "MotionIds", "layers": "Layers", "exposure": "Exposure", "rotation": "Rotation", "camera": "CameraMotion"}


def _call(case: Case, model: str, method: str) -> tuple[Any, dict[str, Any]]:
    """(model argument, keyword arguments) of the `recover` call: depth, shutter, the method (none
    for the arc scatter of `rotation`) and the model's data (ids, the known velocity, the still
    background), as keywords where `recover` takes them, else on the model object (fitting.Exposure(
    velocity=...), ...), so that the evaluation runs on either API."""
    import inspect

    import fitting

    b = case.buffers
    kwargs: dict[str, Any] = {"depth": b.depth, "shutter": case.shutter}
    if method != "arc":
        kwargs["method"] = method
    data: dict[str, Any] = {}
    if model == "motion_ids":
        data["ids"] = case.ids
    elif model == "exposure":
        data["velocity"] = b.velocity / TRUE_EXPOSURE
    elif model == "rotation" and b.background is not None:
        data["background"] = b.background
    if not data:
        return model, kwargs
    accepted = inspect.signature(fitting.recover).parameters
    if all(name in accepted for name in data):
        return model, {**kwargs, **data}
    return getattr(fitting, MODEL_CLASSES[model])(**data), kwargs


def _up_to_sign(found: Any, truth: Any, symmetric: bool) -> float:
    found, truth = np.asarray(found, dtype=np.float64), np.asarray(truth, dtype=np.float64)
    error = float(np.max(np.abs(found - truth)))
    return min(error, float(np.max(np.abs(found + truth)))) if symmetric else error


def error_of(model: str, params: dict[str, Any], truth: dict[str, Any], symmetric: bool) -> tuple[float, dict[str, Any]]:
    """(error in the model's unit, extra errors) of fitted `params` against the case's `truth`."""
    if model == "global":
        return _up_to_sign(params["velocity"], truth["velocity"], symmetric), {}
    if model == "motion_ids":
        palette = np.asarray(params["palette"], dtype=np.float64).reshape(-1, 2)
        per_layer = [_up_to_sign(palette[k], layer["velocity"], symmetric) if k < len(palette) else math.inf for k, layer in enumerate(truth["layers"])]
        return max(per_layer), {"per_layer_px": per_layer}
    if model == "layers":
        palette = np.asarray(params["palette"], dtype=np.float64).reshape(-1, 2)
        depths = np.asarray(params["depths"], dtype=np.float64).reshape(-1)
        per_layer, matched = [], []
        for layer in truth["layers"]:
            k = int(np.argmin(np.abs(depths - layer["depth"])))
            matched.append(k)
            per_layer.append(_up_to_sign(palette[k], layer["velocity"], symmetric))
        return max(per_layer), {"per_layer_px": per_layer, "matched": matched}
    if model == "exposure":
        e = float(params["exposure"])
        miss = min(abs(e - TRUE_EXPOSURE), abs(e + TRUE_EXPOSURE)) if symmetric else abs(e - TRUE_EXPOSURE)
        return 100.0 * miss / TRUE_EXPOSURE, {}
    if model == "rotation":
        a, t = float(params["angle"]), float(truth["angle"])
        miss = min(abs(a - t), abs(a + t)) if symmetric else abs(a - t)
        center = float(np.max(np.abs(np.subtract(params["center"], truth["center"]))))
        return 100.0 * miss / abs(t), {"center_px": center}
    if model == "camera":
        a, t = float(params["advance"]), float(truth["advance_first_order"])
        miss = min(abs(a - t), abs(a + t)) if symmetric else abs(a - t)
        raw = min(abs(a - truth["advance"]), abs(a + truth["advance"])) if symmetric else abs(a - truth["advance"])
        pan_px = float(np.max(np.abs(params["pan"]))) / truth["depth"]
        return 100.0 * miss / abs(t), {"pan_px": pan_px, "roll": abs(float(params["roll"])), "advance_vs_camera_pct": 100.0 * raw / abs(truth["advance"])}
    raise ValueError(f"no error defined for model {model!r}")


def _plain(x: Any) -> Any:
    """JSON-ready copy: arrays to lists, numpy scalars to Python numbers."""
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return _plain(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    return x


def _within(model: str, noise: float, error: float) -> bool | None:
    target = TARGETS.get(model, {}).get(noise > 0)
    return None if target is None else bool(error <= target[0])


def fit_one(fit: dict[str, Any]) -> dict[str, Any]:
    """Run one planned fit; the row (failures included)."""
    import fitting
    from fitting import _models

    case: Case = fit["case"]
    model, method, backend, sigma = fit["model"], fit["method"], fit["backend"], fit["noise"]
    symmetric = _models.is_symmetric(get_shutter(case.shutter))
    row: dict[str, Any] = {"case": case.name, "kind": case.kind, "shutter": case.shutter_label, "symmetric": symmetric, "noise": sigma, "model": model, "method": method, "backend": backend, "unit": UNITS.get(model, "")}
    start = time.perf_counter()
    caught: list[str] = []
    try:
        with warnings.catch_warnings(record=True) as records:  # kept in the row, not printed
            warnings.simplefilter("always", UserWarning)
            model_argument, kwargs = _call(case, model, method)
            result = fitting.recover(case.buffers.color, case.target(sigma), model=model_argument, backend=backend, **kwargs)
        caught = [str(w.message)[:300] for w in records if issubclass(w.category, UserWarning)]
        for w in records:  # anything else goes on as usual
            if not issubclass(w.category, UserWarning):
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        error, extra = error_of(model, result.params, case.truth, symmetric)
        converged = getattr(result, "converged", None)
        row.update(
            error=error,
            extra=_plain(extra),
            converged=None if converged is None else bool(converged),
            explained=_plain(getattr(result, "explained", None)),
            method_shift=_plain(getattr(result, "method_shift", None)),
            solver=result.solver,
            steps=len(result.history),
            loss=float(result.loss),
            params=_plain(result.params),
            failed=False,
            message="",
        )
    except Exception as exc:  # a fit that raises is a failed fit, not a failed evaluation
        row.update(error=math.inf, extra={}, converged=False, explained=None, solver=None, steps=0, loss=None, params=None, failed=True, message=f"{type(exc).__name__}: {exc}"[:500])
    row["seconds"] = time.perf_counter() - start
    row["warnings"] = caught
    row["within"] = _within(model, sigma, row["error"])
    row["truth"] = _plain(case.truth)
    return row


def evaluate(
    cases: Sequence[Case] | None = None,
    *,
    backends: Sequence[str] = ("torch", "jax"),
    models: Iterable[str] | None = None,
    methods: Iterable[str] | None = None,
    noise: Sequence[float] = (0.0, NOISE_SIGMA),
    noisy_backends: Sequence[str] | None = None,
    every_method_backends: Sequence[str] | None = None,
    progress: bool = True,
) -> list[dict[str, Any]]:
    """One row per (case, noise, model, method, backend) fit (see the module docstring and `plan`).

    Each row: case, kind, shutter, symmetric, noise, model, method, backend, unit, error (inf for a
    failed fit), extra (further errors: per-layer, centre, pan ...), within, converged (None when
    FitResult does not say), explained, solver, steps, loss, params, failed, message, seconds, truth."""
    from tqdm import tqdm

    cases = family() if cases is None else list(cases)
    fits = plan(cases, backends=backends, models=models, methods=methods, noise=noise, noisy_backends=noisy_backends, every_method_backends=every_method_backends)
    rows = []
    with tqdm(total=len(fits), desc="held-out fits", unit="fit", disable=not progress, file=sys.stderr) as bar:
        for fit in fits:
            bar.set_postfix_str(f"{fit['case'].name} {fit['model']} {fit['method']} {fit['backend']} noise {fit['noise']:g}")
            rows.append(fit_one(fit))
            bar.update(1)
    return rows


def percentile(values: Sequence[float], q: float) -> float:
    """The q-th percentile with linear interpolation between order statistics (numpy's default),
    exact with infinite values (a failed fit's error): inf where the interpolation reaches one."""
    x = sorted(float(v) for v in values)
    if not x:
        return math.nan
    position = q / 100.0 * (len(x) - 1)
    low = int(math.floor(position))
    frac = position - low
    if frac == 0.0 or low + 1 >= len(x):
        return x[low]
    return x[low] + (x[low + 1] - x[low]) * frac


def _target_text(model: str, noise: float) -> str:
    target = TARGETS.get(model, {}).get(noise > 0)
    if target is None:
        return "-"
    unit = UNITS[model]
    text = f"median <= {target[0]:g} {unit}"
    if target[1] is not None:
        text += f", p90 <= {target[1]:g} {unit}"
    return text


def summarize(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Aggregate rows per (model, method, backend, noise): count, failed, median and 90th percentile
    error, the fraction within the median target, the fraction converged ("n/a" when no fit reports
    it), the median seconds, the target and whether it is met (None without a target)."""
    groups: dict[tuple, list[dict[str, Any]]] = {}
    for row in rows:
        groups.setdefault((row["model"], row["method"], row["backend"], float(row["noise"])), []).append(row)

    def order(key: tuple) -> tuple:
        model, method, backend, noise = key
        methods = _methods()
        return (MODEL_ORDER.index(model) if model in MODEL_ORDER else len(MODEL_ORDER), model, noise, methods.index(method) if method in methods else len(methods), method, backend)

    out = []
    for key in sorted(groups, key=order):
        model, method, backend, noise = key
        group = groups[key]
        errors = [float(r["error"]) for r in group]
        median, p90 = percentile(errors, 50), percentile(errors, 90)
        # A failed fit counts as not converged; "n/a" when no fit that ran reports convergence.
        counted = [r for r in group if r.get("failed") or r.get("converged") is not None]
        reported = any(not r.get("failed") for r in counted)
        converged: float | str = sum(r.get("converged") is True for r in counted) / len(counted) if reported else "n/a"
        target = TARGETS.get(model, {}).get(noise > 0)
        within = sum(e <= target[0] for e in errors) / len(errors) if target else None
        met = None if target is None else bool(median <= target[0] and (target[1] is None or p90 <= target[1]))
        out.append(
            {
                "model": model,
                "method": method,
                "backend": backend,
                "noise": noise,
                "unit": UNITS.get(model, group[0].get("unit", "")),
                "count": len(group),
                "failed": sum(bool(r.get("failed")) for r in group),
                "median": median,
                "p90": p90,
                "within": within,
                "converged": converged,
                "seconds": percentile([float(r["seconds"]) for r in group], 50),
                "target": _target_text(model, noise),
                "met": met,
            }
        )
    return out


def _number(x: float | None) -> str:
    if x is None:
        return "-"
    if math.isinf(x) or math.isnan(x):
        return str(x)
    return f"{x:.3f}" if abs(x) < 10 else f"{x:.1f}"


def _fraction(x: float | str | None) -> str:
    if x is None:
        return "-"
    if isinstance(x, str):
        return x
    return f"{100.0 * x:.0f} %"


def markdown_table(summary: Sequence[dict[str, Any]]) -> str:
    """The summary as a Markdown table."""
    lines = [
        "| model | method | backend | noise | fits | failed | unit | median | p90 | within | converged | median s | target | met |",
        "|---|---|---|---:|---:|---:|---|---:|---:|---:|---:|---:|---|---|",
    ]
    for s in summary:
        met = "-" if s["met"] is None else ("yes" if s["met"] else "no")
        lines.append(
            f"| {s['model']} | {s['method']} | {s['backend']} | {s['noise']:g} | {s['count']} | {s['failed']} | {s['unit']} | {_number(s['median'])} | {_number(s['p90'])} | {_fraction(s['within'])} | {_fraction(s['converged'])} | {s['seconds']:.1f} | {s['target']} | {met} |"
        )
    return "\n".join(lines)


def targets_text() -> str:
    return (
        "Targets (DESIGN.md): velocities (global) within 0.1 px median and 0.25 px p90 noise-free, 0.5 px median with sigma 0.01 noise; "
        "per-layer velocities (motion_ids, layers) within 0.25 px (0.5 px with noise); exposure within 1 %; rotation within 2 %; "
        "the camera's advance (zoom cases, % of the first-order advance) has no target. 'within' = fraction of fits within the median target; "
        "'met' = the median (and p90 where given) within target."
    )


def _markers(label: str | None) -> tuple[str, str]:
    middle = "heldout" if label is None else f"heldout:{label}"
    return f"<!-- {middle}:start -->", f"<!-- {middle}:end -->"


def write_section(path: str | os.PathLike, text: str, *, label: str | None = None) -> None:
    """Replace the text between this label's markers in the Markdown file at `path` (markers kept),
    or append the markers and the text at the end if they are missing (creating the file if needed).
    Nothing else in the file changes."""
    start, end = _markers(label)
    path = Path(path)
    content = path.read_text() if path.exists() else ""
    block = f"{start}\n{text.strip()}\n{end}"
    i = content.find(start)
    j = content.find(end, i + len(start)) if i >= 0 else -1
    if i >= 0 and j >= 0:
        content = content[:i] + block + content[j + len(end) :]
    else:
        if content and not content.endswith("\n"):
            content += "\n"
        content += ("\n" if content else "") + block + "\n"
    path.write_text(content)


def _machine() -> dict[str, Any]:
    from diffblur.app.bench import cpu_model

    model = cpu_model()
    try:
        visible = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        visible = os.cpu_count()
    return {"platform": platform.platform(), "cpu": model, "cores": visible, "python": platform.python_version()}


def _commit() -> str | None:
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, timeout=10, check=True)
        # Changes to what this command writes (BENCHMARKS.md, docs/) do not make the code dirty.
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", ".", ":!BENCHMARKS.md", ":!docs"], capture_output=True, text=True, timeout=10, check=True)
        return out.stdout.strip() + (" (with uncommitted changes)" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return None


def section_text(summary: Sequence[dict[str, Any]], meta: dict[str, Any]) -> str:
    """The BENCHMARKS.md section: title, date, machine, command, seed, targets and the table."""
    label = meta.get("label")
    title = "## Held-out recovery" + (f" ({label})" if label else "")
    m = meta["machine"]
    lines = [
        title,
        "",
        f"Generated by `{meta['command']}` (`fitting.evaluate`); every fit in [{meta['json']}]({meta['json']}).",
        "",
        f"- date: {meta['date']}",
        f"- machine: {m['cpu']}, {m['cores']} cores visible; {m['platform']}; python {m['python']}; threads per framework: {meta['threads'] or 'default'}",
        f"- code: commit {meta['commit']}" if meta.get("commit") else "- code: unknown commit",
        f"- family: `fitting.heldout`, seed {meta['seed']}, {meta['cases']} cases at {meta['size']}x{meta['size']} ({meta['kinds']}), frozen in docs/heldout_family.json; noise levels {', '.join(f'{n:g}' for n in meta['noise'])}",
        f"- {meta['fits']} fits in {meta['seconds'] / 60:.1f} min; load average before {meta['load_before']}, after {meta['load_after']}",
        f"- {targets_text()}",
        "",
        markdown_table(summary),
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = argparse.ArgumentParser(prog="python -m fitting.evaluate", description="Held-out evaluation of fitting.recover on the frozen family of fitting.heldout.")
    parser.add_argument("--cases", type=int, default=30, help="how many cases of the family (default 30)")
    parser.add_argument("--size", type=int, default=64, help="image size of the family in pixels (default 64; the frozen hashes are for 64)")
    parser.add_argument("--backends", default="torch,jax", help="comma-separated (default torch,jax)")
    parser.add_argument("--models", default=None, help="comma-separated subset of the models (default: every model a kind calls for)")
    parser.add_argument("--methods", default=None, help="comma-separated subset of fitting._recover.METHODS (default: all)")
    parser.add_argument("--no-noise", action="store_true", help="noise-free fits only")
    parser.add_argument("--noisy-backends", default=None, help="comma-separated backends of the noisy fits (default: the first of --backends)")
    parser.add_argument("--every-method-backends", default=None, help="comma-separated backends of the non-default methods of global and camera (default: the first of --backends)")
    parser.add_argument("--family", choices=("heldout", "development"), default="heldout", help="the frozen held-out family (the report) or the development family (DEVELOPMENT_SEED: tune on it; its numbers go to no report, BENCHMARKS.md is left alone)")
    parser.add_argument("--json", default=None, help="where to write rows and summary (default docs/heldout.json for the held-out family, none for the development family)")
    parser.add_argument("--write-benchmarks", action=argparse.BooleanOptionalAction, default=True, help="replace this run's section of --benchmarks (default on)")
    parser.add_argument("--benchmarks", default="BENCHMARKS.md", help="the Markdown file of --write-benchmarks (default BENCHMARKS.md)")
    parser.add_argument("--label", choices=("before", "after"), default=None, help="label of the table: BENCHMARKS.md keeps one section per label")
    parser.add_argument("--threads", type=int, default=1, help="threads per framework (torch, numba, XLA); 0 leaves their defaults (default 1)")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)

    development = args.family == "development"
    seed = DEVELOPMENT_SEED if development else HELDOUT_SEED
    if args.json is None and not development:
        args.json = "docs/heldout.json"
    if development:
        args.write_benchmarks = False
    backends = tuple(b for b in args.backends.split(",") if b)
    if args.threads:
        _limit_threads(args.threads, backends)
    noise = (0.0,) if args.no_noise else (0.0, NOISE_SIGMA)
    load_before = _load()
    # The code the fits run: the commit when they start (a checkout changed while they run changes
    # files, not the modules already imported).
    commit = _commit()
    start = time.perf_counter()
    cases = family(args.cases, args.size, seed)
    render_seconds = time.perf_counter() - start
    rows = evaluate(cases, backends=backends, models=None if args.models is None else args.models.split(","), methods=None if args.methods is None else args.methods.split(","), noise=noise, noisy_backends=None if args.noisy_backends is None else tuple(args.noisy_backends.split(",")), every_method_backends=None if args.every_method_backends is None else tuple(args.every_method_backends.split(",")), progress=not args.no_progress)
    seconds = time.perf_counter() - start
    summary = summarize(rows)
    kinds = ", ".join(f"{sum(c.kind == k for c in cases)} {k}" for k in ("objects", "pan", "rotation", "zoom"))
    meta = {
        "label": args.label,
        "command": "python -m fitting.evaluate" + (" " + " ".join(argv) if argv else ""),
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": _machine(),
        "commit": commit,
        "seed": seed,
        "family": args.family,
        "cases": len(cases),
        "size": args.size,
        "kinds": kinds,
        "noise": list(noise),
        "backends": list(backends),
        "noisy_backends": list(backends[:1]) if args.noisy_backends is None else args.noisy_backends.split(","),
        "threads": args.threads,
        "fits": len(rows),
        "render_seconds": render_seconds,
        "seconds": seconds,
        "load_before": load_before,
        "load_after": _load(),
        "json": args.json,
    }
    print(targets_text())
    print(markdown_table(summary))
    print(f"{len(rows)} fits on {len(cases)} cases in {seconds / 60:.1f} min (family rendered in {render_seconds:.1f} s)")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        with open(args.json, "w") as f:
            json.dump({"meta": meta, "targets": {m: {("noisy" if k else "noise-free"): v for k, v in t.items()} for m, t in TARGETS.items()}, "summary": summary, "rows": rows}, f, indent=1)
            f.write("\n")
    if args.write_benchmarks:
        write_section(args.benchmarks, section_text(summary, meta), label=args.label)
    return 0


def _load() -> str:
    try:
        return ", ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:  # pragma: no cover
        return "n/a"


def _limit_threads(threads: int, backends: Sequence[str]) -> None:
    """Run each framework with `threads` threads (before the first fit imports it)."""
    # XLA has no thread-count flag; single-threaded is what it offers (set before jax is imported).
    if threads == 1 and "jax" in backends and "jax" not in sys.modules and "multi_thread_eigen" not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1").strip()
    try:
        import numba

        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    except ImportError:  # pragma: no cover
        pass
    if "torch" in backends:
        import torch

        torch.set_num_threads(threads)


if __name__ == "__main__":
    raise SystemExit(main())
