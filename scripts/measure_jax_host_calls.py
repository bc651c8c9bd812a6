"""Where JAX's time goes around `reconstruct`'s fused kernels: the compiled forward+backward traced
by XLA's profiler, each operation's time per call, beside the same kernels called from Python alone.

1280x720 uniform pan, float32, S=15, `jitter="none"` (the shifted rows), the gradient w.r.t. colour,
velocity and depth, as BENCHMARKS.md's targets pass. Prints the kernels' time inside the XLA program
(its two FFI calls) and alone (the same arrays, called in turns), XLA's own operations, the
program's temporaries and the memory it pages in per call. Run it under different settings (e.g.
`OMP_WAIT_POLICY=PASSIVE`, `XLA_FLAGS=--xla_cpu_multi_thread_eigen=false`) to compare them.

    PYTHONPATH=. python scripts/measure_jax_host_calls.py [--repeats 9]
"""

from __future__ import annotations

import argparse
import collections
import glob
import gzip
import json
import resource
import statistics
import tempfile
import time

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

import jax_impl
from diffblur.app.bench import _inputs, uniform_scene
from diffblur.kernels import reconstruct as kernel


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=9)
    args = parser.parse_args()
    x = _inputs(uniform_scene(height=720, width=1280))
    arrays = {k: jnp.asarray(x[k]) for k in ("color", "velocity", "depth")}

    def blur(a):
        return jax_impl.reconstruct(a["color"], a["velocity"], a["depth"], samples=15, jitter="none")

    program = jax.jit(jax.value_and_grad(lambda a: jnp.sum(blur(a)))).lower(arrays).compile()

    # The kernels' arguments as the program hands them over, to call them alone after.
    captured = {}
    forward, backward = kernel.reconstruct_forward, kernel.reconstruct_backward

    def capture(name, function):
        def spy(*arguments, into, **settings):
            captured[name] = ([np.array(a) for a in arguments], settings, [np.empty_like(r) for r in into])
            return function(*arguments, into=into, **settings)

        return spy

    kernel.reconstruct_forward, kernel.reconstruct_backward = capture("forward", forward), capture("backward", backward)
    jax.block_until_ready(program(arrays))
    kernel.reconstruct_forward, kernel.reconstruct_backward = forward, backward

    calls = {
        "XLA program (fwd+bwd)": lambda: jax.block_until_ready(program(arrays)),
        "forward kernel alone": lambda: forward(*captured["forward"][0], **captured["forward"][1], into=captured["forward"][2]),
        "backward kernel alone": lambda: backward(*captured["backward"][0], **captured["backward"][1], into=captured["backward"][2]),
    }
    times = {name: [] for name in calls}
    for _ in tqdm(range(args.repeats), desc="timing in turns", unit="round"):
        for name, call in calls.items():
            start = time.perf_counter()
            call()
            times[name].append(1e3 * (time.perf_counter() - start))
    for name, values in times.items():
        print(f"{name:26s} median {statistics.median(values):7.1f} ms")

    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    calls["XLA program (fwd+bwd)"]()
    paged_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults) * resource.getpagesize() / 2**20
    print(f"XLA temporaries {program.memory_analysis().temp_size_in_bytes / 2**20:.1f} MB; paged in per call {paged_mb:.1f} MB")

    with tempfile.TemporaryDirectory() as folder:
        with jax.profiler.trace(folder, create_perfetto_trace=True):
            for _ in tqdm(range(args.repeats), desc="tracing", unit="call"):
                calls["XLA program (fwd+bwd)"]()
        events = json.load(gzip.open(glob.glob(f"{folder}/**/*.trace.json.gz", recursive=True)[0]))["traceEvents"]
    per_op = collections.defaultdict(float)
    for event in events:
        if event.get("ph") == "X" and not event["name"].startswith(("$", "ThunkExecutor", "Execute", "CommonPjRt")):
            per_op[event["name"]] += event.get("dur", 0) / 1e3 / args.repeats
    ffi = sum(ms for name, ms in per_op.items() if name.startswith("ffi_call"))
    print(f"traced per call: FFI calls (the kernels) {ffi:.1f} ms, XLA's own operations {sum(per_op.values()) - ffi:.1f} ms")
    for name, ms in sorted(per_op.items(), key=lambda item: -item[1])[:8]:
        print(f"  {ms:7.2f} ms  {name}")


if __name__ == "__main__":
    main()
