"""Compiled against eager, every op and module, both frameworks: the largest difference of the output
and of every gradient, and the compile time.

PyTorch: `torch.compile` (the default backend, inductor, `dynamic=False`) of forward and backward
(the gradient of a fixed weighted sum of the output w.r.t. every floating input), against eager.
JAX: `jax.jit`, `jax.vmap` (over a leading batch axis of 2) and `jax.checkpoint` of the same
gradient, against eager JAX.

Each PyTorch case runs in its own subprocess with a time limit and a fresh, empty Inductor cache
(TORCHINDUCTOR_CACHE_DIR in a new temporary directory: the compile time is a cold build, as in CI):
inductor compiles C++ (minutes per op on 2 cores for the tensor ops), and a crash of its generated
code ends the process; the table then says so instead of losing the sweep. The ops with a fused CPU
kernel run twice: on their default, where the kernel is one custom operator in the graph, and with
`impl="tensor"`, the tensor ops that the compiler traces on other devices (and traced on the CPU too
before the kernels were operators). Inputs: float64, (1, 3, 8, 9) (tiny, to bound the compile), seeded.

    PYTHONPATH=. python scripts/measure_compile_vs_eager.py [--only NAME,...] [--limit 900] [--write]

`--write` puts the rows into the section "Compiled against eager" of BENCHMARKS.md
(`diffblur.app.bench.replace_section`): a case measured in this run replaces its row, the others stay,
each with the date of the run it came from.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from op_cases import CASES, SHAPE, call, inputs, labels, weights

ROOT = Path(__file__).resolve().parents[1]
# --------------------------------------------------------------------------------------- PyTorch


def torch_case(case: str) -> dict:
    """One case, in this process: eager and compiled output and gradients, their differences."""
    import torch

    import torch_impl

    torch.set_num_threads(1)
    name, kinds, options = CASES[case]
    host = inputs(kinds)

    def run(fn):
        leaves = [torch.tensor(a, requires_grad=True) for a in host]
        out = fn(*leaves)
        loss = (out * torch.tensor(weights(tuple(out.shape)))).sum()
        grads = torch.autograd.grad(loss, leaves, allow_unused=True)
        return [out.detach().numpy()] + [np.zeros(a.shape) if g is None else g.numpy() for g, a in zip(grads, host)]

    fn = lambda *arrays: call(torch_impl, name, kinds, options, list(arrays))  # noqa: E731
    eager = run(fn)
    torch._dynamo.reset()
    from torch._dynamo.utils import counters

    counters.clear()
    compiled = torch.compile(fn, dynamic=False)
    started = time.perf_counter()
    got = run(compiled)
    seconds = time.perf_counter() - started
    return {
        "output": float(np.max(np.abs(got[0] - eager[0]))),
        "gradients": {k: float(np.max(np.abs(g - e))) for k, g, e in zip(labels(kinds), got[1:], eager[1:])},
        "compile_s": round(seconds, 1),
        "graph_breaks": sum(counters["graph_break"].values()),
    }


def torch_sweep(cases: list[str], limit: int) -> dict:
    results = {}
    for case in cases:
        started = time.perf_counter()
        cache = tempfile.mkdtemp(prefix="inductor-cold-")
        try:
            run = subprocess.run(
                [sys.executable, __file__, "--torch-case", case],
                cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT), "TORCHINDUCTOR_CACHE_DIR": cache}, capture_output=True, text=True, timeout=limit,
            )
            if run.returncode == 0:
                results[case] = json.loads(run.stdout.strip().splitlines()[-1])
            else:
                tail = [line for line in run.stderr.strip().splitlines() if line.strip()][-1:] or ["(no message)"]
                results[case] = {"error": f"exit {run.returncode}: {tail[0][:160]}"}
        except subprocess.TimeoutExpired:
            results[case] = {"error": f"compile not done in {limit} s"}
        finally:
            shutil.rmtree(cache, ignore_errors=True)
        print(f"torch {case}: {results[case]} ({time.perf_counter() - started:.0f} s)", file=sys.stderr, flush=True)
    return results


# ------------------------------------------------------------------------------------------- JAX


def jax_sweep(cases: list[str]) -> dict:
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    import jax_impl

    results = {}
    for case in cases:
        name, kinds, options = CASES[case]
        host = [jnp.asarray(a) for a in inputs(kinds)]
        out_shape = jax.eval_shape(lambda *a: call(jax_impl, name, kinds, options, list(a)), *host).shape
        w = jnp.asarray(weights(out_shape))

        def value_and_grads(*arrays):
            def loss(*a):
                out = call(jax_impl, name, kinds, options, list(a))
                return jnp.sum(out * w), out

            (_, out), grads = jax.value_and_grad(loss, argnums=tuple(range(len(arrays))), has_aux=True)(*arrays)
            return [out, *grads]

        def diff(a, b):
            return max(float(jnp.max(jnp.abs(x - y))) for x, y in zip(a, b))

        try:
            eager = value_and_grads(*host)
            started = time.perf_counter()
            jitted = jax.jit(value_and_grads)
            jax.block_until_ready(jitted(*host))
            compile_s = time.perf_counter() - started
            jit_diff = diff(jitted(*host), eager)
            batched = jax.vmap(value_and_grads)(*(jnp.stack([a, a]) for a in host))
            vmap_diff = max(diff([x[i] for x in batched], eager) for i in range(2))
            checkpointed = jax.checkpoint(value_and_grads)(*host)
            results[case] = {
                "jit": jit_diff,
                "vmap": vmap_diff,
                "checkpoint": diff(checkpointed, eager),
                "compile_s": round(compile_s, 1),
            }
        except Exception as error:  # noqa: BLE001 - reported in the table
            results[case] = {"error": f"{type(error).__name__}: {str(error).splitlines()[0][:160]}"}
        print(f"jax {case}: {results[case]}", file=sys.stderr, flush=True)
    return results


# ----------------------------------------------------------------------------------------- table


HEADER = (
    "| op | torch.compile: output | torch.compile: gradients (largest, by input) | torch.compile s | graph breaks "
    "| jax.jit | jax.vmap | jax.checkpoint | jax.jit compile s | run (UTC) |"
)


def cells(torch_results: dict, jax_results: dict, run: str) -> dict[str, dict]:
    """Per case measured in this run: its PyTorch cells and JAX cells (None for a framework not run)
    and the run's date."""
    out = {}
    for case in CASES:
        t, j = torch_results.get(case), jax_results.get(case)
        if t is None and j is None:
            continue
        torch_cells = jax_cells = None
        if t is not None and "error" in t:
            torch_cells = [t["error"], "", "", ""]
        elif t is not None:
            grads = ", ".join(f"{k} {v:.1e}" for k, v in t["gradients"].items())
            torch_cells = [f"{t['output']:.1e}", grads, f"{t['compile_s']}", str(t["graph_breaks"])]
        if j is not None and "error" in j:
            jax_cells = [j["error"], "", "", ""]
        elif j is not None:
            jax_cells = [f"{j['jit']:.1e}", f"{j['vmap']:.1e}", f"{j['checkpoint']:.1e}", f"{j['compile_s']}"]
        out[case] = {"torch": torch_cells, "jax": jax_cells, "torch_run": run, "jax_run": run}
    return out


