"""The layered scatter that `recover` fits through (`fitting._models.layered_scatter`): each depth layer
scattered alone and composited nearest first. It equals the plain scatter for one object over a still
background, puts the nearer object in front where two paths cross (the plain scatter averages them),
and gives the same image in both frameworks. JAX fits of one size compile once."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import fitting
from diffblur.reference._scatter import still_fill
from diffblur.scenes._textures import pad
from diffblur.shutters import LinearRamp, Trapezoid, get_shutter
from diffblur.scenes import Camera, ImageTexture, Layer, Scene, Static, Translation, checkers, photo, render_buffers
from fitting import _backends, _models
from fitting.scenes import layer_ids

SIZE = 40


def _scene(objects, shutter="box"):
    """A still photograph (depth 12) behind textured cards: (depth, velocity, top-left, side) each."""
    layers = [Layer(ImageTexture(photo("astronaut", SIZE + 8, SIZE + 8), origin=(-4, -4)), 12.0, Static(), "background")]
    for k, (depth, velocity, corner, side) in enumerate(objects):
        paint = checkers(side, side, 5.0 + 2 * k, (0.9, 0.3 * k, 0.1), (0.1, 0.2, 0.8 - 0.3 * k))
        layers.append(Layer(pad(paint, np.ones((side, side)), corner), depth, Translation(velocity), f"card {k}"))
    return render_buffers(Scene(SIZE, SIZE, tuple(layers)), shutter=shutter)


@pytest.fixture(scope="module")
def crossing():
    """Two cards whose paths cross: the nearer (depth 3) moving right over the farther (depth 5)
    moving left."""
    return _scene([(3.0, (5.0, 0.0), (8, 12), 11), (5.0, (-5.0, 1.0), (20, 15), 12)])


def _context(be, buffers, *, layered: bool, samples: int = 48):
    ids = layer_ids(buffers)
    options = {"method": "scatter", "samples": 9, "arc_samples": 16, "shutter": "box", "max_radius": 20.0, "jac": "bwd", "scatter_samples": samples}
    extras = {"weight": be.array(np.ones_like(buffers.depth)), "layers": _models.layer_stack(be, buffers.color, buffers.depth, ids) if layered else None}
    ctx = _models.Context(be, be.array(buffers.color), be.array(buffers.depth), be.array(buffers.target), SIZE, SIZE, 1.0, options, extras)
    return ctx, ids


def _per_layer(ctx, ids, buffers):
    """(L, 2, H, W) each layer's true velocity over the whole image, the nearest layer first."""
    velocity = buffers.velocity
    fields = [np.broadcast_to(velocity[:, :, ids[0, 0] == k][..., :1].reshape(1, 2, 1, 1), velocity.shape) for k in ctx.extras["layers"].ids]
    return ctx.be.array(np.concatenate(fields))


def test_push_pull_is_the_scatters_still_fill():
    rng = np.random.default_rng(3)
    for shape in ((1, 3, 13, 9), (2, 2, 16, 16), (1, 1, 1, 7)):
        color = rng.random(shape)
        known = (rng.random((shape[0], 1, *shape[2:])) < 0.3).astype(np.float64)
        np.testing.assert_allclose(_models.push_pull(color, known), still_fill(color, known), rtol=0, atol=1e-14)


@pytest.mark.parametrize("backend", ["torch", "jax"])
def test_one_object_over_a_still_background_is_the_plain_scatter(backend):
    buffers = _scene([(3.0, (4.0, 2.0), (12, 12), 14)])
    be = _backends.adapter(backend)
    plain, _ = _context(be, buffers, layered=False)
    layered, ids = _context(be, buffers, layered=True)
    expected = be.numpy(_models._blur(plain, be.array(buffers.velocity)))
    found = be.numpy(_models.layered_scatter(layered, _per_layer(layered, ids, buffers)))
    np.testing.assert_allclose(found, expected, rtol=0, atol=1e-12)


def test_the_nearer_object_stays_in_front_where_paths_cross(crossing):
    """With the true velocities, the layered scatter is closer to the rendered target than the
    plain scatter, which averages the two cards where they pass over each other (seed 003 has no
    depth write): there (rows 15-22, columns 15-24) by more than 1.5x, and over the whole image."""
    be = _backends.adapter("torch")
    plain, ids = _context(be, crossing, layered=False)
    layered, _ = _context(be, crossing, layered=True)
    errors = {}
    for name, ctx, motion in (("plain", plain, be.array(crossing.velocity)), ("layered", layered, _per_layer(layered, ids, crossing))):
        error = ((be.numpy(_models.render_batch(ctx, motion)) - crossing.target) ** 2).mean(axis=1)[0]
        errors[name] = (float(error[15:23, 15:25].mean()), float(error.mean()))
    assert errors["layered"][0] * 1.5 < errors["plain"][0], errors
    assert errors["layered"][1] < errors["plain"][1], errors


