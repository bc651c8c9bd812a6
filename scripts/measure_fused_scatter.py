"""Measure bezier_scatter's fused CPU splats (diffblur.kernels.scatter) against the tensor ops.

1280x720, float32, a uniform pan: the photograph and depth of `diffblur.app.bench.uniform_scene` with
offsets (-V, +V), V = (8, 0) px, degree 2, a Gaussian shutter (named: the default is the box),
coverage normalisation and the push-pull fill; 16 points per curve (what samples=None picks for these 16 px paths). Forward
and forward+backward (w.r.t. color, depth and both offsets) in PyTorch (eager; also samples=None,
which measures the paths with tensor ops first) and JAX (jitted, compile time reported apart).

Times are medians of `--repeats` runs after one warm-up, forward and forward+backward runs taking
turns, in milliseconds.

    PYTHONPATH=. python scripts/measure_fused_scatter.py [--repeats 3] [--fused-only]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from diffblur.app.timing import median_ms_each

HALF_SPREAD = 8.0
SAMPLES = 16


def scene() -> list[np.ndarray]:
    """color, depth, offset_prev, offset_next: float32, (1, C, 720, 1280)."""
    from diffblur.app.bench import uniform_scene

    buffers = uniform_scene(height=720, width=1280)
    offset = np.zeros((1, 2, 720, 1280), dtype=np.float32)
    offset[:, 0] = HALF_SPREAD
    return [np.ascontiguousarray(buffers.color, dtype=np.float32), np.ascontiguousarray(buffers.depth, dtype=np.float32), -offset, offset]


def torch_times(arrays, options, repeats):
    """Forward and forward+backward of torch_impl.bezier_scatter on float32 CPU tensors."""
    import torch

    import torch_impl

    tensors = [torch.from_numpy(a) for a in arrays]

    def forward():
        with torch.no_grad():
            torch_impl.bezier_scatter(*tensors, **options)

    def forward_backward():
        inputs = [t.clone().requires_grad_() for t in tensors]
        torch_impl.bezier_scatter(*inputs, **options).sum().backward()

    return tuple(median_ms_each([forward, forward_backward], repeats))


def jax_times(arrays, options, repeats):
    """Compile+first call, forward and forward+backward of a jitted jax_impl.bezier_scatter."""
    import jax
    import jax.numpy as jnp

    import jax_impl

    inputs = [jnp.asarray(a) for a in arrays]
    forward = jax.jit(lambda *a: jax_impl.bezier_scatter(*a, **options))
    # value_and_grad: forward + backward (jax.grad alone may drop a forward whose value the gradient does not need).
    gradient = jax.jit(jax.value_and_grad(lambda *a: jnp.sum(jax_impl.bezier_scatter(*a, **options)), argnums=(0, 1, 2, 3)))
    start = time.perf_counter()
    jax.block_until_ready(forward(*inputs))
    compile_ms = 1e3 * (time.perf_counter() - start)
    return (
        compile_ms,
        *median_ms_each([lambda: jax.block_until_ready(forward(*inputs)), lambda: jax.block_until_ready(gradient(*inputs))], repeats),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--fused-only", action="store_true", help="skip the tensor ops (seconds per call)")
    args = parser.parse_args()
    import jax

    jax.config.update("jax_enable_x64", False)
    import numba

    arrays = scene()
    print(f"bezier_scatter 1280x720 float32, uniform pan |V| = {HALF_SPREAD:g} px, degree 2 (ms); cpus {os.cpu_count()}, numba threads {numba.get_num_threads()}")
    print(f"load average before: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
    print(f"{'path':<11} {'samples':>7} {'torch fwd':>10} {'torch f+b':>10} {'jax compile':>12} {'jax fwd':>9} {'jax f+b':>9}")
    paths = (("fused", "auto"),) if args.fused_only else (("fused", "auto"), ("tensor ops", "tensor"))
    for path, impl in paths:
        options = dict(degree=2, samples=SAMPLES, shutter="gaussian", impl=impl)
        torch_fwd, torch_both = torch_times(arrays, options, args.repeats)
        compile_ms, jax_fwd, jax_both = jax_times(arrays, options, args.repeats)
        print(f"{path:<11} {SAMPLES:>7} {torch_fwd:10.0f} {torch_both:10.0f} {compile_ms:12.0f} {jax_fwd:9.0f} {jax_both:9.0f}", flush=True)
        # samples=None measures the paths (eager only: JAX cannot jit it).
        torch_fwd, torch_both = torch_times(arrays, dict(options, samples=None), args.repeats)
        print(f"{path:<11} {'None':>7} {torch_fwd:10.0f} {torch_both:10.0f}", flush=True)
    print(f"load average after: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")


if __name__ == "__main__":
    main()
