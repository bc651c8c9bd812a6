"""The tile options of gather_blur and reconstruct in both backends: tiled adaptive sampling (seed
001) with the still-tile early-out, and the pyramid for large motion. Outputs and gradients against
NumPy are in the equivalence harness (cases_tiles.py); here, what the options promise."""

from __future__ import annotations

import numpy as np
import pytest

from diffblur.ops.adaptive import adaptive_classes, class_pixels, tile_sample_counts
from tests.backends import backend  # noqa: F401


def test_adaptive_classes():
    assert adaptive_classes(False, 15) is None
    assert adaptive_classes(True, 15) == (3, 7, 15)
    assert adaptive_classes(True, 31) == (3, 7, 15, 31)
    assert adaptive_classes(True, 9) == (3, 7, 9)
    assert adaptive_classes(True, 1) == (1,)
    assert adaptive_classes((5, 3), 15) == (3, 5, 15)
    assert adaptive_classes([15], 15) == (15,)


def test_tile_counts_and_class_pixels_by_hand():
    # speeds: still, just moving, 1.5 (2r = 3 -> 3 taps), 1.6 (-> 7), 3.5 (-> 7), 3.6 (-> 15), 40 (-> 15)
    speed = np.array([[[0.0, 0.002, 1.5, 1.6, 3.5, 3.6, 40.0]]])
    np.testing.assert_array_equal(tile_sample_counts(speed, (3, 7, 15), 1e-3, np), [[[0, 3, 3, 7, 7, 15, 15]]])
    np.testing.assert_array_equal(tile_sample_counts(speed, (3, 7, 15), 0.501, np), [[[0, 0, 3, 7, 7, 15, 15]]])
    counts = np.array([[[3, 0], [0, 3]], [[0, 0], [3, 0]]])  # (B=2, 2 x 2 tiles of 2 px) on 3 x 4 images
    # image 0: tile (0, 0) rows 0-1 cols 0-1; tile (1, 1) row 2 (partial) cols 2-3. image 1: tile (1, 0) row 2 cols 0-1.
    expected = [0, 1, 4, 5, 10, 11, 12 + 8, 12 + 9]
    np.testing.assert_array_equal(class_pixels(counts, 3, 2, 3, 4), expected)


def _scene(rng, height=40, width=40, batch=2):
    """Tiles of 16 px (gather) and 5 px (reconstruct, max_radius 5): a fast block, a slow block, the rest still."""
    velocity = np.zeros((batch, 2, height, width))
    velocity[:, 0, 2:12, 2:12] = 4.0 + rng.random((batch, 10, 10))  # fast: 15 taps
    velocity[:, 1, 2:12, 2:12] = rng.normal(size=(batch, 10, 10))
    velocity[:, 0, 33:38, 20:30] = 1.2  # slow: 3 taps
    depth = rng.uniform(1.0, 2.0, size=(batch, 1, height, width))
    return rng.random((batch, 3, height, width)), velocity, depth


def _pixel_map(counts, tile, height, width):
    return np.repeat(np.repeat(counts, tile, axis=1), tile, axis=2)[:, None, :height, :width]


@pytest.mark.parametrize("op", ["gather_blur", "reconstruct"])
def test_adaptive_equals_the_filter_of_each_tiles_class(backend, op):
    """Still tiles return the image (and so does the full-rate filter there), full-rate tiles get the
    full-rate result, and a 3-tap tile gets the 3-sample filter's result."""
    rng = np.random.default_rng(21)
    color, velocity, depth = _scene(rng)
    arrays = [backend.array(a) for a in (color, velocity, depth)]
    if op == "gather_blur":
        run = lambda **o: backend.numpy(backend.ops.gather_blur(*arrays[:2], **o))  # noqa: E731
        tile = 16
    else:
        run = lambda **o: backend.numpy(backend.ops.reconstruct(*arrays, max_radius=5.0, **o))  # noqa: E731
        tile = 5
    adaptive = run(samples=15, adaptive=True)
    full, three = run(samples=15), run(samples=3)
    from diffblur import reference

    tiles = reference.tile_max(velocity, tile)
    if op == "reconstruct":
        tiles = reference.neighbor_max(tiles)
    counts = tile_sample_counts(np.hypot(tiles[:, 0], tiles[:, 1]), (3, 7, 15), 1e-3, np)
    assert {0, 3, 15} <= set(np.unique(counts)), "the scene must have still, 3-tap and full-rate tiles"
    pixels = np.broadcast_to(_pixel_map(counts, tile, 40, 40), color.shape)
    np.testing.assert_allclose(adaptive[pixels == 0], color[pixels == 0], rtol=0, atol=0)
    np.testing.assert_allclose(full[pixels == 0], color[pixels == 0], atol=1e-12)
    np.testing.assert_allclose(adaptive[pixels == 15], full[pixels == 15], atol=1e-12)
    np.testing.assert_allclose(adaptive[pixels == 3], three[pixels == 3], atol=1e-12)
    assert np.abs(adaptive[pixels == 15] - color[pixels == 15]).max() > 0.05


