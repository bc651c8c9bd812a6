"""A one-framework install runs the core tests and its framework's: the test suite run in a
subprocess with the other framework made unimportable (tests/without_framework.py), over the core
tests, one framework-specific module of each side and a module written once for both backends.
Tests of the missing framework must skip with the reason, and nothing may fail or error."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

#: Tests written once for both backends (the `backend` fixture), a few cheap ones.
BOTH = [
    "tests/equivalence/test_bad_input.py",
    "tests/equivalence/test_module.py",  # its JAX-only tests import JAX inside the test: skipped too
    "-k",
    "test_shutters or test_torch_primitives or test_jax_primitives or unknown or NHWC or tile or learns_a_shutter or learnable_only",
]
#: (framework kept, the other's module that must skip, tests to run)
RUNS = {
    "torch": ("jax", "tests/jax/test_jax_primitives.py", ["tests/core/test_shutters.py", "tests/jax/test_jax_primitives.py", *BOTH]),
    "jax": ("torch", "tests/torch/test_torch_primitives.py", ["tests/core/test_shutters.py", "tests/torch/test_torch_primitives.py", *BOTH]),
}


@pytest.mark.parametrize("kept", list(RUNS))
def test_suite_runs_with_one_framework(kept):
    blocked, other_module, args = RUNS[kept]
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTEST_", "DIFFBLUR_TESTS_"))}
    env["DIFFBLUR_TESTS_WITHOUT"] = blocked
    command = [sys.executable, "-m", "pytest", "-p", "tests.without_framework", "-p", "no:cacheprovider", "-p", "no:xdist", "-v", "-rs", *args]
    result = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    output = result.stdout + result.stderr
    assert result.returncode == 0, output[-3000:]
    summary = output.strip().splitlines()[-1]
    passed = int(re.search(r"(\d+) passed", summary).group(1))
    assert passed >= 20 and "failed" not in summary and "error" not in summary, summary
    # The other framework's own module and its backend's cases skip, saying what is missing.
    assert re.search(rf"SKIPPED \[\d+\] tests/conftest.py:\d+: needs {blocked}, not installed", output), output[-3000:]
    assert re.search(rf"SKIPPED \[\d+\] tests/equivalence/test_bad_input.py:\d+: {blocked} is not installed", output), output[-3000:]
    assert other_module.split("/")[-1] not in re.sub(r"SKIPPED.*|unable to import.*", "", output)
    kept_test, other_test = (f"test_{f}_layer_learns_a_shutter_shape" for f in (kept, blocked))
    assert re.search(rf"{kept_test} PASSED", output) and re.search(rf"{other_test} SKIPPED", output), output[-3000:]
    # The kept framework's cases of the tests written for both ran.
    assert re.search(rf"test_bad_input.py::\S+\[{kept}-[^\]]*\] PASSED", output), output[-3000:]