def earlier_cells(path: Path) -> tuple[dict[str, dict], str]:
    """The cases' cells in the section "Compiled against eager" of `path`, in this script's columns;
    and, where rows of the earlier layout (no graph breaks or run columns) are there (those cells
    empty), the paragraph that describes their run."""
    heading = "## Compiled against eager"
    if not path.exists() or heading not in path.read_text():
        return {}, ""
    section = path.read_text().split(heading, 1)[1].split("\n## ", 1)[0]
    paragraphs = [p.strip() for p in section.strip().split("\n\n")]
    first = paragraphs[0].replace("\n", " ") if paragraphs and not paragraphs[0].startswith("|") else ""
    out = {}
    for line in section.splitlines():
        row = [c.strip() for c in line.strip().strip("|").split("|")]
        if not line.startswith("| ") or row[0] not in CASES:
            continue
        if len(row) == 8:  # op, 3 PyTorch cells, 4 JAX cells
            row = [*row[:4], "", *row[4:], EARLIER]
        if row[-1].startswith(("torch ", "jax ")):
            runs = {"torch": "", "jax": "", **dict(part.split(" ", 1) for part in row[-1].split("; "))}
        else:
            runs = {"torch": row[-1], "jax": row[-1]}
        out[row[0]] = {"torch": row[1:5], "jax": row[5:9], "torch_run": runs["torch"], "jax_run": runs["jax"]}
    note = ""
    if any(EARLIER in (c["torch_run"], c["jax_run"]) for c in out.values()):
        note = next((p for p in paragraphs if p.startswith("Rows dated")), "") if first.startswith("Generated by") else f"Rows dated '{EARLIER}': " + first
    return out, note


