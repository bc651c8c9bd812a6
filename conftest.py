"""Test-wide settings, also for the doctests in the packages: strict JAX, float64 available.

JAX runs with strict dtype promotion and rank promotion errors (as equinox and optimistix test
themselves), and x64 enabled so the float64 checks are float64; float32 tests ask for float32.
"""

import os

os.environ.setdefault("MPLBACKEND", "Agg")

try:
    import jax
except ImportError:  # a torch-only install runs the torch and core tests
    jax = None

if jax is not None:
    jax.config.update("jax_enable_x64", True)
    jax.config.update("jax_numpy_dtype_promotion", "strict")
    jax.config.update("jax_numpy_rank_promotion", "raise")
