"""Fixtures for every test module (the `backend` fixture), and one-framework installs: a test module
that imports a framework that is not installed is skipped, naming it, instead of failing to collect.
An install with only the torch extra (or only jax) so runs the core tests and that framework's."""

from __future__ import annotations

import pytest

from tests.backends import INSTALLED, backend  # noqa: F401  (the fixture, for every test module)

#: Top-level modules that come with each framework's extra.
FRAMEWORK_OF = {"torch": "torch", "kornia": "torch", "jax": "jax", "jaxlib": "jax", "equinox": "jax", "optax": "jax", "optimistix": "jax"}


def missing_framework(error: BaseException | None) -> str | None:
    """The framework whose absence raised `error` (a ModuleNotFoundError), or None."""
    if not isinstance(error, ModuleNotFoundError) or not error.name:
        return None
    framework = FRAMEWORK_OF.get(error.name.split(".")[0])
    return framework if framework is not None and not INSTALLED[framework] else None


class FrameworkModule(pytest.Module):
    """A test module that is skipped, with the reason, when it imports a framework not installed."""

    def _getobj(self):
        try:
            return super()._getobj()
        except self.CollectError as error:
            framework = missing_framework(error.__cause__)
            if framework is None:
                raise
            reason = f"needs {framework}, not installed (import {error.__cause__.name}); pip install 'diffblur[{framework}]'"
            raise pytest.skip.Exception(reason, allow_module_level=True) from None


def pytest_pycollect_makemodule(module_path, parent):
    return FrameworkModule.from_parent(parent, path=module_path)
