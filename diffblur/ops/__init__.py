"""The ops, each defined once: its options, its docstring and its math, for both frameworks.

One module per op (`gather`, `reconstruct`, `scatter`, `warp`, `motion_ids`, `primitives`, the layer
in `module`), each holding

- its options, a frozen dataclass (`OpOptions`) that checks them and resolves what follows from them;
- the public docstring, which both backends show;
- the math, written once against a `Backend` (`diffblur.ops.backend`): `be.xp` is the framework's
  array namespace (torch or jax.numpy, for the functions the two share by name and meaning) and
  `be`'s methods hold what differs (sampling reads, scatter-adds, the tap loop, value checks under
  compilation, the fused kernels).

`torch_impl` and `jax_impl` keep, per op, the public function with its jaxtyping signature, which
passes its own `Backend` here. Shared by several ops: `sampling` (the bilinear and nearest reads),
`pyramid` (the pre-filtered levels), `adaptive` (tiled adaptive sampling), `taps` (where the taps sit
in the exposure, the shutter's weights).

Nothing here imports a framework: the backends hand theirs in.
"""
