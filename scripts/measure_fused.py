"""Measure the fused CPU kernels (diffblur.kernels: reconstruct, gather) against the tensor ops and
kornia, in one run.

Part 1, the design's targets: 1280x720 uniform pan, float32, S=15, forward and forward+backward
(w.r.t. every differentiable input), `reconstruct` and `gather_blur` in PyTorch (eager) and JAX
(jitted, compile time reported apart), and kornia's motion_blur (kernel 31, bilinear, backward
w.r.t. the image and the angle).
Part 2, adaptive sampling: a 512x512 scene that is 90 % still, full rate against adaptive=True, both
ops, both frameworks (JAX jitted), fused and tensor ops, with the largest output difference.

Times are medians of `--repeats` runs after one warm-up, the runs of a pair (forward and
forward+backward, full rate and adaptive) taking turns, in milliseconds.

    PYTHONPATH=. python scripts/measure_fused.py [--repeats 3] [--only targets|adaptive]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

from diffblur.app.timing import median_ms_each

sys.path.insert(0, os.path.dirname(__file__))


def _torch_pair(op, arrays, options, repeats):
    """Forward and forward+backward times of a torch_impl op on float32 CPU tensors."""
    import torch

    import torch_impl

    fn = getattr(torch_impl, op)

    def forward():
        with torch.no_grad():
            fn(*arrays, **options)

    def forward_backward():
        inputs = [a.clone().requires_grad_() for a in arrays]
        fn(*inputs, **options).sum().backward()

    return tuple(median_ms_each([forward, forward_backward], repeats))


def _jax_pair(op, arrays, options, repeats):
    """Compile+first-call, forward and forward+backward times of a jitted jax_impl op."""
    import jax
    import jax.numpy as jnp

    import jax_impl

    fn = getattr(jax_impl, op)
    forward = jax.jit(lambda *a: fn(*a, **options))
    # value_and_grad: forward + backward (jax.grad alone may drop a forward whose value the gradient does not need).
    gradient = jax.jit(jax.value_and_grad(lambda *a: jnp.sum(fn(*a, **options)), argnums=tuple(range(len(arrays)))))
    start = time.perf_counter()
    jax.block_until_ready(forward(*arrays))
    compile_ms = 1e3 * (time.perf_counter() - start)
    return (
        compile_ms,
        *median_ms_each([lambda: jax.block_until_ready(forward(*arrays)), lambda: jax.block_until_ready(gradient(*arrays))], repeats),
    )


def targets(repeats: int) -> None:
    import jax.numpy as jnp
    import kornia
    import torch

    from diffblur.app.bench import _inputs, uniform_scene

    scene = _inputs(uniform_scene(height=720, width=1280))
    names = {"reconstruct": ("color", "velocity", "depth"), "gather_blur": ("color", "velocity")}
    print("1280x720 uniform pan, float32, S=15 (ms)")
    print(f"{'op':<12} {'path':<11} {'torch fwd':>10} {'torch f+b':>10} {'jax compile':>12} {'jax fwd':>9} {'jax f+b':>9}")
    for op, keys in names.items():
        for path, impl in (("fused", "auto"), ("tensor ops", "tensor")):
            options = dict(samples=15, impl=impl)
            torch_fwd, torch_both = _torch_pair(op, [torch.from_numpy(scene[k]) for k in keys], options, repeats)
            compile_ms, jax_fwd, jax_both = _jax_pair(op, [jnp.asarray(scene[k]) for k in keys], options, repeats)
            print(f"{op:<12} {path:<11} {torch_fwd:10.0f} {torch_both:10.0f} {compile_ms:12.0f} {jax_fwd:9.0f} {jax_both:9.0f}", flush=True)
    color, angle = torch.from_numpy(scene["color"]), torch.tensor(scene["angle"])

    def kornia_forward():
        with torch.no_grad():
            kornia.filters.motion_blur(color, 31, angle, 0.0, border_type="replicate", mode="bilinear")

    def kornia_forward_backward():
        image, direction = color.clone().requires_grad_(), angle.clone().requires_grad_()
        kornia.filters.motion_blur(image, 31, direction, 0.0, border_type="replicate", mode="bilinear").sum().backward()

    kornia_ms = median_ms_each([kornia_forward, kornia_forward_backward], repeats)
    print(f"kornia motion_blur k=31: forward {kornia_ms[0]:.0f}, forward+backward {kornia_ms[1]:.0f}")


def adaptive(repeats: int) -> None:
    import jax
    import jax.numpy as jnp
    import torch

    import jax_impl
    import torch_impl
    from measure_warps_adaptive_pyramid import still_scene

    scene = still_scene(512)
    print("512x512, 90 % still, float32, S=15, forward (ms); JAX jitted")
    for op in ("gather_blur", "reconstruct"):
        count = 2 if op == "gather_blur" else 3
        for path, impl in (("fused", "auto"), ("tensor ops", "tensor")):
            for framework in ("torch", "jax"):
                if framework == "torch":
                    arrays = [torch.from_numpy(a) for a in scene[:count]]
                    fn = getattr(torch_impl, op)
                    full = lambda fn=fn, arrays=arrays: fn(*arrays, samples=15, impl=impl).numpy()  # noqa: E731
                    tiled = lambda fn=fn, arrays=arrays: fn(*arrays, samples=15, adaptive=True, impl=impl).numpy()  # noqa: E731
                else:
                    arrays = [jnp.asarray(a) for a in scene[:count]]
                    fn = getattr(jax_impl, op)
                    full_jit = jax.jit(lambda *a, fn=fn: fn(*a, samples=15, impl=impl))
                    tiled_jit = jax.jit(lambda *a, fn=fn: fn(*a, samples=15, adaptive=True, impl=impl))
                    full = lambda f=full_jit, arrays=arrays: np.asarray(f(*arrays))  # noqa: E731
                    tiled = lambda f=tiled_jit, arrays=arrays: np.asarray(f(*arrays))  # noqa: E731
                with torch.no_grad():
                    difference = float(np.abs(full() - tiled()).max())
                    full_ms, tiled_ms = median_ms_each([full, tiled], repeats)
                print(
                    f"{op:<12} {path:<11} {framework:<6} full {full_ms:7.1f}  adaptive {tiled_ms:6.1f}  "
                    f"{full_ms / tiled_ms:4.1f}x  max difference {difference:.1e}",
                    flush=True,
                )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--only", choices=("targets", "adaptive"))
    arguments = parser.parse_args()
    print(f"{os.cpu_count()} CPUs, load {os.getloadavg()[0]:.1f}")
    if arguments.only != "adaptive":
        targets(arguments.repeats)
    if arguments.only != "targets":
        adaptive(arguments.repeats)


if __name__ == "__main__":
    main()
