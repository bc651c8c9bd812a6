"""Recovery with the defaults on scenes of objects over a still background: the layers model and
select_model find each layer's motion, the exposure comes out within 1 %, both frameworks reach the
same parameters, and a fit that cannot explain the blur says so. Small scenes (32 to 48 px) keep
this within the test budget; the held-out family (`python -m fitting.evaluate`) has the full numbers."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import fitting
from diffblur.scenes._textures import pad
from diffblur.scenes import ImageTexture, Layer, Scene, Static, Translation, photo, render_buffers
from fitting import scenes
from fitting._models import depth_layers


def _object_over_background(size: int = 40, velocity=(4.0, 2.0), shutter="box"):
    """A photographed square (depth 2) moving `velocity` over a still photograph (depth 10)."""
    background = Layer(ImageTexture(photo("astronaut", size + 8, size + 8), origin=(-4, -4)), 10.0, Static(), "background")
    n = int(0.4 * size)
    card = Layer(pad(photo("chelsea", n, n, zoom=1.5), np.ones((n, n)), (size // 3, size // 3)), 2.0, Translation(velocity), "card")
    return render_buffers(Scene(size, size, (background, card)), shutter=shutter)


@pytest.fixture(scope="module")
def square():
    return _object_over_background(32, (3.0, 1.5))


def _up_to_sign(found, expected) -> float:
    found, expected = np.asarray(found), np.asarray(expected)
    return float(min(np.abs(found - expected).max(), np.abs(found + expected).max()))


def test_depth_layers_are_the_depth_gaps_at_any_scale():
    depth = np.full((1, 1, 8, 8), 10.0)
    depth[..., 2:5, 2:5] = 2.0
    depth[..., 6:, 6:] = 2.05  # within 10 % of 2: the same layer
    ids, depths = depth_layers(depth)
    assert ids.max() == 1 and np.all(ids[depth < 5] == 0) and np.all(ids[depth == 10] == 1)
    np.testing.assert_allclose(depths, [2.0, 10.0])
    for factor in (0.01, 100.0):
        np.testing.assert_array_equal(depth_layers(depth * factor)[0], ids)
    tilted = np.broadcast_to(np.linspace(2.0, 4.0, 64).reshape(1, 1, 8, 8), (1, 1, 8, 8))
    assert depth_layers(tilted)[0].max() == 0  # a smooth surface: one layer


def test_layers_model_recovers_an_object_over_a_still_background(square):
    """Defaults only (no init, no levels, no solver): each layer within 0.25 px."""
    result = fitting.recover(square.color, square.target, depth=square.depth, model="layers")
    card, background = result.params["palette"]
    assert result.params["depths"] == pytest.approx([2.0, 10.0])
    assert _up_to_sign(card, (3.0, 1.5)) < 0.25, result.params
    assert np.abs(background).max() < 0.25, result.params
    assert result.converged and result.explained > 0.9, (result.converged, result.explained, result.message)


def test_select_model_picks_layers_for_an_object_over_a_still_background(square):
    selection = fitting.select_model(square.color, square.target, depth=square.depth, candidates=("global", "rotation", "layers"))
    assert selection.choice == "layers", selection.reason


def test_exposure_through_the_scatter_within_one_percent(square):
    """The scatter leaves out the pixels its fill guesses (behind the moving square); the
    reconstruction filter and the gather are 5-20 % off on such scenes."""
    result = fitting.recover(square.color, square.target, depth=square.depth, model=fitting.Exposure(velocity=square.velocity / 0.6), method="scatter")
    assert abs(result.params["exposure"] - 0.6) < 0.006, result.params
    assert result.converged


def test_a_global_fit_of_a_scene_it_cannot_explain_warns(square):
    with pytest.warns(UserWarning, match=r"recover\(model='global'\) explains only"), pytest.warns(UserWarning, match="biased by the method's own error"):
        result = fitting.recover(square.color, square.target, depth=square.depth, model="global", method="gather")
    assert result.explained < 0.5


def test_a_start_of_either_sign_reports_the_canonical_sign_in_params_and_field():
    s, _, _ = scenes.translation(32, (3.0, -1.5))
    result = fitting.recover(s.color, s.target, model="global", method="gather", samples=15, init={"velocity": (-3.5, 1.0)})
    np.testing.assert_allclose(result.params["velocity"], [3.0, -1.5], atol=0.1)
    np.testing.assert_allclose(result.velocity[0, :, 5, 5], result.params["velocity"])


def test_dense_init_of_the_wrong_shape_is_refused():
    s, _, _ = scenes.translation(24, (2.0, 1.0))
    with pytest.raises(ValueError, match=r"init\['velocity'\] of model 'dense' must be a \(1, 2, H, W\) field"):
        fitting.recover(s.color, s.target, model="dense", init={"velocity": (9.0, 4.0)})


def test_every_default_fit_converges_or_warns():
    """A fit stopped by its step limit says so, by `converged` and a warning."""
    s, _, _ = scenes.translation(24, (2.0, 1.0))
    with pytest.warns(UserWarning, match="did not converge: stopped after the most iterations allowed"):
        result = fitting.recover(s.color, s.target, model="global", method="gather", iterations=1, search=False)
    assert not result.converged


def test_a_fit_biased_by_its_method_is_flagged_and_an_unbiased_one_is_not():
    """Through reconstruct a tent-shutter pan comes out about 10 % short (the scatter and the gather
    do not): the scatter, refitted from that answer, moves it, which marks the fit not converged."""
    s, _, _ = scenes.translation(24, (4.0, 1.5), shutter="tent")
    with pytest.warns(UserWarning, match="biased by the method's own error"):
        biased = fitting.recover(s.color, s.target, model="global", method="reconstruct", shutter="tent")
    assert _up_to_sign(biased.params["velocity"], (4.0, 1.5)) > fitting.METHOD_SHIFT_WARNING
    assert biased.method_shift > fitting.METHOD_SHIFT_WARNING and not biased.converged
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        fair = fitting.recover(s.color, s.target, model="global", method="gather", shutter="tent")
    assert _up_to_sign(fair.params["velocity"], (4.0, 1.5)) < 0.1
    assert fair.method_shift < fitting.METHOD_SHIFT_WARNING and fair.converged
    assert np.isnan(fitting.recover(s.color, s.target, model="global", shutter="tent").method_shift)  # the default method: nothing to check


_PROBLEMS = {
    "global gather": lambda: (scenes.translation(32, (3.0, -1.5))[0], dict(model="global", method="gather")),
    "global reconstruct": lambda: (scenes.translation(32, (2.5, 1.0))[0], dict(model="global", method="reconstruct")),
    "layers": lambda: (_object_over_background(32, (3.0, 1.5)), dict(model="layers")),
    "exposure scatter": lambda: (_object_over_background(32, (3.0, 1.5)), dict(model="exposure", method="scatter")),
    "motion_ids": lambda: (scenes.two_objects(32)[0], dict(model="motion_ids", method="gather")),
}


@pytest.mark.slow
@pytest.mark.parametrize("problem", sorted(_PROBLEMS))
def test_torch_and_jax_reach_the_same_parameters(problem):
    """The default solver is one loop for both frameworks: the parameters agree within 1e-3
    relative (or 1e-3 px where a value is near 0)."""
    buffers, options = _PROBLEMS[problem]()
    if options["model"] == "exposure":
        options["model"] = fitting.Exposure(velocity=buffers.velocity / 0.6)
    if options["model"] == "motion_ids":
        options["model"] = fitting.MotionIds(scenes.layer_ids(buffers))
    found = {}
    for backend in ("torch", "jax"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            found[backend] = fitting.recover(buffers.color, buffers.target, depth=buffers.depth, backend=backend, **options)
    for name, value in found["torch"].params.items():
        np.testing.assert_allclose(found["jax"].params[name], value, rtol=1e-3, atol=1e-3, err_msg=name)
    assert found["torch"].converged == found["jax"].converged


@pytest.mark.filterwarnings("ignore:recover\\(model='layers'\\) did not converge:UserWarning")  # the gather's bias on this scene: the options are the point
def test_a_model_object_carries_its_options_and_a_name_is_its_defaults(square):
    """fitting.Layers(ratio=...) is used as given and left unchanged; "layers" is Layers()."""
    model = fitting.Layers(ratio=1.5)
    by_object = fitting.recover(square.color, square.target, depth=square.depth, model=model, method="gather", search=False, init={"palette": [[3.0, 1.5], [0.1, 0.0]]})
    by_name = fitting.recover(square.color, square.target, depth=square.depth, model="layers", method="gather", search=False, init={"palette": [[3.0, 1.5], [0.1, 0.0]]})
    assert model.depths == () and by_object.model == by_name.model == "layers"
    np.testing.assert_allclose(by_object.params["palette"], by_name.params["palette"])
    assert by_object.params["depths"] == pytest.approx([2.0, 10.0])
