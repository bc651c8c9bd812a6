"""On a GPU: every op's output and gradients on the device against the CPU's, no host
synchronisation inside `diffblur.without_host_reads`, and the speed of reconstruct (the design's
aim: under 1 ms at 1920x1080) and gather_blur, in PyTorch and JAX.

Made for a lent GPU machine's short lease: one command; the checks first, then the
timings, the most wanted first; no timing starts after --budget seconds (the rows left say so),
and DIR holds what is done after each step. The CPU side of the checks runs the tensor ops
(`impl="tensor"`), which the suite checks against the fused CPU kernels to float64 rounding, so
nothing here compiles those kernels (numba: minutes on a cold cache).

    PYTHONPATH=. python scripts/measure_gpu.py --out DIR [--device cuda] [--budget 300] [--write]

DIR gets gpu.json and gpu.md, the section "GPU" of BENCHMARKS.md (`--write` puts it there; where
the run's files come back from another machine, `--render DIR/gpu.json --write`). Exit status 1
when a check fails. `--device cpu` runs the same on the CPU: the test suite does so at a
tiny size (tests/test_measure_gpu.py).

Checks, float64, the inputs of `op_cases.py` at CHECK_SHAPE, each case of `op_cases.CASES` and a
few more options (`CHECKS`): the output and the gradient of a fixed weighted sum of it w.r.t. every
floating input, on the device against the CPU, in each framework (the largest difference over the
largest reference value), and the two frameworks against each other on the device. Then inside
`without_host_reads`: on a GPU, PyTorch's forward and backward under
`torch.cuda.set_sync_debug_mode("error")` (a synchronising call raises; on the CPU
tests/torch/test_meta_device.py refuses host reads instead), and JAX's jitted forward and backward
free of host callbacks (none in its compiled program).

Timings, float32, the bench's uniform scene (a photograph under a pan of 15 px): the bench's
settings `reconstruct S=15, bilinear` (the default jitter), `... no jitter` and `gather_blur S=15,
bilinear` at 1920x1080, then 1280x720 (order: `timing_jobs`); forward and forward+backward (the
gradient of the output's sum w.r.t. the floating inputs) in turns, the median of --repeats after a
warm-up, each call waiting for the device. PyTorch eager and JAX `jax.jit`, each inside
`without_host_reads` (what a GPU user runs: no data checks, no waiting) and, for the default
reconstruct, with the data checks; `torch.compile(fullgraph=True)` of reconstruct's forward, its
compile time too; kornia's `motion_blur` (kernel 31) where kornia is installed. With each, the
memory of a forward+backward (the design asks O(pixels)): PyTorch's peak GPU allocation, JAX's
compiled temporaries.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import re
import sys
import time
from contextlib import nullcontext
from pathlib import Path

import numpy as np
from op_cases import CASES, call, inputs, weights

from diffblur.app.bench import _fmt

ROOT = Path(__file__).resolve().parents[1]
CHECK_SHAPE = (2, 3, 24, 32)
#: Largest difference allowed between devices, relative to the reference's largest value (float64:
#: the same formulas in another order of summation differ by about 1e-15 of it).
TOLERANCE = 1e-9
#: The ops and the module that take `impl`: their CPU reference runs the tensor ops.
TAKE_IMPL = ("gather_blur", "reconstruct", "bezier_scatter", "MotionBlur")
CHECKS = {
    **{case: spec for case, spec in CASES.items() if "impl=" not in case},
    "gather_blur pyramid": ("gather_blur", "cv", {"samples": 5, "sampling": "pyramid"}),
    "reconstruct jitter='none'": ("reconstruct", "cvz", {"samples": 5, "max_radius": 4.0, "jitter": "none"}),
    "reconstruct adaptive": ("reconstruct", "cvz", {"samples": 5, "max_radius": 4.0, "adaptive": True}),
}
#: Host callbacks in a compiled JAX program (each one waits for the device): `pure_callback`,
#: `io_callback` and `jax.debug.callback` lower to these targets.
HOST_CALLBACK = re.compile(r"xla_(ffi_)?python_(cpu|gpu|cuda)_callback")
SIZES = ((1080, 1920), (720, 1280))  # (H, W)
TARGET_SIZE = (1080, 1920)
TIMED = (("reconstruct", "S=15, bilinear, no jitter"), ("reconstruct", "S=15, bilinear"), ("gather_blur", "S=15, bilinear"))
KORNIA = ("kornia.motion_blur", "kernel 31, bilinear")
NOT_ON_CPU = "not checked (cpu)"


def reference_options(name: str, options: dict) -> dict:
    return {**options, "impl": "tensor"} if name in TAKE_IMPL else options


def relative_difference(got: list[np.ndarray], reference: list[np.ndarray]) -> float:
    """The largest difference over the output and gradients, each relative to its reference's
    largest magnitude, or to 1e-6 where that is smaller (a gradient that is zero on one device and
    rounding noise on the other)."""
    return max(float(np.max(np.abs(g - r)) / max(float(np.max(np.abs(r))), 1e-6)) for g, r in zip(got, reference))


# --------------------------------------------------------------------------------------- PyTorch


def torch_values(case: str, device: str, reference: bool, hostless: bool = False) -> list[np.ndarray]:
    """The case's output and gradients on `device` (float64): the tensor ops where `reference`.
    hostless: inside `without_host_reads`, on a GPU under a sync debug mode that raises on any
    synchronising call of the op's forward and backward (the module's move to the device and the
    weights' copy, which a user makes once, are outside it)."""
    import torch

    import diffblur
    import torch_impl

    name, kinds, options = CHECKS[case]
    options = reference_options(name, options) if reference else options
    host = inputs(kinds, CHECK_SHAPE)
    leaves = [torch.tensor(a, device=device, requires_grad=True) for a in host]
    watch = hostless and torch.device(device).type == "cuda"

    def unwatched(fn):
        def run(*args):
            if watch:
                torch.cuda.set_sync_debug_mode("default")
            try:
                return fn(*args)
            finally:
                if watch:
                    torch.cuda.set_sync_debug_mode("error")

        return run

    if watch:
        torch.cuda.synchronize()
        torch.cuda.set_sync_debug_mode("error")
    try:
        with diffblur.without_host_reads() if hostless else nullcontext():
            out = call(torch_impl, name, kinds, options, leaves, place=unwatched(lambda layer: layer.to(device)))
            weight = unwatched(lambda: torch.tensor(weights(tuple(out.shape)), device=device))()
            grads = torch.autograd.grad((out * weight).sum(), leaves, allow_unused=True)
    finally:
        if watch:
            torch.cuda.set_sync_debug_mode("default")
    return [out.detach().cpu().numpy()] + [np.zeros(a.shape) if g is None else g.cpu().numpy() for g, a in zip(grads, host)]


