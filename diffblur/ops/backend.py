"""`Backend`: what an op written once in `diffblur.ops` asks of a framework.

Each backend (`torch_impl._backend.TORCH`, `jax_impl._backend.JAX`) is an instance of a subclass.
`xp` is the framework's array namespace (torch or jax.numpy), used for what the two spell the same
with the same meaning (where, floor, sqrt, stack, ...); the subclass's methods hold what differs:

- argument facts and value checks: `array`, `is_array`, `is_floating`, `is_integer`,
  `require_same_device`, `check_values`, `check_positive`, `check_finite`, `is_tracing`, `values`;
- arrays: `astype`, `index`, `stop_gradient`, `arange`, `asarray`, `zeros`, `on_device`, `concat`,
  `permute`, `repeat`, `pad`, `argmax`, `take_along` (x's values at integer `index` along `axis`,
  the other axes broadcast, as NumPy's take_along_axis), `read_pixels`, `contiguous`, `row_indices`,
  `write_rows`, `scatter_add`, `scatter_min`, `band`, `per_channel`, `widen_window`, `noise_jitter`;
- compilation and gradients: `constant`, `outside_compiler`, `compiled`, `needs_gradient`, and the
  loops whose memory matters, `sum_taps` (reconstruct's and the gather's taps) and `sum_chunks`
  (the scatter's chunks of points);
- the fused CPU kernels: `bindings` (the backend's binding modules); `kernel_reason` and
  `run_kernel`, defined here over them.

Attributes: `name` ("torch", "jax"), `xp`, `half` (the half dtypes), `compiler` (its name, for
messages), `integer` (the index dtype), `array_word` and `array_type_name` (for messages).
"""

from __future__ import annotations

from typing import Any

__all__ = ["Backend"]


class Backend:
    """The base of each framework's backend; see the module docstring for what a subclass defines."""

    def __init__(self, name: str, xp: Any, *, half: tuple, compiler: str, integer: Any, array_word: str, array_type_name: str) -> None:
        self.name, self.xp, self.half, self.compiler = name, xp, half, compiler
        self.integer, self.array_word, self.array_type_name = integer, array_word, array_type_name

    def __repr__(self) -> str:
        return f"Backend({self.name!r})"

    def bindings(self) -> tuple[Any, Any]:
        """The backend's modules that bind the fused kernels: (reconstruct's and gather_blur's,
        bezier_scatter's). Imported when first asked for: they import numba."""
        raise NotImplementedError

    def kernel_reason(self, op: str, color: Any, o: Any, *arrays: Any) -> str | None:
        """Why `op`'s fused kernel cannot run these inputs and options `o`, or None when it can;
        reconstruct passes its jitter in `arrays`."""
        fused, fused_scatter = self.bindings()
        if op == "gather_blur":
            return fused.gather_unfused_reason(color, o.sampling)
        if op == "bezier_scatter":
            return fused_scatter.unfused_reason(color)
        return fused.unfused_reason(o, color, *arrays)

    def run_kernel(self, op: str, *arrays: Any) -> Any:
        """`op` on its fused kernel: gather_blur (color, velocity, o), reconstruct (color, velocity,
        depth, jitter, o), bezier_scatter's splats (color, depth, kind, terms, masses, extent,
        moving, paper) and its instants (color, log depth, depth, kind, terms, times, extent,
        moving)."""
        from diffblur.ops.sampling import position_dtype

        fused, fused_scatter = self.bindings()
        if op == "bezier_scatter":
            return fused_scatter.fused_splat(*arrays)
        if op == "instants":
            return fused_scatter.fused_instants(*arrays)
        *arrays, o = arrays
        if op == "gather_blur":
            return fused.fused_gather(*arrays, o.window, o.samples, o.classes, position_dtype(self, arrays[0].dtype))
        return fused.fused_reconstruct(*arrays, o)
