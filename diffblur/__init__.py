"""diffblur: differentiable real-time motion blur, framework-neutral core (NumPy only).

Submodules: `conventions` (shapes, units, constants), `checks` (argument checks both backends
share), `reference` (NumPy oracle of every op). The PyTorch ops live in `torch_impl`, the JAX
ops in `jax_impl`; this package never imports either framework.
"""

__version__ = "0.1.0"