EARLIER = "earlier run (below)"


def merged_rows(new: dict[str, dict], old: dict[str, dict]) -> tuple[list[str], bool]:
    """One row per case: this run's cells where it measured them, the earlier ones elsewhere.
    Also whether a cell of the earlier layout's run remains."""
    lines, earlier = [], False
    for case in CASES:
        n, o = new.get(case, {}), old.get(case, {})
        row = {}
        for framework in ("torch", "jax"):
            if n.get(framework) is not None:
                row[framework], row[framework + "_run"] = n[framework], n[framework + "_run"]
            elif o.get(framework) is not None and o[framework + "_run"]:
                row[framework], row[framework + "_run"] = o[framework], o[framework + "_run"]
            else:
                row[framework], row[framework + "_run"] = ["not run", "", "", ""], ""
        if not n and not o:
            continue
        earlier |= EARLIER in (row["torch_run"], row["jax_run"])
        if row["torch_run"] == row["jax_run"] or not row["jax_run"]:
            run = row["torch_run"]
        else:
            run = f"torch {row['torch_run']}; jax {row['jax_run']}" if row["torch_run"] else f"jax {row['jax_run']}"
        lines.append("| " + " | ".join([case, *row["torch"], *row["jax"], run]) + " |")
    return lines, earlier


def write_section(text: str) -> None:
    from diffblur.app.bench import replace_section

    replace_section(str(ROOT / "BENCHMARKS.md"), "## Compiled against eager", text)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", default="", help="comma-separated case names (default: all)")
    parser.add_argument("--limit", type=int, default=900, help="seconds one PyTorch case may take")
    parser.add_argument("--frameworks", default="torch,jax")
    parser.add_argument("--write", action="store_true", help="write the table into BENCHMARKS.md")
    parser.add_argument("--torch-case", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.torch_case:
        print(json.dumps(torch_case(args.torch_case)))
        return
    cases = [c for c in CASES if not args.only or c in args.only.split(",")]
    frameworks = args.frameworks.split(",")
    load = os.getloadavg()[0]
    run = f"{datetime.now(timezone.utc):%Y-%m-%d %H:%M}"
    jax_results = jax_sweep(cases) if "jax" in frameworks else {}
    torch_results = torch_sweep(cases, args.limit) if "torch" in frameworks else {}
    import torch

    old, note = earlier_cells(ROOT / "BENCHMARKS.md") if args.write else ({}, "")
    table, earlier = merged_rows(cells(torch_results, jax_results, run), old)
    note = note if earlier else ""
    header = (
        f"Generated by `PYTHONPATH=. python scripts/measure_compile_vs_eager.py --write`; the last run {run} UTC "
        f"({platform.processor() or platform.machine()}, {os.cpu_count()} cores, load average before {load:.1f}, "
        f"torch {torch.__version__}), its rows dated in the last column; rows of earlier runs are kept as they were. "
        f"Inputs float64 {SHAPE}, seeded; largest absolute difference from eager of the output and of the gradient of a "
        "fixed weighted sum of it w.r.t. each floating input (c colour, v velocity, z depth, d distance, p/n offsets). "
        "PyTorch: `torch.compile(dynamic=False)`, default backend (inductor), each case in its own process with an empty "
        "Inductor cache, compile time = the first forward+backward, graph breaks as Dynamo counts them. The ops with a "
        "fused CPU kernel on their default (one custom operator in the graph, forward and backward) and with "
        "`impl='tensor'` (the tensor ops, traced tap by tap: what their default compiled to before the kernels were "
        "operators). JAX: the same gradient eager against `jax.jit`, `jax.vmap` (batch of 2) and `jax.checkpoint`."
    )
    lines = ["## Compiled against eager", "", header, "", HEADER, "|---|---:|---|---:|---:|---:|---:|---:|---:|---|"]
    lines += table
    text = "\n".join(lines + (["", note] if note else [])) + "\n"
    print(text)
    if args.write:
        write_section(text)


if __name__ == "__main__":
    main()
