"""Compile the fused kernels of one dtype into numba's on-disk cache: `python -m tests.warm_kernels float32`.

conftest.py runs it in pytest-xdist's controller, float32 and float64 side by side, before the workers
start. On a cold cache each worker otherwise compiled every kernel itself, both at once (~95 s of
CPU per worker, measured). The arrays are tiny; the kernels' argument types are what the tests and
both frameworks pass (`diffblur.kernels.shared.read_only` makes PyTorch's and JAX's arrays one type).
"""

from __future__ import annotations

import sys


def warm(dtype_name: str) -> None:
    import warnings

    import torch

    import torch_impl

    generator = torch.Generator().manual_seed(0)
    dtype = getattr(torch, dtype_name)

    def leaf(*shape, scale=1.0):
        return (torch.rand(*shape, dtype=dtype, generator=generator) * scale).requires_grad_()

    # The random offsets leave no pixel still; the scatter's warning says so, which is no news here.
    warnings.filterwarnings("ignore", message=r"bezier_scatter\(fill='still'\) found no still pixel")
    color, depth = leaf(1, 3, 10, 12), leaf(1, 1, 10, 12)
    velocity = leaf(1, 2, 10, 12, scale=4.0)
    torch_impl.reconstruct(color, velocity, depth, impl="fused").sum().backward()
    # Without jitter the kernels read shifted rows, whose backward adds its bands' margins in a kernel of its own.
    torch_impl.reconstruct(color, velocity, depth, jitter="none", impl="fused").sum().backward()
    torch_impl.gather_blur(color, velocity, impl="fused").sum().backward()
    torch_impl.gather_blur(color, velocity, adaptive=True, impl="fused").sum().backward()
    torch_impl.bezier_scatter(color, depth, -velocity, velocity, impl="fused").sum().backward()


if __name__ == "__main__":
    try:
        import numba  # noqa: F401
        import torch  # noqa: F401
    except ImportError:  # nothing to compile, or nothing to drive it with: the tests report which
        sys.exit(0)
    warm(sys.argv[1])
