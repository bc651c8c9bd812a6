"""Test-wide settings, also for the doctests in the packages: strict JAX, float64 available.

JAX runs with strict dtype promotion and rank promotion errors (as equinox and optimistix test
themselves), and x64 enabled so the float64 checks are float64; float32 tests ask for float32.
"""

import os

os.environ.setdefault("MPLBACKEND", "Agg")
# XLA's CPU compiler spends most of the suite's JAX time on code the tests run once: its backend
# optimisations (a quarter of the warp_blend equivalence tests' CPU time) and its fusion emitters
# (the older emitters compile a reconstruct's check_grads in a third of the time); results stay
# within every tolerance. A user's own XLA_FLAGS for either setting win.
for _flag in ("--xla_backend_optimization_level=0", "--xla_cpu_use_fusion_emitters=false"):
    if _flag.split("=")[0] not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + _flag).strip()

try:
    import jax
except ImportError:  # a torch-only install runs the torch and core tests
    jax = None

import importlib.util  # noqa: E402


def _installed(name: str) -> bool:
    """Whether `name` can be imported, without importing it (tests/without_framework.py's blocker
    raises ModuleNotFoundError from the lookup itself)."""
    try:
        return importlib.util.find_spec(name) is not None
    except ModuleNotFoundError:
        return False


if jax is not None:
    jax.config.update("jax_enable_x64", True)
    jax.config.update("jax_numpy_dtype_promotion", "strict")
    jax.config.update("jax_numpy_rank_promotion", "raise")


def pytest_configure(config):
    """In pytest-xdist's controller, compile the fused kernels once, before the workers start (see
    tests/warm_kernels.py): one process per dtype, side by side. A warm cache makes this a few
    seconds; a plain run without workers compiles as it goes, as before."""
    import subprocess
    import sys
    import time
    from pathlib import Path

    if jax is None or not _installed("torch"):
        # A one-framework install: modules that import the other framework (its backend package,
        # the cross-framework tests) have no doctests to run here; their tests skip with the reason
        # (tests/conftest.py).
        config.option.doctest_ignore_import_errors = True
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None):
        return
    terminal = config.pluginmanager.get_plugin("terminalreporter")
    say = terminal.write_line if terminal is not None else print
    say("compiling the fused kernels into numba's cache first (tests/warm_kernels.py): 2 to 3 minutes on a cold cache")
    start = time.perf_counter()
    root = Path(__file__).parent
    runs = [subprocess.Popen([sys.executable, "-m", "tests.warm_kernels", dtype], cwd=root) for dtype in ("float32", "float64")]
    failed = [run.args[-1] for run in runs if run.wait() != 0]
    # A failure here shows again, with its test, where the tests call the kernel.
    say(f"fused kernels ready in {time.perf_counter() - start:.0f} s" + (f" (warm-up failed: {', '.join(failed)})" if failed else ""))
