"""The public surface: the same names and signatures in both backends, keyword-only options,
imports that stay within their framework, and shape annotations that hold at run time."""

from __future__ import annotations

import inspect
import pkgutil
import subprocess
import sys

import numpy as np
import pytest
from beartype import beartype
from jaxtyping import jaxtyped

import diffblur
import jax_impl
import torch_impl

PUBLIC = sorted(torch_impl.__all__)


def test_backends_export_the_same_names():
    assert sorted(torch_impl.__all__) == sorted(jax_impl.__all__)
    for name in PUBLIC:
        assert callable(getattr(torch_impl, name)) and callable(getattr(jax_impl, name))


@pytest.mark.parametrize("name", PUBLIC)
def test_same_signature_in_both_backends(name):
    torch_sig = inspect.signature(getattr(torch_impl, name))
    jax_sig = inspect.signature(getattr(jax_impl, name))
    assert [(p.name, p.kind, p.default) for p in torch_sig.parameters.values()] == [
        (p.name, p.kind, p.default) for p in jax_sig.parameters.values()
    ]


@pytest.mark.parametrize("name", PUBLIC)
def test_options_are_keyword_only(name):
    """Every parameter with a default is an option, and options are keyword-only (dm-pix's rule);
    a module's first argument, the method it runs, may be positional: MotionBlur("gather")."""
    for backend in (torch_impl, jax_impl):
        params = list(inspect.signature(getattr(backend, name)).parameters.values())
        if inspect.isclass(getattr(backend, name)):
            assert params[0].name == "method"
            params = params[1:]
        for param in params:
            if param.default is not inspect.Parameter.empty and param.kind is not inspect.Parameter.VAR_KEYWORD:
                assert param.kind is inspect.Parameter.KEYWORD_ONLY, f"{backend.__name__}.{name}({param.name}=...)"


@pytest.mark.parametrize("name", PUBLIC)
def test_every_public_op_is_documented(name):
    for backend in (torch_impl, jax_impl):
        doc = inspect.getdoc(getattr(backend, name))
        assert doc and len(doc.splitlines()) >= 2, f"{backend.__name__}.{name} needs a docstring"


def _imported_modules(statement: str) -> set[str]:
    code = f"import sys; {statement}; print(' '.join(sorted(m.split('.')[0] for m in sys.modules)))"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return set(result.stdout.split())


def test_core_imports_neither_framework():
    submodules = [m.name for m in pkgutil.walk_packages(diffblur.__path__, "diffblur.") if m.name != "diffblur.__main__"]
    loaded = _imported_modules("; ".join(f"import {m}" for m in ["diffblur", *submodules]))
    assert "torch" not in loaded and "jax" not in loaded


def test_torch_backend_does_not_import_jax():
    loaded = _imported_modules("import torch_impl")
    assert "torch" in loaded and "jax" not in loaded


def test_jax_backend_does_not_import_torch():
    loaded = _imported_modules("import jax_impl")
    assert "jax" in loaded and "torch" not in loaded


def _checked_layer_call(layer, *args):
    """Call a layer's forward (torch) or __call__ (Equinox) under the annotation checker."""
    method = layer.forward if hasattr(layer, "forward") else layer.__call__
    return jaxtyped(typechecker=beartype)(method)(*args)


def _valid_calls(backend):
    rng = np.random.default_rng(0)
    image = lambda c: backend.array(rng.normal(size=(2, c, 9, 10)))  # noqa: E731
    ops = backend.ops
    return {
        "soft_depth_compare": lambda f: f(image(1), image(1), 0.5),
        "cone": lambda f: f(image(1), image(1)),
        "cylinder": lambda f: f(image(1), image(1)),
        "safe_length": lambda f: f(image(2)),
        "velocity_from_motion": lambda f: f(image(2), exposure=0.5),
        "tile_max": lambda f: f(image(2), 4),
        "neighbor_max": lambda f: f(ops.tile_max(image(2), 4)),
        "interleaved_gradient_noise": lambda f: f(9, 10),
        "gather_blur": lambda f: f(image(3), image(2), samples=3),
        "MotionBlur": lambda f: _checked_layer_call(f("reconstruct", samples=3, max_radius=4.0), image(3), image(2), abs(image(1)) + 1.0),
        "reconstruct": lambda f: f(image(3), image(2), abs(image(1)) + 1.0, samples=3, max_radius=4.0),
        "bezier_scatter": lambda f: f(image(3), abs(image(1)) + 1.0, image(2), image(2), samples=3),
        "accumulate_warps": lambda f: f(image(3), image(2), instants=3),
        "warp_blend": lambda f: f(image(3), image(2), iterations=2),
        "velocity_from_motion_ids": lambda f: f(backend.array(rng.integers(0, 3, size=(2, 1, 9, 10)), "int64"), backend.array(rng.normal(size=(2, 3, 2)))),
    }


def test_shape_annotations_hold_at_run_time(backend):
    """Each op, wrapped in jaxtyping's checker with beartype, accepts valid input and returns the
    annotated shape (e.g. tile_max's "b 2 th tw", safe_length's "b 1 h w")."""
    calls = _valid_calls(backend)
    assert sorted(calls) == PUBLIC
    for name, call in calls.items():
        # Some public ops are wrapped (unknown keywords listed, JAX's forward-mode hint) over the annotated function.
        op = inspect.unwrap(getattr(backend.ops, name))
        call(op if inspect.isclass(op) else jaxtyped(typechecker=beartype)(op))


def test_the_annotation_checker_is_live(backend):
    """Guard for the test above: a call that breaks an op's annotation must be caught, or that test
    proves nothing. safe_length accepts any rank itself but is annotated for (b, c, h, w)."""
    from jaxtyping import TypeCheckError

    checked = jaxtyped(typechecker=beartype)(inspect.unwrap(backend.ops.safe_length))
    with pytest.raises(TypeCheckError):
        checked(backend.array(np.ones((2, 3, 3))), axis=0)