# ------------------------------------------------------------------------------------------- JAX


def jax_device(kind: str):
    import jax

    return jax.devices("cpu" if kind == "cpu" else "gpu")[0]


def jax_values(case: str, device: str, reference: bool) -> list[np.ndarray]:
    """The case's output and gradients under `jax.jit` on `device` (float64); the tensor ops where
    `reference`."""
    import jax
    import jax.numpy as jnp

    import jax_impl

    name, kinds, options = CHECKS[case]
    options = reference_options(name, options) if reference else options
    with jax.default_device(jax_device(device)):
        host = [jnp.asarray(a) for a in inputs(kinds, CHECK_SHAPE)]
        out_shape = jax.eval_shape(lambda *a: call(jax_impl, name, kinds, options, list(a)), *host).shape
        w = jnp.asarray(weights(out_shape))

        def loss(*arrays):
            out = call(jax_impl, name, kinds, options, list(arrays))
            return jnp.sum(out * w), out

        (_, out), grads = jax.jit(jax.value_and_grad(loss, argnums=tuple(range(len(host))), has_aux=True))(*host)
        return [np.asarray(out)] + [np.asarray(g) for g in grads]


def jax_host_callbacks(case: str, device: str) -> list[str]:
    """The host callbacks in the compiled forward+backward of the case's tensor ops, traced inside
    `without_host_reads` (none expected)."""
    import jax
    import jax.numpy as jnp

    import diffblur
    import jax_impl

    name, kinds, options = CHECKS[case]
    options = reference_options(name, options)
    with jax.default_device(jax_device(device)), diffblur.without_host_reads():
        host = [jnp.asarray(a) for a in inputs(kinds, CHECK_SHAPE)]
        loss = lambda *arrays: jnp.sum(call(jax_impl, name, kinds, options, list(arrays)))  # noqa: E731
        text = jax.jit(jax.grad(loss, argnums=tuple(range(len(host))))).lower(*host).as_text()
    return sorted(set(m.group(0) for m in HOST_CALLBACK.finditer(text)))


# ---------------------------------------------------------------------------------------- checks


