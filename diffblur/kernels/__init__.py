"""The fused CPU kernels (numba): NumPy arrays in, NumPy arrays out, one file per op.

- `reconstruct`: `reconstruct`'s filter and its hand-written backward;
- `gather`: `gather_blur`'s, with the shutter's mass table;
- `scatter`: `bezier_scatter`'s splats;
- `shared`: what they share: numba's set-up (threading layer, kernel lock), the pair
  layouts, the row blocks, the bilinear reads, and the scratch named tuples' allocation.

The backends bind them (`torch_impl._fused*` as custom operators, `jax_impl._fused*` as `custom_vjp`s
over host callbacks). This layer imports the core (`diffblur.conventions`, `taps`, `shutters`, ...),
never a framework, the scenes or the apps (tests/core/test_layers.py).
"""
