"""A pytest plugin that makes one framework look uninstalled, to check that a one-framework install
runs its tests: `DIFFBLUR_TESTS_WITHOUT=jax python -m pytest -p tests.without_framework ...` (or
`=torch`). Loaded with -p, it installs its import blocker before conftest.py or any test imports
anything; importing a blocked module then raises ModuleNotFoundError, as on a machine without it.
tests/test_one_framework.py runs it."""

from __future__ import annotations

import os
import sys

#: The top-level modules each framework's extra brings.
BLOCKED = {"jax": ("jax", "jaxlib", "equinox", "optax", "optimistix"), "torch": ("torch", "kornia", "torchvision")}


class Blocker:
    """A meta path finder that refuses the blocked top-level modules."""

    def __init__(self, names: tuple[str, ...]) -> None:
        self.names = names

    def find_spec(self, fullname, path=None, target=None):
        if fullname.split(".")[0] in self.names:
            raise ModuleNotFoundError(f"No module named {fullname!r} (blocked by tests/without_framework.py)", name=fullname)
        return None


framework = os.environ.get("DIFFBLUR_TESTS_WITHOUT")
if framework is not None:
    if framework not in BLOCKED:
        raise ValueError(f"DIFFBLUR_TESTS_WITHOUT must be one of {', '.join(BLOCKED)}, got {framework!r}")
    already = sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED[framework])
    if already:
        raise RuntimeError(f"{', '.join(already)} imported before the blocker: load it with -p tests.without_framework")
    sys.meta_path.insert(0, Blocker(BLOCKED[framework]))
