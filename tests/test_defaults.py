"""Defaults that hold across the ops: one shutter (`diffblur.conventions.DEFAULT_SHUTTER`), so that
two ops called with defaults blur a scene as the same camera would.
"""

from __future__ import annotations

import inspect

import numpy as np
import pytest

import jax_impl
import torch_impl
from diffblur import conventions, reference
from tests.backends import BACKENDS, backend_params

OPS_WITH_SHUTTER = ["gather_blur", "reconstruct", "bezier_scatter", "accumulate_warps"]  # warp_blend has none


@pytest.mark.parametrize("name", OPS_WITH_SHUTTER)
@pytest.mark.parametrize("module", [torch_impl, jax_impl, reference], ids=["torch", "jax", "reference"])
def test_every_op_defaults_to_the_one_shutter(module, name):
    parameters = inspect.signature(getattr(module, name)).parameters
    assert parameters["shutter"].default == conventions.DEFAULT_SHUTTER


@pytest.mark.parametrize("backend", backend_params())
def test_scatter_and_gather_blur_a_translation_alike_with_defaults(backend):
    """A uniform translation, every pixel moving 3 px each way: the degree-1 scatter and the gather,
    each with its defaults and 15 points/taps, are the same camera: the same image (to rounding), where
    a Gaussian scatter against the box gather differs by 0.04 on average."""
    rng = np.random.default_rng(4)
    color = rng.uniform(size=(1, 1, 24, 24))
    velocity = np.zeros((1, 2, 24, 24))
    velocity[:, 0] = 3.0
    a = backend.array
    gather = backend.numpy(backend.ops.gather_blur(a(color), a(velocity), samples=15))[..., 6:-6, 6:-6]
    scatter = lambda **kw: backend.numpy(  # noqa: E731
        backend.ops.bezier_scatter(a(color), a(np.ones((1, 1, 24, 24))), a(-velocity), a(velocity), degree=1, samples=15, fill="color", **kw)
    )[..., 6:-6, 6:-6]
    same = np.abs(scatter() - gather).mean()
    other = np.abs(scatter(shutter="gaussian") - gather).mean()
    assert same < 1e-6 and other > 0.01, (same, other)


def _tilted_scene():
    """16 x 16: a tilted floor (depth 5 to 2 down the rows) sliding 2 px down but for its last 4 rows,
    its splats landing on
    nearer and farther parts of itself, with a box at depth 1.5 moving 3 px right over it; offsets
    as for a translation; depth in arbitrary units."""
    rng = np.random.default_rng(8)
    color = rng.uniform(size=(1, 3, 16, 16))
    depth = np.broadcast_to(np.linspace(5.0, 2.0, 16)[:, None], (1, 1, 16, 16)).copy()
    depth[..., 5:10, 4:9] = 1.5
    velocity = np.zeros((1, 2, 16, 16))
    velocity[:, 1, :12] = 2.0  # the last rows are still
    velocity[:, :, 5:10, 4:9] = np.array([3.0, 0.0])[:, None, None]
    return color, depth, velocity


def _depth_ops(module, a, tensor_ops: bool):
    """Every op that reads depth, with defaults (only the shutter named), on arrays made by `a`; also
    on the tensor ops if asked (JAX's compile for 16 x 16 takes seconds; the equivalence harness
    checks JAX's tensor ops against the reference with these defaults)."""
    ops = {
        "reconstruct": lambda c, z, v: module.reconstruct(a(c), a(v), a(z), shutter="box"),
        "bezier_scatter": lambda c, z, v: module.bezier_scatter(a(c), a(z), a(-v), a(v), shutter="box"),
    }
    if tensor_ops:
        ops["bezier_scatter_tensor_ops"] = lambda c, z, v: module.bezier_scatter(a(c), a(z), a(-v), a(v), shutter="box", impl="tensor")
        ops["reconstruct_tensor_ops"] = lambda c, z, v: module.reconstruct(a(c), a(v), a(z), shutter="box", impl="tensor")
    return ops


