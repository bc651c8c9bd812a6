"""diffblur: differentiable real-time motion blur, framework-neutral core (NumPy only).

The core, this package's top level: `conventions` (shapes, units, constants), `checks` (argument
checks both backends share), `shutters`, `metrics`, `ops` (every op defined once: its options,
docstring and math, for both frameworks) and `reference` (the NumPy oracle of every op). Above it: `kernels` (the fused CPU kernels, numba), `scenes` (the
ground-truth renderer) and `app` (the command, the benchmark, the demo). The PyTorch ops live in
`torch_impl`, the JAX ops in `jax_impl`; only `app` imports them, and nothing in this package
imports a framework (tests/core/test_layers.py).
"""

from diffblur.checks import without_host_reads

__all__ = ["without_host_reads"]
__version__ = "0.1.0"
