"""Soak: each image op called many times in a loop (default 1,000) at 256x256, with random valid
inputs and options, both frameworks; the resident memory must stay flat after the first calls, and
no call may fail.

Per op and framework: the options are drawn per call from a small set (so JAX's compiled functions,
cached per option set as a training loop would, stop growing after the first calls), the inputs
fresh each call (colour in [0, 1), velocity up to 20 px with still regions, depth in [1, 3]), and
the call is a forward and the gradient of the output's sum w.r.t. colour and velocity. RSS is read
from /proc/self/status after each call; "growth" is the RSS after the last call less the RSS after
call `--settle` (default 100), which lets the allocators and caches reach their working size.

To find where a growth comes from, each row also has: the JAX compilations (XLA backend compiles,
counted with `jax.monitoring`) in all and after call `--settle`, which would show a compile cache
still growing; and the RSS after the loop once glibc has handed its free heap back
(`malloc_trim(0)`), which would show memory that was freed but kept by the allocator rather than
held by live objects. `--fixed` draws one option set only (the first), for comparison.

    PYTHONPATH=. python scripts/measure_soak.py [--calls 1000] [--size 256] [--frameworks torch,jax]
        [--ops gather_blur,...] [--fixed] [--write]

`--write` puts the rows into the section "Soak" of BENCHMARKS.md (`diffblur.app.bench.replace_section`):
a row of this run replaces the row of the same framework, op and option draw, the others stay, each
with the date of the run it came from.
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import os
import platform
import re
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


#: XLA backend compilations so far in this process (JAX only), counted by `_count_compiles`.
COMPILES = [0]


def _count_compiles() -> None:
    import jax.monitoring

    def listener(event: str, duration: float, **_) -> None:
        if event == "/jax/core/compile/backend_compile_duration":
            COMPILES[0] += 1

    jax.monitoring.register_event_duration_secs_listener(listener)


def trimmed_rss_mb() -> float:
    """RSS after glibc hands its free heap pages back to the system (nan where there is no glibc)."""
    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        return float("nan")
    return rss_mb()


def jax_step(op):
    import jax
    import jax.numpy as jnp

    import jax_impl

    if not getattr(jax_step, "counting", False):
        _count_compiles()
        jax_step.counting = True
    compiled = {}

    def step(host, options):
        key = tuple(sorted(options.items()))
        if key not in compiled:
            loss = lambda c, v, z: jnp.sum(call(jax_impl, op, c, v, z, options))  # noqa: E731
            compiled[key] = jax.jit(jax.grad(loss, argnums=(0, 1)))
        grads = compiled[key](*(jnp.asarray(a) for a in host))
        return float(jnp.sum(jnp.abs(grads[0])))

    return step


def soak(framework: str, op: str, calls: int, size: int, settle: int, fixed: bool = False) -> dict:
    step = (torch_step if framework == "torch" else jax_step)(op)
    rng = np.random.default_rng(0)
    sets = OPTIONS[op][:1] if fixed else OPTIONS[op]
    before = COMPILES[0]
    rss, compiles, errors, started = [], [], 0, time.perf_counter()
    for _ in range(calls):
        options = sets[rng.integers(len(sets))]
        try:
            value = step(draw(rng, size), options)
            errors += not np.isfinite(value)
        except Exception:  # noqa: BLE001 - counted and reported
            errors += 1
        rss.append(rss_mb())
        compiles.append(COMPILES[0])
    seconds = time.perf_counter() - started
    settled = min(settle, calls) - 1
    return {
        "rss_first": rss[0],
        "rss_settle": rss[settled],
        "rss_last": rss[-1],
        "rss_max": max(rss[settled:]),
        "rss_trimmed": trimmed_rss_mb(),
        "compiles": compiles[-1] - before if framework == "jax" else None,
        "compiles_after_settle": compiles[-1] - compiles[settled] if framework == "jax" else None,
        "errors": errors,
        "ms_per_call": 1e3 * seconds / calls,
    }


HEADER = (
    "| framework | op | option sets | calls | errors | RSS call 1 | RSS settled | RSS last | growth MB | peak above settled MB "
    "| RSS after malloc_trim | JAX compiles (after settled) | ms per call | run (UTC) |"
)


def row(framework: str, op: str, sets: int, calls: int, r: dict, run: str) -> str:
    compiles = "" if r["compiles"] is None else f"{r['compiles']} ({r['compiles_after_settle']})"
    cells = [
        framework, op, str(sets), str(calls), str(r["errors"]), f"{r['rss_first']:.0f}", f"{r['rss_settle']:.0f}", f"{r['rss_last']:.0f}",
        f"{r['rss_last'] - r['rss_settle']:+.1f}", f"{r['rss_max'] - r['rss_settle']:+.1f}", f"{r['rss_trimmed']:.0f}", compiles,
        f"{r['ms_per_call']:.0f}", run,
    ]
    return "| " + " | ".join(cells) + " |"


def kept_rows(path: Path, replaced: set[tuple[str, str, str]]) -> tuple[list[str], str]:
    """The rows of the section "Soak" in `path` in this script's columns, except those whose
    (framework, op, option sets) this run measured again; and the notes that go with them: the
    findings of the earlier runs whose rows remain, and, where rows of the earlier layout (no calls,
    trim, compiles or run columns) are carried over (with those cells empty), that section's first
    paragraph, which describes their run."""
    if not path.exists() or "## Soak" not in path.read_text():
        return [], ""
    section = path.read_text().split("## Soak", 1)[1].split("\n## ", 1)[0]
    paragraphs = [p.strip() for p in section.strip().split("\n\n")]
    earlier = paragraphs[0].replace("\n", " ") if paragraphs and not paragraphs[0].startswith("|") else ""
    rows, old_layout = [], False
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if not line.startswith("| ") or cells[0] not in ("torch", "jax"):
            continue
        if (cells[0], cells[1], cells[2]) in replaced:
            continue
        if len(cells) == 10:  # framework, op, sets, errors, 3 RSS, growth, peak, ms
            cells = [*cells[:3], "1000", *cells[3:9], "", "", cells[9], "earlier run (below)"]
        old_layout |= cells[-1] == "earlier run (below)"
        rows.append("| " + " | ".join(cells) + " |")
    if old_layout and earlier.startswith("Generated by"):  # already carried once: keep its note only
        earlier = next((p for p in paragraphs if p.startswith("Rows dated")), "")
    elif old_layout:
        earlier = "Rows dated 'earlier run (below)': " + earlier
    # The findings of earlier runs whose rows are still in the table.
    runs = {row.strip("| ").split(" | ")[-1] for row in rows}
    found = [p for p in paragraphs if (m := re.match(r"In the run of (\d{4}-\d\d-\d\d \d\d:\d\d)", p)) and m.group(1) in runs]
    return rows, "\n\n".join(found + ([earlier] if old_layout else []))


def findings(results: dict, settle: int, run: str) -> str:
    """What this run's rows say about growth after settling, in words computed from them."""
    grew = {key: r for key, r in results.items() if r["rss_last"] - r["rss_settle"] > 2.0}
    if not grew:
        return f"In the run of {run}, no row grew by more than 2 MB after call {settle}."
    parts = []
    for (framework, op), r in grew.items():
        compiles = "" if r["compiles_after_settle"] is None else f", {r['compiles_after_settle']} XLA compilations after call {settle}"
        parts.append(
            f"{framework} {op} grew {r['rss_last'] - r['rss_settle']:+.1f} MB{compiles}, and after `malloc_trim(0)` its RSS was "
            f"{r['rss_trimmed']:.0f} MB ({r['rss_trimmed'] - r['rss_settle']:+.1f} against settled)"
        )
    text = f"In the run of {run}: " + "; ".join(parts) + "."
    jax_grew = [r for (framework, _), r in grew.items() if framework == "jax"]
    if jax_grew and all(r["compiles_after_settle"] == 0 for r in jax_grew):
        text += " No JAX row that grew compiled anything after the settling call: its growth is not a compile cache filling up."
    returned = [r["rss_trimmed"] - r["rss_settle"] <= 2.0 for r in grew.values()]
    if all(returned):
        text += " glibc handed the growth back when asked: free heap it kept, not live objects."
    elif any(returned):
        text += " Where the RSS after `malloc_trim` is back within 2 MB of settled, the growth was free heap glibc kept, not live objects."
    return text