def test_adaptive_gradients_equal_the_full_rate_ones_but_for_the_still_switch(backend):
    """With only full-rate and still tiles: the same gradients for color and depth everywhere, and for
    the velocity of the moving pixels. Still tiles return the image, so a still pixel's velocity gets
    no gradient of its own there (the full-rate filter's jittered taps give it one): the switch that
    makes still tiles cost nothing."""
    rng = np.random.default_rng(22)
    color, velocity, depth = _scene(rng, height=30, width=30, batch=1)  # no 3-tap tiles (the slow block is outside)
    arrays = [backend.array(a) for a in (color, velocity, depth)]
    full = backend.grad(lambda c, v, d: backend.ops.reconstruct(c, v, d, max_radius=5.0, samples=7) ** 2, *arrays)
    adaptive = backend.grad(lambda c, v, d: backend.ops.reconstruct(c, v, d, max_radius=5.0, samples=7, adaptive=(7,)) ** 2, *arrays)
    np.testing.assert_allclose(adaptive[0], full[0], atol=1e-10)
    np.testing.assert_allclose(adaptive[2], full[2], atol=1e-10)
    np.testing.assert_allclose(adaptive[1][..., 2:12, 2:12], full[1][..., 2:12, 2:12], atol=1e-10)
    assert np.abs(adaptive[1][..., 2:12, 2:12]).max() > 1e-3


def test_adaptive_under_torch_compile_equals_eager():
    """Under torch.compile the classes cannot size tensors: every class runs on every pixel and the
    result is selected per tile; one graph (fullgraph), the same values and gradients as eager."""
    import torch

    import torch_impl

    rng = np.random.default_rng(23)
    color, velocity, _ = _scene(rng, height=20, width=36, batch=1)

    def run(c, v):
        return torch_impl.gather_blur(c, v, samples=7, adaptive=True)

    results = []
    torch._dynamo.reset()
    for fn in (run, torch.compile(run, backend="aot_eager", fullgraph=True, dynamic=False)):
        c, v = (torch.tensor(a, dtype=torch.float32, requires_grad=True) for a in (color, velocity))
        out = fn(c, v)
        (out * out).sum().backward()
        results.append((out.detach().numpy(), c.grad.numpy(), v.grad.numpy()))
    for compiled, eager in zip(results[1], results[0]):
        np.testing.assert_allclose(compiled, eager, atol=1e-5, rtol=1e-5)


def _gather(o, b, **options):
    return o.gather_blur(b.array(np.ones((1, 3, 4, 4))), b.array(np.ones((1, 2, 4, 4))), **options)


def _reconstruct(o, b, **options):
    return o.reconstruct(b.array(np.ones((1, 3, 4, 4))), b.array(np.ones((1, 2, 4, 4))), b.array(np.ones((1, 1, 4, 4))), **options)


BAD_CALLS = [
    ("gather adaptive even", lambda o, b: _gather(o, b, samples=15, adaptive=(4, 7)), ValueError, r"adaptive classes must be odd integers in \[1, samples=15\], got \(4, 7\)"),
    ("gather adaptive above samples", lambda o, b: _gather(o, b, samples=7, adaptive=(3, 9)), ValueError, r"adaptive classes must be odd integers in \[1, samples=7\]"),
    ("gather adaptive string", lambda o, b: _gather(o, b, adaptive="yes"), TypeError, r"adaptive must be a bool or a non-empty sequence of odd sample counts, got 'yes'"),
    ("reconstruct adaptive empty", lambda o, b: _reconstruct(o, b, adaptive=()), TypeError, r"adaptive must be a bool or a non-empty sequence"),
    ("reconstruct adaptive float", lambda o, b: _reconstruct(o, b, adaptive=(3.0,)), ValueError, r"adaptive classes must be odd integers"),
]


@pytest.mark.parametrize("call, error, pattern", [c[1:] for c in BAD_CALLS], ids=[c[0] for c in BAD_CALLS])
def test_bad_input(backend, call, error, pattern):
    with pytest.raises(error, match=pattern):
        call(backend.ops, backend)


def test_pyramid_levels_by_hand():
    from diffblur.ops.pyramid import level_of_detail, level_sizes, numpy_levels

    assert level_sizes(5, 3) == [(5, 3), (3, 2), (2, 1), (1, 1)]
    image = np.arange(9.0).reshape(1, 3, 3)
    levels = numpy_levels(image)
    # level 1: 2 x 2 blocks of [[0 1 2 2] [3 4 5 5] [6 7 8 8] [6 7 8 8]] (last row and column repeated)
    np.testing.assert_allclose(levels[1][0], [[2.0, 3.5], [6.5, 8.0]])
    np.testing.assert_allclose(levels[2][0], [[5.0]])
    np.testing.assert_allclose(level_of_detail(np.array([0.5, 1.0, 2.0, 4.0, 1e6]), 3, np), [0.0, 0.0, 1.0, 2.0, 2.0])


