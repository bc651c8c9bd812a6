"""The fitting issue's numbers, measured on the ground-truth scenes of `fitting.scenes`.

`measure(...)` runs every check and returns the rows it prints; `python -m fitting.measure` runs it
with the defaults it prints first. Each row: what, backend, solver, the value found, the truth, the
error, the seconds. Timings are wall-clock on whatever else the machine is doing (print `uptime`
next to them); compare them only within one run.
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

import numpy as np

import fitting
from diffblur.shutters import LinearRamp
from fitting import scenes

DEFAULTS = {"size": 64, "timing_size": 256, "far": 30.0, "noise": 0.01, "select_size": 32, "accuracy": True, "selection": True, "timing": True}

SOLVERS = {"torch": ("adam", "lbfgs"), "jax": ("lm", "dogleg", "bfgs", "lbfgs", "adam")}


def _up_to_sign(found: Any, expected: Any) -> float:
    found, expected = np.asarray(found, dtype=np.float64), np.asarray(expected, dtype=np.float64)
    return float(min(np.abs(found - expected).max(), np.abs(found + expected).max()))


def _row(what: str, result: fitting.FitResult, found: Any, truth: Any, error: float) -> dict[str, Any]:
    row = {
        "what": what,
        "backend": result.backend,
        "solver": result.solver,
        "found": np.round(np.asarray(found, dtype=np.float64), 4).tolist(),
        "truth": truth,
        "error": round(error, 4),
        "steps": len(result.history),
        "seconds": round(result.seconds, 2),
    }
    print(json.dumps(row), flush=True)
    return row


def measure(*, size: int = DEFAULTS["size"], timing_size: int = DEFAULTS["timing_size"], far: float = DEFAULTS["far"], noise: float = DEFAULTS["noise"], select_size: int = DEFAULTS["select_size"], accuracy: bool = DEFAULTS["accuracy"], selection: bool = DEFAULTS["selection"], timing: bool = DEFAULTS["timing"]) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    if accuracy:
        rows += _accuracy(size, far, noise)
    if selection:
        rows += _selection(select_size)
    if timing:
        rows += _timing(timing_size)
    return rows


def _accuracy(size: int, far: float, noise: float) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    velocity = (3.0, -1.5)
    s, _, truth = scenes.translation(size, velocity)
    # Global velocity, noise-free: every backend and solver through the gather, and the quasi-Newton
    # ones through the (slower) reconstruction filter.
    for backend, solvers in SOLVERS.items():
        for solver in solvers:
            r = fitting.recover(s.color, s.target, depth=s.depth, model="global", backend=backend, solver=solver, method="gather", samples=15)
            rows.append(_row("global gather noise-free", r, r.params["velocity"], velocity, _up_to_sign(r.params["velocity"], velocity)))
    for backend, solver in (("torch", "lbfgs"), ("jax", "dogleg")):
        r = fitting.recover(s.color, s.target, depth=s.depth, model="global", method="reconstruct", backend=backend, solver=solver, iterations=12)
        rows.append(_row("global reconstruct noise-free", r, r.params["velocity"], velocity, _up_to_sign(r.params["velocity"], velocity)))
    noisy = s.target + np.random.default_rng(0).normal(scale=noise, size=s.target.shape)
    for backend, solver in (("torch", "lbfgs"), ("jax", "dogleg")):
        r = fitting.recover(s.color, noisy, depth=s.depth, model="global", method="reconstruct", backend=backend, solver=solver, iterations=12)
        rows.append(_row(f"global reconstruct noise {noise}", r, r.params["velocity"], velocity, _up_to_sign(r.params["velocity"], velocity)))
    # Sign: truth with x < 0, box (canonical sign) against LinearRamp(0.8) (true sign).
    flipped = (-3.0, 1.5)
    for label, shutter in (("box", "box"), ("linear_ramp 0.8", LinearRamp(0.8))):
        sc, _, _ = scenes.translation(size, flipped, shutter=shutter)
        r = fitting.recover(sc.color, sc.target, depth=sc.depth, model="global", shutter=shutter, method="gather", samples=15)
        rows.append(_row(f"sign, shutter {label} (reported, vs the true sign)", r, r.params["velocity"], flipped, float(np.abs(np.subtract(r.params["velocity"], flipped)).max())))
    # Exposure and shutter shape.
    for backend, solver in (("torch", "lbfgs"), ("jax", "dogleg")):
        r = fitting.recover(s.color, s.target, depth=s.depth, model=fitting.Exposure(velocity), backend=backend, solver=solver, iterations=10)
        rows.append(_row("exposure (reconstruct)", r, r.params["exposure"], 1.0, abs(r.params["exposure"] - 1.0)))
        r = fitting.recover(s.color, s.target, model=fitting.Exposure(velocity), backend=backend, method="gather", samples=31)
        rows.append(_row("exposure (gather, 31 taps)", r, r.params["exposure"], 1.0, abs(r.params["exposure"] - 1.0)))
    # Rotation (the propeller, arc scatter) and motion IDs (two objects).
    p, _, ptruth = scenes.propeller(size, 0.5)
    for backend, solver in (("torch", "lbfgs"), ("jax", "dogleg")):
        r = fitting.recover(p.color, p.target, depth=p.depth, model=fitting.Rotation(background=p.background), backend=backend, solver=solver, iterations=12, init={"angle": 0.3})
        rows.append(_row("rotation angle (relative error)", r, r.params["angle"], 0.5, abs(r.params["angle"] - 0.5) / 0.5))
    t, ids, ttruth = scenes.two_objects(size)
    for backend, solver in (("torch", "lbfgs"), ("jax", "dogleg")):
        for method in ("gather", "reconstruct"):
            r = fitting.recover(t.color, t.target, depth=t.depth, model=fitting.MotionIds(ids, boundary=3), method=method, backend=backend, solver=solver, iterations=15, init={"palette": [[2.0, 0.5], [-0.5, 1.5]]})
            error = max(_up_to_sign(f, e) for f, e in zip(r.params["palette"], ttruth["palette"]))
            rows.append(_row(f"motion_ids {method}, boundary 3", r, r.params["palette"], ttruth["palette"], error))
    # Coarse-to-fine from `far` px away.
    c, _, _ = scenes.translation(size, (6.0, 2.0), margin=size)
    start = {"velocity": (6.0, 2.0 + far)}
    for levels in (1, 4):
        r = fitting.recover(c.color, c.target, model="global", method="gather", samples=31, init=start, iterations=60, levels=levels)
        rows.append(_row(f"global from {far:g} px away, {levels} level(s)", r, r.params["velocity"], (6.0, 2.0), _up_to_sign(r.params["velocity"], (6.0, 2.0))))
    return rows


def _selection(select_size: int) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    # Model selection.
    for name, candidates in (("pan", ("global", "rotation", "motion_ids", "camera")), ("two_objects", ("global", "rotation", "motion_ids", "camera")), ("propeller", ("global", "rotation", "motion_ids", "camera"))):
        sc, sids, _ = getattr(scenes, name)(select_size)
        start_time = time.perf_counter()
        sel = fitting.select_model(sc.color, sc.target, depth=sc.depth, ids=sids, candidates=candidates, method="gather", samples=9, solver="lbfgs", iterations=15, background=sc.background, arc_samples=8)
        row = {"what": f"select_model on {name}", "choice": sel.choice, "reason": sel.reason, "seconds": round(time.perf_counter() - start_time, 1)}
        print(json.dumps(row), flush=True)
        rows.append(row)
    return rows


def _timing(timing_size: int) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    velocity = (3.0, -1.5)
    # Every solver to its default step count through the gather (15 taps); the reconstruction
    # filter (9 taps) with 10 quasi-Newton steps.
    big, _, _ = scenes.translation(timing_size, velocity)
    for backend, solvers in SOLVERS.items():
        for solver in solvers:
            r = fitting.recover(big.color, big.target, depth=big.depth, model="global", backend=backend, solver=solver, method="gather", samples=15)
            rows.append(_row(f"timing {timing_size}x{timing_size} global gather", r, r.params["velocity"], velocity, _up_to_sign(r.params["velocity"], velocity)))
    for backend, solver in (("torch", "lbfgs"), ("jax", "dogleg")):
        r = fitting.recover(big.color, big.target, depth=big.depth, model="global", method="reconstruct", backend=backend, solver=solver, iterations=10)
        rows.append(_row(f"timing {timing_size}x{timing_size} global reconstruct", r, r.params["velocity"], velocity, _up_to_sign(r.params["velocity"], velocity)))
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Measure the fitting issue's numbers on ground-truth scenes. Defaults: " + ", ".join(f"{k}={v}" for k, v in DEFAULTS.items()))
    parser.add_argument("--size", type=int, default=DEFAULTS["size"])
    parser.add_argument("--timing-size", type=int, default=DEFAULTS["timing_size"])
    parser.add_argument("--far", type=float, default=DEFAULTS["far"])
    parser.add_argument("--noise", type=float, default=DEFAULTS["noise"])
    parser.add_argument("--select-size", type=int, default=DEFAULTS["select_size"])
    parser.add_argument("--no-timing", action="store_true", help="skip the timing part")
    parser.add_argument("--no-accuracy", action="store_true", help="skip the accuracy part")
    parser.add_argument("--no-selection", action="store_true", help="skip the model selection part")
    parser.add_argument("--json", help="also write the rows to this file")
    args = parser.parse_args(argv)
    options = dict(size=args.size, timing_size=args.timing_size, far=args.far, noise=args.noise, select_size=args.select_size, accuracy=not args.no_accuracy, selection=not args.no_selection, timing=not args.no_timing)
    print("fitting.measure", json.dumps(options), flush=True)
    rows = measure(**options)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
