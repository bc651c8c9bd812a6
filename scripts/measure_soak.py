"""Soak: each image op called many times in a loop (default 1,000) at 256x256, with random valid
inputs and options, both frameworks; the resident memory must stay flat after the first calls, and
no call may fail.

Per op and framework: the options are drawn per call from a small set (so JAX's compiled functions,
cached per option set as a training loop would, stop growing after the first calls), the inputs
fresh each call (colour in [0, 1), velocity up to 20 px with still regions, depth in [1, 3]), and
the call is a forward and the gradient of the output's sum w.r.t. colour and velocity. RSS is read
from /proc/self/status after each call; "growth" is the RSS after the last call less the RSS after
call `--settle` (default 100), which lets the allocators and caches reach their working size.

    PYTHONPATH=. python scripts/measure_soak.py [--calls 1000] [--size 256] [--write]

`--write` replaces the section "Soak" of BENCHMARKS.md with the table.
"""

from __future__ import annotations

import argparse
import gc
import os
import platform
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

#: op -> the option sets drawn from (each a dict of keyword options).
OPTIONS = {
    "gather_blur": [{"samples": s, "shutter": sh, "adaptive": a} for s in (5, 15) for sh in ("box", "tent") for a in (False, True)],
    "reconstruct": [{"samples": s, "adaptive": a, "max_radius": r} for s in (5, 15) for a in (False, True) for r in (10.0, 20.0)],
    "bezier_scatter": [{"degree": d, "samples": s, "fill": "color"} for d in (1, 2, 3) for s in (9, 16)],
    "warp_blend": [{"iterations": i} for i in (1, 2, 3)],
    "accumulate_warps": [{"instants": n} for n in (4, 8, 16)],
}


def rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def draw(rng: np.random.Generator, size: int):
    color = rng.random((1, 3, size, size), dtype=np.float32)
    speed = rng.uniform(0.0, 20.0) * rng.random((1, 1, size, size), dtype=np.float32)
    speed[:, :, : size // 3] = 0.0  # a still band
    angle = rng.uniform(0.0, 2 * np.pi)
    velocity = np.concatenate([speed * np.cos(angle), speed * np.sin(angle)], axis=1).astype(np.float32)
    depth = rng.uniform(1.0, 3.0, size=(1, 1, size, size)).astype(np.float32)
    return color, velocity, depth


def call(ops, op, c, v, z, options):
    if op == "reconstruct":
        return ops.reconstruct(c, v, z, **options)
    if op == "bezier_scatter":  # a cubic also takes the point at t = -1/2 (here on the straight path)
        extra = {"offset_mid_prev": -0.5 * v} if options.get("degree") == 3 else {}
        return ops.bezier_scatter(c, z, -v, v, **options, **extra)
    return getattr(ops, op)(c, v, **options)


def torch_step(op):
    import torch

    import torch_impl

    def step(host, options):
        c, v, z = (torch.from_numpy(a) for a in host)
        c.requires_grad_()
        v.requires_grad_()
        call(torch_impl, op, c, v, z, options).sum().backward()
        return float(c.grad.abs().sum())

    return step


def jax_step(op):
    import jax
    import jax.numpy as jnp

    import jax_impl

    compiled = {}

    def step(host, options):
        key = tuple(sorted(options.items()))
        if key not in compiled:
            loss = lambda c, v, z: jnp.sum(call(jax_impl, op, c, v, z, options))  # noqa: E731
            compiled[key] = jax.jit(jax.grad(loss, argnums=(0, 1)))
        grads = compiled[key](*(jnp.asarray(a) for a in host))
        return float(jnp.sum(jnp.abs(grads[0])))

    return step


def soak(framework: str, op: str, calls: int, size: int, settle: int) -> dict:
    step = (torch_step if framework == "torch" else jax_step)(op)
    rng = np.random.default_rng(0)
    sets = OPTIONS[op]
    rss, errors, started = [], 0, time.perf_counter()
    for _ in range(calls):
        options = sets[rng.integers(len(sets))]
        try:
            value = step(draw(rng, size), options)
            errors += not np.isfinite(value)
        except Exception:  # noqa: BLE001 - counted and reported
            errors += 1
        rss.append(rss_mb())
    gc.collect()
    return {
        "rss_first": rss[0],
        "rss_settle": rss[min(settle, calls) - 1],
        "rss_last": rss[-1],
        "rss_max": max(rss[min(settle, calls) - 1:]),
        "errors": errors,
        "ms_per_call": 1e3 * (time.perf_counter() - started) / calls,
    }


def write_section(text: str) -> None:
    from diffblur.bench import replace_section

    replace_section(str(ROOT / "BENCHMARKS.md"), "## Soak", text)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=1000)
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--settle", type=int, default=100)
    parser.add_argument("--frameworks", default="torch,jax")
    parser.add_argument("--ops", default=",".join(OPTIONS))
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args()
    load = os.getloadavg()[0]
    rows = []
    for framework in args.frameworks.split(","):
        for op in args.ops.split(","):
            r = soak(framework, op, args.calls, args.size, args.settle)
            row = (
                f"| {framework} | {op} | {len(OPTIONS[op])} | {r['errors']} | {r['rss_first']:.0f} | {r['rss_settle']:.0f} | "
                f"{r['rss_last']:.0f} | {r['rss_last'] - r['rss_settle']:+.1f} | {r['rss_max'] - r['rss_settle']:+.1f} | {r['ms_per_call']:.0f} |"
            )
            print(row, flush=True)
            rows.append(row)
    import torch

    text = "\n".join([
        "## Soak",
        "",
        f"Generated by `PYTHONPATH=. python scripts/measure_soak.py --write`; {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC, "
        f"{platform.machine()}, {os.cpu_count()} cores, load average before {load:.1f}, torch {torch.__version__}. "
        f"Each op {args.calls} times at {args.size}x{args.size}, float32, fresh random inputs and an option set drawn per call "
        "(forward + gradient w.r.t. colour and velocity; PyTorch eager, JAX `jax.jit` cached per option set), "
        f"one process, the frameworks and ops in turn. RSS in MB after call 1, after call {args.settle} (settled) and after "
        "the last; growth = last - settled, peak = the largest RSS after settling - settled. Errors: calls that raised or "
        "gave a non-finite gradient.",
        "",
        "| framework | op | option sets | errors | RSS call 1 | RSS settled | RSS last | growth MB | peak above settled MB | ms per call |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
        *rows,
    ]) + "\n"
    print(text)
    if args.write:
        write_section(text)


if __name__ == "__main__":
    main()