def check_case(case: str, device: str, frameworks: tuple[str, ...]) -> dict:
    """One case's row: per framework the device against the CPU and the host-read check; the two
    frameworks against each other on the device. Errors are reported, not raised."""
    row: dict = {"case": case}
    got = {}
    for framework in frameworks:
        try:
            if framework == "torch":
                got["torch"] = torch_values(case, device, reference=False)
                row["torch"] = relative_difference(got["torch"], torch_values(case, "cpu", reference=True))
                if device == "cuda":
                    torch_values(case, device, reference=False, hostless=True)
                    row["torch_hostless"] = "ok"
                else:  # no sync debug mode off a GPU; tests/torch/test_meta_device.py refuses host reads on the CPU
                    row["torch_hostless"] = NOT_ON_CPU
            else:
                got["jax"] = jax_values(case, device, reference=False)
                row["jax"] = relative_difference(got["jax"], jax_values(case, "cpu", reference=True))
                callbacks = jax_host_callbacks(case, device)
                row["jax_hostless"] = "ok" if not callbacks else "host callbacks: " + ", ".join(callbacks)
        except Exception as error:  # noqa: BLE001 - reported in the table
            row[f"{framework}_error"] = f"{type(error).__name__}: {str(error).splitlines()[0][:200] if str(error) else ''}"
    if "torch" in got and "jax" in got:
        row["torch_vs_jax"] = relative_difference(got["torch"], got["jax"])
    row["passed"] = passed(row, frameworks)
    return row


def passed(row: dict, frameworks: tuple[str, ...]) -> bool:
    differences = [row.get(f) for f in frameworks] + ([row.get("torch_vs_jax")] if len(frameworks) == 2 else [])
    return all(d is not None and d <= TOLERANCE for d in differences) and all(row.get(f"{f}_hostless") in ("ok", NOT_ON_CPU) for f in frameworks)


# --------------------------------------------------------------------------------------- timings


def timing_jobs(sizes: tuple[tuple[int, int], ...], frameworks: tuple[str, ...], kornia: bool, compile_: bool) -> list[dict]:
    """The timings in the order they run, the most wanted first: at the first size reconstruct
    without and with the jitter, then compiled by torch.compile (on a GPU eager PyTorch launches a
    kernel per tensor op: the 1 ms aim may need the compiled form), then with the data checks, then
    gather_blur and kornia (where installed); then the same at the other sizes, torch.compile aside."""
    reconstruct, gather = TIMED[:2], TIMED[2:]
    jobs = []

    def add(size, settings, mode, among=frameworks):
        jobs.extend(dict(size=size, method=m, setting=label, framework=f, mode=mode) for m, label in settings for f in among if f in frameworks)

    for index, size in enumerate(sizes):
        add(size, reconstruct, "without_host_reads")
        if compile_ and index == 0:
            add(size, reconstruct, "torch.compile", ("torch",))
        add(size, reconstruct[1:], "data checks")
        add(size, gather, "without_host_reads")
        if kornia:
            add(size, (KORNIA,), "eager", ("torch",))
    return jobs


def _setting(method: str, label: str):
    from diffblur.app.bench import SETTINGS

    return next(s for s in SETTINGS if (s.method, s.label) == (method, label))


def run_timing(job: dict, device: str, x: dict, repeats: int) -> dict:
    """One job's forward and forward+backward medians (ms), and its compile time (s) where it has one."""
    import diffblur
    from diffblur.app.bench import _JaxRunner, _TorchRunner
    from diffblur.app.timing import median_ms, median_ms_each

    setting = _setting(job["method"], job["setting"])
    hostless = job["mode"] in ("without_host_reads", "torch.compile")

    def inside(fn):
        def run():
            with diffblur.without_host_reads() if hostless else nullcontext():
                return fn()

        return run

    if job["framework"] == "jax":
        import jax

        with jax.default_device(jax_device(device)), diffblur.without_host_reads() if hostless else nullcontext():
            prepared = _JaxRunner().prepare(setting, x)  # traced and compiled here, inside the mode
        forward, backward = median_ms_each([prepared["forward"], prepared["backward"]], repeats)
        return dict(forward_ms=forward, backward_ms=backward, compile_s=prepared["compile_s"] + prepared["compile_backward_s"], memory_mb=prepared["xla_temp_mb"])
    import torch

    runner = _TorchRunner(device)
    if job["mode"] != "torch.compile":
        prepared = runner.prepare(setting, x)
        forward, backward = median_ms_each([inside(prepared["forward"]), inside(prepared["backward"])], repeats)
        memory_mb = None
        if runner.device.type == "cuda":  # the peak of one forward+backward above what was allocated before it
            before = torch.cuda.memory_allocated()
            torch.cuda.reset_peak_memory_stats()
            inside(prepared["backward"])()
            memory_mb = (torch.cuda.max_memory_allocated() - before) / 2**20
        return dict(forward_ms=forward, backward_ms=backward, compile_s=None, memory_mb=memory_mb)

    import torch_impl

    tensors = {k: torch.from_numpy(v).to(runner.device) for k, v in x.items()}
    compiled = torch.compile(lambda t: setting.call(torch_impl, t), fullgraph=True, dynamic=False)
    wait = torch.cuda.synchronize if runner.device.type == "cuda" else (lambda: None)

    def forward():
        with torch.no_grad():
            compiled(tensors)
        wait()

    started = time.perf_counter()
    inside(forward)()
    compile_s = time.perf_counter() - started
    return dict(forward_ms=median_ms(inside(forward), repeats), backward_ms=None, compile_s=compile_s, memory_mb=None)


