"""Peak memory of every image op on degenerate shapes (1xN, Nx1), every dtype, both frameworks.

One forward + backward (the gradient of the output's sum w.r.t. every floating input) per case, eager
PyTorch and eager JAX, default options, velocities mixing still pixels and speeds up to ~40 px.
The peak is the resident-set high-water mark above the resting RSS (`diffblur.app.bench._peak_rss_mb`:
malloc_trim, then /proc/self/clear_refs resets VmHWM), divided by the inputs' bytes.

    PYTHONPATH=. python scripts/measure_degenerate_memory.py [--n 4097] [--frameworks torch,jax]
"""

from __future__ import annotations

import argparse

import numpy as np

from diffblur.app.bench import _peak_rss_mb

OPS = ("gather_blur", "reconstruct", "bezier_scatter", "warp_blend", "accumulate_warps")
DTYPES = ("float16", "bfloat16", "float32", "float64")


def arrays(height: int, width: int):
    rng = np.random.default_rng(0)
    color = rng.random((1, 3, height, width))
    speed = np.where(rng.random((1, 1, height, width)) < 0.5, 0.0, rng.uniform(0.0, 40.0, size=(1, 1, height, width)))
    angle = rng.uniform(0.0, 2 * np.pi, size=(1, 1, height, width))
    velocity = np.concatenate([speed * np.cos(angle), speed * np.sin(angle)], axis=1)
    depth = rng.uniform(1.0, 2.0, size=(1, 1, height, width))
    return color, velocity, depth


def call(ops, op, c, v, z):
    if op == "gather_blur":
        return ops.gather_blur(c, v)
    if op == "reconstruct":
        return ops.reconstruct(c, v, z)
    if op == "bezier_scatter":
        return ops.bezier_scatter(c, z, -v, v, fill="color")
    if op == "warp_blend":
        return ops.warp_blend(c, v)
    return ops.accumulate_warps(c, v)


def torch_case(op, dtype, host):
    import torch

    import torch_impl

    def run():
        leaves = [torch.tensor(a, dtype=getattr(torch, dtype), requires_grad=True) for a in host]
        out = call(torch_impl, op, *leaves)
        out.float().sum().backward()

    return run


def jax_case(op, dtype, host):
    import jax
    import jax.numpy as jnp

    import jax_impl

    def run():
        leaves = [jnp.asarray(a, dtype=dtype) for a in host]
        grads = jax.grad(lambda c, v, z: jnp.sum(call(jax_impl, op, c, v, z).astype(jnp.float32)), argnums=(0, 1, 2))(*leaves)
        jax.block_until_ready(grads)

    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=4097)
    parser.add_argument("--frameworks", default="torch,jax")
    args = parser.parse_args()
    print("| framework | op | dtype | shape | peak MB | peak / input bytes |")
    print("|---|---|---|---|---:|---:|")
    for framework in args.frameworks.split(","):
        import jax

        jax.config.update("jax_enable_x64", True)
        for op in OPS:
            for dtype in DTYPES:
                for height, width in ((1, args.n), (args.n, 1)):
                    host = arrays(height, width)
                    size = sum(a.size for a in host) * (2 if dtype == "bfloat16" else np.dtype(dtype).itemsize)
                    case = (torch_case if framework == "torch" else jax_case)(op, dtype, host)
                    try:
                        case()  # warm: compile caches, allocator pools
                        peak = _peak_rss_mb(case)
                        cells = [f"{peak:.1f}", f"{peak * 2**20 / size:.0f}"]
                    except Exception as error:  # noqa: BLE001 - reported in the table
                        cells = [f"{type(error).__name__}: {str(error).splitlines()[0][:80]}", ""]
                    print(f"| {framework} | {op} | {dtype} | {height}x{width} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