@pytest.mark.parametrize("scale", [0.01, 100.0])
@pytest.mark.parametrize("backend", backend_params())
def test_rescaling_depth_changes_no_output_with_defaults(backend, scale):
    """Depth in any units: multiplying it by 0.01 or 100 leaves every op's output unchanged (float64:
    to 1e-9). With the old band of 0.1 depth units the scatter changed by up to 0.2 here."""
    color, depth, velocity = _tilted_scene()
    for name, op in _depth_ops(backend.ops, backend.array, tensor_ops=backend.name == "torch").items():
        base = backend.numpy(op(color, depth, velocity))
        scaled = backend.numpy(op(color, depth * scale, velocity))
        np.testing.assert_allclose(scaled, base, atol=1e-9, err_msg=name)


def test_rescaling_depth_changes_no_reference_output():
    color, depth, velocity = _tilted_scene()
    color, depth, velocity = color[..., 4:16, :10], depth[..., 4:16, :10], velocity[..., 4:16, :10]
    for op in (
        lambda z: reference.reconstruct(color, velocity, z, samples=5, shutter="box"),
        lambda z: reference.bezier_scatter(color, z, -velocity, velocity, samples=4, shutter="box"),
    ):
        base = op(depth)
        for scale in (0.01, 100.0):
            np.testing.assert_allclose(op(depth * scale), base, atol=1e-9)


@pytest.mark.parametrize("backend", backend_params())
def test_an_absolute_band_stays_available(backend):
    """soft_z_extent in depth units still applies (and then depth's units matter)."""
    color, depth, velocity = _tilted_scene()
    a = backend.array
    absolute = lambda z: backend.numpy(backend.ops.bezier_scatter(a(color), a(z), a(-velocity), a(velocity), shutter="box", soft_z_extent=0.1))  # noqa: E731
    assert np.abs(absolute(depth * 0.01) - absolute(depth)).max() > 0.01
    relative = backend.numpy(backend.ops.bezier_scatter(a(color), a(depth), a(-velocity), a(velocity), shutter="box", relative_z_extent=0.05))
    # The relative band is the absolute band log(1 + r) on log depth.
    via_log = backend.numpy(backend.ops.bezier_scatter(a(color), a(np.log(depth) + 10.0), a(-velocity), a(velocity), shutter="box", soft_z_extent=float(np.log1p(0.05))))
    np.testing.assert_allclose(relative, via_log, atol=1e-9)


@pytest.mark.parametrize("backend", backend_params())
def test_bad_bands_are_refused(backend):
    color, depth, velocity = (backend.array(x) for x in _tilted_scene())
    for op in (
        lambda **kw: backend.ops.reconstruct(color, velocity, depth, **kw),
        lambda **kw: backend.ops.bezier_scatter(color, depth, -velocity, velocity, samples=3, **kw),
    ):
        with pytest.raises(ValueError, match=r"relative_z_extent must be > 0, got 0"):
            op(relative_z_extent=0.0)
        with pytest.raises(ValueError, match=r"soft_z_extent must be > 0, got -1"):
            op(soft_z_extent=-1.0)


def test_the_defaults_table_in_the_docs_matches_the_signatures():
    """docs/defaults.md lists each op's defaults; every row must be what the signatures say, in both
    backends, and every keyword default of the ops it covers must have a row."""
    import pathlib
    import re

    text = (pathlib.Path(__file__).resolve().parents[1] / "docs" / "defaults.md").read_text()
    rows = re.findall(r"^\| `(\w+)` \| `(\w+)` \| `([^`]+)` \|", text, flags=re.M)
    assert len(rows) > 20
    documented = {}
    for op, option, default in rows:
        documented[(op, option)] = eval(default)  # noqa: S307 - literals written in the docs
    for module in (torch_impl, jax_impl):
        for op in {op for op, _ in documented}:
            parameters = inspect.signature(getattr(module, op)).parameters
            for option, default in documented.items():
                if option[0] == op:
                    assert parameters[option[1]].default == default, (module.__name__, op, option[1])
            for name, p in parameters.items():
                if p.kind == p.KEYWORD_ONLY and p.default is not None and not callable(p.default):
                    assert (op, name) in documented or name == "shutter", (op, name)
    assert "| all that take one | `shutter` | `\"box\"` |" in text and conventions.DEFAULT_SHUTTER == "box"