# ---------------------------------------------------------------------------------------- report


def environment(device: str, frameworks: tuple[str, ...]) -> dict:
    """The bench's machine record (`diffblur.app.bench._machine`: processor, versions of the modules
    loaded, date) and the device each framework runs on."""
    from diffblur.app.bench import _machine

    devices = {}
    if "torch" in frameworks:
        import torch

        devices["torch_device"] = torch.cuda.get_device_name() if device == "cuda" else "cpu"
    if "jax" in frameworks:
        devices["jax_device"] = str(jax_device(device).device_kind)
    return {**_machine(os.getloadavg()), "device": device, **devices}


def _ms(value: float | None) -> str:
    """A time in ms: three decimals below 10 ms (a GPU's times are fractions of one)."""
    return _fmt(value, 3 if value is not None and value < 10 else 1)


def _difference(value: float | None, error: str | None) -> str:
    return error if error else ("-" if value is None else f"{value:.1e}")


def markdown(results: dict) -> str:
    """The section "GPU" of BENCHMARKS.md."""
    env = results["environment"]
    names = ", ".join(f"{k} {v}" for k, v in env["versions"].items())
    devices = "; ".join(f"{k.split('_')[0]}: {env[k]}" for k in ("torch_device", "jax_device") if k in env)
    lines = [
        "## GPU",
        "",
        f"Generated by `PYTHONPATH=. python scripts/measure_gpu.py --device {env['device']} --write` on {env['date']} "
        f"({devices}; {env['cpu']}, {env['cores']} cores; {names}), in {results['seconds']:.0f} s. Checks: float64, inputs {CHECK_SHAPE}, the largest "
        f"difference of the output and of the gradients of a fixed weighted sum, relative to the reference's largest value (or 1e-6) "
        f"(tolerance {TOLERANCE:.0e}): the device against the CPU's tensor ops, and PyTorch against JAX on the device; "
        "'no host reads': PyTorch's forward and backward inside `diffblur.without_host_reads` under "
        "`torch.cuda.set_sync_debug_mode(\"error\")`, JAX's compiled forward and backward there without host callbacks.",
        "",
        "| case | PyTorch device vs CPU | JAX device vs CPU | PyTorch vs JAX | PyTorch: no host reads | JAX: no host reads | passed |",
        "|---|---:|---:|---:|---|---|---|",
    ]
    for row in results["checks"]:
        lines.append(
            f"| {row['case']} | {_difference(row.get('torch'), row.get('torch_error'))} | {_difference(row.get('jax'), row.get('jax_error'))} "
            f"| {_difference(row.get('torch_vs_jax'), None)} | {row.get('torch_hostless', '-')} | {row.get('jax_hostless', '-')} | {'yes' if row['passed'] else 'NO'} |"
        )
    lines += [
        "",
        "Timings: float32, the bench's uniform scene, forward and forward+backward in turns, median of "
        f"{results['repeats']} after a warm-up, each call waiting for the device; compile s: JAX's forward and "
        "forward+backward, torch.compile's first forward; memory MB: PyTorch's peak GPU allocation during one "
        "forward+backward above what was allocated before it, JAX's compiled temporaries (XLA's memory_analysis).",
        "",
        "| size | method | setting | framework | mode | forward ms | fwd+bwd ms | compile s | memory MB |",
        "|---|---|---|---|---|---:|---:|---:|---:|",
    ]
    for row in results["timings"]:
        size = f"{row['size'][1]}x{row['size'][0]}"
        if "skipped" in row or "error" in row:
            lines.append(f"| {size} | {row['method']} | {row['setting']} | {row['framework']} | {row['mode']} | {row.get('skipped') or row['error']} | | | |")
            continue
        lines.append(
            f"| {size} | {row['method']} | {row['setting']} | {row['framework']} | {row['mode']} | {_ms(row['forward_ms'])} | {_ms(row['backward_ms'])} "
            f"| {_fmt(row['compile_s'])} | {_fmt(row.get('memory_mb'))} |"
        )
    best = [r for r in results["timings"] if r.get("forward_ms") is not None and r["method"] == "reconstruct" and tuple(r["size"]) == TARGET_SIZE]
    if best:
        fastest = min(best, key=lambda r: r["forward_ms"])
        met = "met" if fastest["forward_ms"] < 1.0 else "not met"
        lines += ["", f"Target, reconstruct at 1920x1080 under 1 ms: {met}, fastest {_ms(fastest['forward_ms'])} ms ({fastest['framework']}, {fastest['setting']}, {fastest['mode']})."]
    return "\n".join(lines) + "\n"