def write_section(text: str) -> None:
    from diffblur.app.bench import replace_section

    replace_section(str(ROOT / "BENCHMARKS.md"), "## Soak", text)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=1000)
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--settle", type=int, default=100)
    parser.add_argument("--frameworks", default="torch,jax")
    parser.add_argument("--ops", default=",".join(OPTIONS))
    parser.add_argument("--fixed", action="store_true", help="one option set per op (the first), for comparison")
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args()
    load = os.getloadavg()[0]
    run = f"{datetime.now(timezone.utc):%Y-%m-%d %H:%M}"
    rows, replaced, results = [], set(), {}
    for framework in args.frameworks.split(","):
        for op in args.ops.split(","):
            sets = "1 (fixed)" if args.fixed else str(len(OPTIONS[op]))
            r = results[framework, op] = soak(framework, op, args.calls, args.size, args.settle, fixed=args.fixed)
            rows.append(row(framework, op, sets, args.calls, r, run))
            replaced.add((framework, op, sets))
            print(rows[-1], flush=True)
    import torch

    kept, earlier = kept_rows(ROOT / "BENCHMARKS.md", replaced) if args.write else ([], "")
    order = {(f, o): i for i, (f, o) in enumerate((f, o) for f in ("torch", "jax") for o in OPTIONS)}
    table = sorted(rows + kept, key=lambda line: order.get(tuple(c.strip() for c in line.strip("| ").split("|")[:2]), len(order)))
    text = "\n".join([
        "## Soak",
        "",
        f"Generated by `PYTHONPATH=. python scripts/measure_soak.py --write`; the last run {run} UTC "
        f"({platform.machine()}, {os.cpu_count()} cores, load average before {load:.1f}, torch {torch.__version__}, "
        f"calls {args.calls}, {args.size}x{args.size}, settled = call {args.settle}), its rows dated in the last column; "
        "rows of earlier runs are kept as they were. "
        "Each op called many times at 256x256 unless said, float32, fresh random inputs and an option set drawn per call "
        "(forward + gradient w.r.t. colour and velocity; PyTorch eager, JAX `jax.jit` cached per option set), "
        "one process, the frameworks and ops in turn. RSS in MB after call 1, after the settling call and after "
        "the last; growth = last - settled, peak = the largest RSS after settling - settled; the RSS after the loop once "
        "glibc returned its free heap (`malloc_trim(0)`); XLA compilations in the op's loop (after the settling call in "
        "brackets). Errors: calls that raised or gave a non-finite gradient.",
        "",
        HEADER,
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|",
        *table,
        *(["", findings(results, args.settle, run)] if results else []),
        *(["", earlier] if earlier else []),
    ]) + "\n"
    print(text)
    if args.write:
        write_section(text)


if __name__ == "__main__":
    main()
