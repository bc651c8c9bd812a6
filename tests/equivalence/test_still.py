""""Still" means "moves at most `diffblur.conventions.STILL_SPEED` px", never "exactly zero".

A renderer's offsets carry float leftovers (1e-6 px) on static surfaces; with them the scatter must
give the result of exact zeros (its fill="still" needs the still pixels), in the NumPy reference and
both backends, on the tensor ops and the fused kernel. fill="still" warns, eagerly and once per
process, when an image has no still pixel (it then fills as fill="color").
"""

from __future__ import annotations

import warnings

import jax
import numpy as np
import pytest

from diffblur import conventions, reference
from diffblur.ops import scatter as scatter_options
from diffblur.scenes import preset_scene, render_buffers
from tests.backends import BACKENDS, backend_params

LEFTOVER = 1e-6


@pytest.fixture(scope="module")
def propeller():
    """A spinning propeller before a still background (48 x 48, box shutter), and its offsets with
    uniform leftovers in [-1e-6, 1e-6] px added everywhere (seeded)."""
    buffers = render_buffers(preset_scene("propeller", height=48, width=48), shutter="box")
    rng = np.random.default_rng(21)
    leftovers = [o + rng.uniform(-LEFTOVER, LEFTOVER, o.shape) for o in (buffers.offset_prev, buffers.offset_next)]
    return buffers, leftovers


@pytest.mark.parametrize("impl", ["tensor", "auto"], ids=["tensor_ops", "fused_where_it_applies"])
@pytest.mark.parametrize("backend", backend_params())
def test_scatter_leftovers_give_the_result_of_exact_zeros(backend, impl, propeller):
    buffers, (prev, nxt) = propeller
    a = backend.array
    still = (buffers.offset_prev == 0).all(1) & (buffers.offset_next == 0).all(1)
    assert 0.5 < still.mean() < 1.0  # the scene has still pixels, and moving ones
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)  # still pixels are found: no warning
        exact = backend.numpy(backend.ops.bezier_scatter(a(buffers.color), a(buffers.depth), a(buffers.offset_prev), a(buffers.offset_next), shutter="box", impl=impl))
        rounded = backend.numpy(backend.ops.bezier_scatter(a(buffers.color), a(buffers.depth), a(prev), a(nxt), shutter="box", impl=impl))
    # Counting the leftovers as motion loses the still pixels' fill: 0.33 of the contrast, 6 dB.
    np.testing.assert_allclose(rounded, exact, atol=1e-5)


def test_reference_and_arc_leftovers_are_still():
    """The NumPy reference, on a 1 x 5 line: a bright pixel moving 1 px each way over a still row whose
    offsets carry leftovers; and an arc whose still pixels turn by a leftover angle."""
    color = np.array([[[[0.2, 0.4, 1.0, 0.6, 0.8]]]])
    depth = np.ones((1, 1, 1, 5))
    offset = np.zeros((1, 2, 1, 5))
    offset[0, 0, 0, 2] = 1.0
    leftovers = np.full_like(offset, LEFTOVER)
    leftovers[0, 0, 0, 2] = 1.0
    exact = reference.bezier_scatter(color, depth, -offset, offset, samples=3, shutter="box")
    rounded = reference.bezier_scatter(color, depth, -leftovers, leftovers, samples=3, shutter="box")
    np.testing.assert_allclose(rounded, exact, atol=1e-5)
    # The bright pixel's uncovered third is filled from its still neighbours (0.4 and 0.6), not itself.
    assert exact[0, 0, 0, 2] < 0.95

    center = np.broadcast_to(np.array([2.0, 0.0]).reshape(1, 2, 1, 1), (1, 2, 1, 5)).copy()
    angle = np.zeros((1, 1, 1, 5))
    angle[0, 0, 0, 4] = 0.5
    exact = reference.bezier_scatter(color, depth, None, None, arc_center=center, arc_angle=angle, samples=3, shutter="box")
    angle[0, 0, 0, :4] = LEFTOVER
    rounded = reference.bezier_scatter(color, depth, None, None, arc_center=center, arc_angle=angle, samples=3, shutter="box")
    np.testing.assert_allclose(rounded, exact, atol=1e-5)


def test_moving_mask_threshold_is_the_convention():
    """Offsets just below STILL_SPEED are still, just above move, in both backends."""
    limit = conventions.STILL_SPEED
    for backend in BACKENDS:
        color = backend.array(np.array([[[[0.0, 1.0, 0.0, 0.5]]]]))
        depth = backend.array(np.ones((1, 1, 1, 4)))
        for scale, changed in ((0.99, False), (1.01, True)):
            offset = np.zeros((1, 2, 1, 4))
            offset[0, 0, 0, 1] = limit * scale
            out = backend.numpy(backend.ops.bezier_scatter(color, depth, backend.array(-offset), backend.array(offset), samples=3, shutter="box", fill=color * 0.0))
            # A moving pixel shows the (black) background for the time its splats leave it uncovered.
            assert (abs(out[0, 0, 0, 1] - 1.0) > 1e-9) == changed, (backend.name, scale)


@pytest.fixture
def fresh_warning(monkeypatch):
    """The no-still-pixel warning comes once per process: let this test see it again."""
    monkeypatch.setattr(scatter_options, "_warned_without_still", False)


@pytest.mark.parametrize("backend", backend_params())
def test_fill_still_warns_without_still_pixels(backend, fresh_warning):
    rng = np.random.default_rng(3)
    color = backend.array(rng.uniform(size=(2, 1, 6, 6)))
    depth = backend.array(np.ones((2, 1, 6, 6)))
    offset = np.zeros((2, 2, 6, 6))
    offset[1, 0] = 0.7  # image 1 moves everywhere; image 0 is still
    offset = backend.array(offset)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        # Still pixels, fill="color", a background, or traced arrays: nothing to warn about.
        warnings.simplefilter("error", UserWarning)
        backend.ops.bezier_scatter(color, depth, -offset, offset, samples=3, fill="color")
        backend.ops.bezier_scatter(color, depth, -offset, offset, samples=3, fill=color)
        backend.ops.bezier_scatter(color[:1], depth[:1], -offset[:1], offset[:1], samples=3)
        if backend.name == "jax":  # traced: no value to look at, no warning
            jax.jit(lambda c, d, o: backend.ops.bezier_scatter(c, d, -o, o, samples=3))(color, depth, offset)
    with pytest.warns(UserWarning, match=r"no still pixel .* in image\(s\) \[1\]"):
        backend.ops.bezier_scatter(color, depth, -offset, offset, samples=3)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)  # once per process: a fit does not repeat it
        backend.ops.bezier_scatter(color, depth, -offset, offset, samples=3)


def test_reference_warns_without_still_pixels(fresh_warning):
    offset = np.full((1, 2, 3, 3), 0.5)
    with pytest.warns(UserWarning, match="no still pixel"):
        reference.bezier_scatter(np.ones((1, 1, 3, 3)), np.ones((1, 1, 3, 3)), -offset, offset, samples=3)