def write_section(text: str) -> None:
    from diffblur.app.bench import replace_section

    replace_section(str(ROOT / "BENCHMARKS.md"), "## GPU", text)


def save(results: dict, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "gpu.json").write_text(json.dumps(results, indent=1))
    (out / "gpu.md").write_text(markdown(results))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, help="folder for gpu.json and gpu.md (required unless --render)")
    parser.add_argument("--render", type=Path, help="a run's gpu.json (one brought back from a GPU machine): print its section, with --write put it into BENCHMARKS.md, run nothing")
    parser.add_argument("--device", default="cuda", choices=("cuda", "cpu"))
    parser.add_argument("--frameworks", default="torch,jax")
    parser.add_argument("--budget", type=float, default=300.0, help="seconds from the start after which no timing starts")
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--sizes", default="", help="HxW,... in place of 1080x1920,720x1280 (e.g. a tiny size for a test)")
    parser.add_argument("--only", default="", help="comma-separated check cases (default: all)")
    parser.add_argument("--no-compile", action="store_true", help="leave out torch.compile")
    parser.add_argument("--write", action="store_true", help="put the section into BENCHMARKS.md")
    args = parser.parse_args()
    if args.render:
        text = markdown(json.loads(args.render.read_text()))
        print(text, end="")
        if args.write:
            write_section(text)
        return 0
    if args.out is None:
        parser.error("--out is required (or --render a run's gpu.json)")
    os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")  # JAX leaves PyTorch its share of the GPU
    frameworks = tuple(f for f in args.frameworks.split(",") if f)
    if "jax" in frameworks:
        import jax

        jax.config.update("jax_enable_x64", True)  # the checks' float64
    sizes = tuple(tuple(int(n) for n in size.split("x")) for size in args.sizes.split(",")) if args.sizes else SIZES
    started = time.perf_counter()
    results = {"environment": environment(args.device, frameworks), "repeats": args.repeats, "checks": [], "timings": [], "seconds": 0.0}
    for case in [c for c in CHECKS if not args.only or c in args.only.split(",")]:
        row = check_case(case, args.device, frameworks)
        results["checks"].append(row)
        print(f"check {case}: {row}", file=sys.stderr, flush=True)
    results["seconds"] = time.perf_counter() - started
    save(results, args.out)
    if "jax" in frameworks:
        jax.config.update("jax_enable_x64", False)  # the timings as `diffblur bench` runs them
    kornia = "torch" in frameworks and importlib.util.find_spec("kornia") is not None
    scenes = {}
    for job in timing_jobs(sizes, frameworks, kornia, not args.no_compile):
        row = {**job}
        if time.perf_counter() - started > args.budget:
            row["skipped"] = f"not run: past the {args.budget:.0f} s budget"
        else:
            from diffblur.app.bench import _inputs, uniform_scene

            if job["size"] not in scenes:
                scenes[job["size"]] = _inputs(uniform_scene(height=job["size"][0], width=job["size"][1], instants=1))
            try:
                row.update(run_timing(job, args.device, scenes[job["size"]], args.repeats))
            except Exception as error:  # noqa: BLE001 - reported in the table
                row["error"] = f"{type(error).__name__}: {str(error).splitlines()[0][:200] if str(error) else ''}"
        results["timings"].append(row)
        results["seconds"] = time.perf_counter() - started
        save(results, args.out)
        print(f"timing {row}", file=sys.stderr, flush=True)
    text = markdown(results)
    print(text, end="")
    if args.write:
        write_section(text)
    return 0 if all(row["passed"] for row in results["checks"]) else 1


if __name__ == "__main__":
    sys.exit(main())
