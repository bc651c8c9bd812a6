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
from tests.backends import BACKENDS

OPS_WITH_SHUTTER = ["gather_blur", "reconstruct", "bezier_scatter", "accumulate_warps"]  # warp_blend has none


@pytest.mark.parametrize("name", OPS_WITH_SHUTTER)
@pytest.mark.parametrize("module", [torch_impl, jax_impl, reference], ids=["torch", "jax", "reference"])
def test_every_op_defaults_to_the_one_shutter(module, name):
    parameters = inspect.signature(getattr(module, name)).parameters
    assert parameters["shutter"].default == conventions.DEFAULT_SHUTTER


@pytest.mark.parametrize("backend", BACKENDS, ids=lambda b: b.name)
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
