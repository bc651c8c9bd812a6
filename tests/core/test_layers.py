"""The layers of `diffblur`, read off every module's imports with `ast` (imports inside functions,
`importlib.import_module("...")` and `__import__("...")` with a constant name count too).

The rule enforced, by where a module lives under diffblur/:

- app (`diffblur/app/`, and `diffblur/__main__.py`, the `python -m diffblur` entry point that only
  calls app's `main`): may import anything: a backend, a framework, `fitting`.
- every other module (core, kernels, scenes) imports no framework or backend: none of `torch`,
  `jax`, `equinox`, their ecosystems (`kornia`, `optax`, `optimistix`, `jaxtyping`), `torch_impl`,
  `jax_impl`, `fitting`.
- kernels (`diffblur/kernels/`): import the core only, never `diffblur.scenes` or `diffblur.app`.
- scenes (`diffblur/scenes/`): import the core only, never `diffblur.kernels` or `diffblur.app`.
- core (the top level and `diffblur/reference/`): imports none of `diffblur.scenes`, `diffblur.app`,
  `diffblur.kernels`, except the (module, import) pairs of `CORE_USES_KERNELS`, for a dispatch
  that genuinely needs a kernel. It is empty: the dispatch to the kernels lives in the backends
  (`torch_impl/_fused*.py`, `jax_impl/_fused*.py`).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

FRAMEWORKS = ("torch", "jax", "jaxlib", "equinox", "kornia", "optax", "optimistix", "jaxtyping", "torch_impl", "jax_impl", "fitting")
FORBIDDEN = {
    "core": FRAMEWORKS + ("diffblur.scenes", "diffblur.app", "diffblur.kernels"),
    "kernels": FRAMEWORKS + ("diffblur.scenes", "diffblur.app"),
    "scenes": FRAMEWORKS + ("diffblur.kernels", "diffblur.app"),
    "app": (),
}
#: (module, imported module) pairs of the core allowed to reach a kernel: none today.
CORE_USES_KERNELS: set[tuple[str, str]] = set()


def layer_of(relative: Path) -> str:
    """The layer of a module, from its path relative to the package (diffblur/)."""
    if relative.parts[0] in ("app", "kernels", "scenes"):
        return relative.parts[0]
    if relative.as_posix() == "__main__.py":
        return "app"
    return "core"


def module_name(relative: Path) -> str:
    parts = ["diffblur", *relative.with_suffix("").parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported_names(source: str, name: str, is_package: bool = False) -> set[str]:
    """Every module that the source of module `name` may import: `import a.b` gives a.b; `from a
    import b` gives a and a.b (b may be a submodule); relative imports are resolved."""
    package = name if is_package else name.rpartition(".")[0]
    names = set()
    for node in ast.walk(ast.parse(source, name)):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join([*anchor, base] if base else anchor)
            names.add(base)
            names.update(f"{base}.{alias.name}" for alias in node.names)
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str):
            function = node.func
            called = function.attr if isinstance(function, ast.Attribute) else getattr(function, "id", "")
            if called in ("import_module", "__import__"):
                names.add(node.args[0].value)
    return names


def violations(package: Path) -> list[str]:
    """The imports of the modules under `package` (a diffblur/ folder) that break the layers."""
    found = []
    for path in sorted(package.rglob("*.py")):
        relative = path.relative_to(package)
        name, layer = module_name(relative), layer_of(relative)
        for imported in sorted(imported_names(path.read_text(), name, path.name == "__init__.py")):
            for banned in FORBIDDEN[layer]:
                if imported == banned or imported.startswith(banned + "."):
                    if layer == "core" and (name, imported) in CORE_USES_KERNELS:
                        continue
                    found.append(f"{relative.as_posix()} ({layer}) imports {imported}")
    return found


def test_every_layer_imports_only_what_it_may():
    assert violations(ROOT / "diffblur") == []


def test_the_reader_sees_imports_inside_functions():
    """The check is not vacuous: app's lazy imports of the frameworks are found, and a module that
    imported one inside a function would be caught."""
    bench = (ROOT / "diffblur" / "app" / "bench.py").read_text()
    assert {"torch", "jax", "torch_impl", "jax_impl"} <= imported_names(bench, "diffblur.app.bench")
    source = "def f():\n    import jax.numpy as jnp\n    from ..app import cli\n    return __import__('torch')\n"
    assert {"jax.numpy", "diffblur.app", "diffblur.app.cli", "torch"} <= imported_names(source, "diffblur.kernels.x")


@pytest.mark.parametrize("layer", ["core", "kernels", "scenes", "app"])
def test_every_layer_has_modules(layer):
    modules = [p for p in (ROOT / "diffblur").rglob("*.py") if layer_of(p.relative_to(ROOT / "diffblur")) == layer]
    assert len(modules) >= 3, layer
