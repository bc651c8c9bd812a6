"""Fixtures for every test module (the `backend` fixture), and one-framework installs: a test module
that imports a framework that is not installed is skipped, naming it, instead of failing to collect.
An install with only the torch extra (or only jax) so runs the core tests and that framework's."""

from __future__ import annotations

import pytest

from tests.backends import INSTALLED, backend  # noqa: F401  (the fixture, for every test module)

#: Top-level modules that come with each framework's extra.
FRAMEWORK_OF = {"torch": "torch", "kornia": "torch", "jax": "jax", "jaxlib": "jax", "equinox": "jax", "optax": "jax", "optimistix": "jax"}


def missing_framework(error: BaseException | None) -> str | None:
    """The framework whose absence raised `error` (a ModuleNotFoundError, or an error raised while
    handling one), or None."""
    seen = set()
    while error is not None and id(error) not in seen:
        seen.add(id(error))
        if isinstance(error, ModuleNotFoundError) and error.name:
            framework = FRAMEWORK_OF.get(error.name.split(".")[0])
            if framework is not None and not INSTALLED[framework]:
                return framework
        error = error.__cause__ or error.__context__
    return None


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    """A test that fails only because it imports (itself, or through an op or `fitting`) a
    framework that is not installed is reported as skipped, with the reason, as
    pytest.importorskip would; with both frameworks installed nothing changes."""
    report = yield
    if report.failed and call.excinfo is not None:
        framework = missing_framework(call.excinfo.value)
        if framework is not None:
            report.outcome = "skipped"
            reason = f"needs {framework}, not installed; pip install 'diffblur[{framework}]'"
            report.longrepr = (str(item.path), item.location[1] or 0, f"Skipped: {reason}")
    return report


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