def test_pixels_two_moving_layers_share_are_left_out_of_the_residual():
    """Two cards whose paths sweep over common pixels, neither hiding the other at t = 0. With the
    true velocities the composite is the target to float rounding wherever at most one layer covers
    a pixel for part of the exposure; where both do, it assumes their coverings independent in time
    and misses by up to 0.1. `covered` trusts only the former."""
    buffers = _scene([(3.0, (6.0, 2.0), (6, 6), 12), (5.0, (-2.0, 5.0), (14, 20), 12)])
    be = _backends.adapter("torch")
    ctx, ids = _context(be, buffers, layered=True)
    motion = _per_layer(ctx, ids, buffers)
    error = np.abs(be.numpy(_models.layered_scatter(ctx, motion)) - buffers.target).max(axis=1)[0]
    trusted = _models.covered(ctx, motion)[0, 0] > 0
    assert (error > 0.05).sum() > 10, "the composite should miss where the cards' paths overlap"
    assert trusted.mean() > 0.6 and error[trusted].max() < 0.002, (trusted.mean(), error[trusted].max())


def test_torch_and_jax_layered_scatter_agree(crossing):
    images = {}
    for backend in ("torch", "jax"):
        be = _backends.adapter(backend)
        ctx, ids = _context(be, crossing, layered=True, samples=16)
        images[backend] = be.numpy(_models.layered_scatter(ctx, _per_layer(ctx, ids, crossing)))
    np.testing.assert_allclose(images["jax"], images["torch"], rtol=0, atol=1e-12)


@pytest.mark.slow
def test_jax_fits_of_one_size_compile_once(crossing):
    """A second fit of the same size and model options reuses every compiled function, whatever
    its shutter (a table of data to the compiled loss, `_models.TabulatedWindow`)."""
    import jax

    compiles = []

    def listen(event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            compiles.append(duration)

    # Other cards, places, directions and shutter, at the same speeds (the scatter's points per path
    # follow the speed, and they are a static option).
    shutter = Trapezoid(ramp=0.4)
    other = _scene([(3.0, (0.0, -5.0), (16, 18), 12), (5.0, (1.0, 5.0), (6, 8), 11)], shutter=shutter)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        fitting.recover(crossing.color, crossing.target, depth=crossing.depth, model=fitting.Exposure(velocity=crossing.velocity), backend="jax", levels=1)
        jax.monitoring.register_event_duration_secs_listener(listen)
        try:
            result = fitting.recover(other.color, other.target, depth=other.depth, model=fitting.Exposure(velocity=other.velocity), backend="jax", levels=1, shutter=shutter)
        finally:
            jax.monitoring.unregister_event_duration_listener(listen)
    assert compiles == [], compiles
    assert abs(result.params["exposure"] - 1.0) < 0.01, result.params


def test_select_model_picks_layers_for_two_crossing_objects(crossing):
    """With defaults: the smaller models (global, rotation, camera) do not pay, `layers` is tried
    although they used up select_model's patience, and it finds every layer within 0.25 px."""
    selection = fitting.select_model(crossing.color, crossing.target, depth=crossing.depth)
    assert selection.choice == "layers", selection.reason
    result = selection.fits["layers"]
    expected = {3.0: (5.0, 0.0), 5.0: (-5.0, 1.0), 12.0: (0.0, 0.0)}
    for depth, velocity in zip(result.params["depths"], result.params["palette"]):
        truth = np.array(expected[min(expected, key=lambda d: abs(d - depth))])
        assert min(np.abs(np.subtract(velocity, truth)).max(), np.abs(np.add(velocity, truth)).max()) < 0.25, result.params


def test_select_model_picks_camera_for_a_zoom():
    """A dolly towards a photograph: the image expands about its centre, which neither one velocity
    nor a rotation explains."""
    margin = 10
    background = Layer(ImageTexture(photo("coffee", SIZE + 2 * margin, SIZE + 2 * margin, zoom=1.5), origin=(-margin, -margin)), 12.0, Static(), "background")
    c = (SIZE - 1) / 2.0
    buffers = render_buffers(Scene(SIZE, SIZE, (background,), Camera(advance=2.0, center=(c, c))), shutter="box")
    selection = fitting.select_model(buffers.color, buffers.target, depth=buffers.depth)
    assert selection.choice == "camera", selection.reason


@pytest.mark.parametrize("backend", ["torch", "jax"])
def test_a_tabulated_shutter_blurs_as_its_window_does(backend):
    """The fit's table of a window's antiderivative at the strata edges of K points gives the
    scatter's and the gather's masses exactly, for every kind of window."""
    be = _backends.adapter(backend)
    rng = np.random.default_rng(3)
    color, depth, velocity = (be.array(x) for x in (rng.random((1, 3, 10, 12)), rng.uniform(1.0, 3.0, (1, 1, 10, 12)), rng.normal(0.0, 3.0, (1, 2, 10, 12))))
    windows = (get_shutter("box"), get_shutter("raised_cosine"), Trapezoid(ramp=0.4), LinearRamp(slope=-0.6))
    # JAX compiles the ops anew for each window (a static option): two of them there.
    for window in windows if backend == "torch" else windows[1::2]:
        tables = _models.shutter_tables(be, window, [16, 9])
        for count, blur in ((16, lambda w: be.ops.bezier_scatter(color, depth, -velocity, velocity, degree=1, samples=16, shutter=w)), (9, lambda w: be.ops.gather_blur(color, velocity, samples=9, shutter=w))):
            np.testing.assert_allclose(be.numpy(blur(_models.TabulatedWindow(*tables[count]))), be.numpy(blur(window)), rtol=0, atol=1e-12, err_msg=f"{window} {count}")
        edges = np.linspace(-1.0, 1.0, 10)
        np.testing.assert_allclose(be.numpy(_models.TabulatedWindow(*tables[9]).antiderivative(be.array(edges), be.xp)), window.antiderivative(edges), atol=1e-15)