@pytest.mark.parametrize("op", ["gather_blur", "reconstruct"])
def test_pyramid_changes_nothing_where_taps_are_a_pixel_apart(backend, op):
    rng = np.random.default_rng(24)
    color = backend.array(rng.random((1, 3, 12, 13)))
    velocity = backend.array(rng.normal(size=(1, 2, 12, 13)) * 1.2)  # |V| <= ~4: 2 |V| / 15 < 1
    depth = backend.array(rng.uniform(1.0, 2.0, size=(1, 1, 12, 13)))
    args = (color, velocity) if op == "gather_blur" else (color, velocity, depth)
    run = getattr(backend.ops, op)
    # The pyramid runs on the tensor ops: compare with them, not with the fused kernel (same value,
    # other rounding).
    # XLA may round the two graphs' sums differently (1 ulp with its older CPU emitters).
    np.testing.assert_allclose(backend.numpy(run(*args, samples=15, sampling="pyramid")), backend.numpy(run(*args, samples=15, impl="tensor")), rtol=0, atol=1e-14)


@pytest.mark.parametrize("op", ["gather_blur", "reconstruct"])
def test_pyramid_smooths_fewer_taps_than_pixels_travelled(backend, op):
    """Stripes of period 2 px under a long motion with 5 samples whose taps land 4 px apart (gather:
    V = 10, taps at 0, +-4, +-8 px; reconstruct: V = 12, taps at +-4, +-8 px): point taps all read
    stripes of the pixel's own parity and the stripes survive; pyramid taps read level 2 (averaged
    over 4 px) and give the true streak, the stripes averaged to 0.5 (the 63-tap gather)."""
    speed = 10.0 if op == "gather_blur" else 12.0
    color = np.zeros((1, 1, 8, 64))
    color[..., ::2] = 1.0
    velocity = np.zeros((1, 2, 8, 64))
    velocity[:, 0] = speed
    depth = np.ones((1, 1, 8, 64))
    arrays = [backend.array(a) for a in (color, velocity, depth)]
    run = getattr(backend.ops, op)
    args = arrays[:2] if op == "gather_blur" else arrays
    options = {} if op == "gather_blur" else {"max_radius": speed, "jitter": "none"}
    truth = backend.numpy(backend.ops.gather_blur(*arrays[:2], samples=63))[..., 16:48]
    np.testing.assert_allclose(truth, 0.5, atol=0.02)
    point = backend.numpy(run(*args, samples=5, **options))[..., 16:48]
    pyramid = backend.numpy(run(*args, samples=5, sampling="pyramid", **options))[..., 16:48]
    point_error, pyramid_error = np.abs(point - truth).max(), np.abs(pyramid - truth).max()
    assert point_error > 0.4, "the point taps should alias on this scene"
    assert pyramid_error < 0.05


def test_pyramid_gradient_reaches_the_velocity_through_the_level(backend):
    """Where the level of detail is fractional, moving |V| changes the blend of two levels: the
    velocity's gradient is nonzero even on a uniform translation, where the tap positions alone
    would read a linear ramp image the same way along x."""
    ramp = np.tile(np.linspace(0.0, 1.0, 32) ** 2, (1, 1, 8, 1))
    velocity = np.zeros((1, 2, 8, 32))
    velocity[:, 1] = 6.0  # vertical motion over an image constant along y: only the level blend changes it
    grads = backend.grad(lambda c, v: backend.ops.gather_blur(c, v, samples=5, sampling="pyramid"), backend.array(ramp), backend.array(velocity))
    assert np.all(np.isfinite(grads[1]))
    assert np.abs(grads[1][:, 1]).max() > 1e-4


PYRAMID_BAD_CALLS = [
    ("gather unknown sampling", lambda o, b: _gather(o, b, sampling="pyramids"), ValueError, r"sampling must be one of 'bilinear', 'nearest', 'pyramid'"),
    ("gather pyramid with adaptive", lambda o, b: _gather(o, b, sampling="pyramid", adaptive=True), ValueError, r"sampling='pyramid' does not combine with adaptive sampling yet; got adaptive=True"),
    ("reconstruct pyramid with adaptive", lambda o, b: _reconstruct(o, b, sampling="pyramid", adaptive=True), ValueError, r"sampling='pyramid' does not combine with adaptive sampling yet; got adaptive=True"),
]


@pytest.mark.parametrize("call, error, pattern", [c[1:] for c in PYRAMID_BAD_CALLS], ids=[c[0] for c in PYRAMID_BAD_CALLS])
def test_pyramid_bad_input(backend, call, error, pattern):
    with pytest.raises(error, match=pattern):
        call(backend.ops, backend)
