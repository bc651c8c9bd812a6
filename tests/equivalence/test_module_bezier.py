"""MotionBlur(method="bezier"): module == `bezier_scatter` for every option and every way of giving the
paths (a velocity, offsets, a cubic's offsets, an arc, with a background), the exposure scaling the
paths, a learnable shutter shape (the scatter's Gaussian), and a short fit through the layer, in both
frameworks."""

from __future__ import annotations

import numpy as np
import pytest

from diffblur.shutters import Gaussian, Tukey

RNG = np.random.default_rng(23)
SHAPE = (2, 3, 10, 11)
COLOR = RNG.random(SHAPE)
DEPTH = RNG.uniform(1.0, 1.3, size=(2, 1, 10, 11))
#: A third of the pixels still, so that the default fill ("still") has pixels to estimate from.
STILL = RNG.random((2, 1, 10, 11)) < 0.35
VELOCITY = np.where(STILL, 0.0, RNG.normal(size=(2, 2, 10, 11)) * 1.5)
PREV, NEXT, MID = (np.where(STILL, 0.0, RNG.normal(size=(2, 2, 10, 11)) * 1.5) for _ in range(3))
CENTER = np.broadcast_to(np.array([4.0, 6.0]).reshape(1, 2, 1, 1), (2, 2, 10, 11)).copy()
ANGLE = RNG.normal(size=(2, 1, 10, 11)) * 0.3
BACKGROUND = RNG.random(SHAPE)
#: Exact in every float width, so the stored exposure multiplies exactly.
EXPOSURE = 0.625

OPTIONS = [
    {},
    {"degree": 1},
    {"degree": 3},
    {"samples": 5},
    {"max_samples": 3},
    {"shutter": "box"},
    {"shutter": Tukey(0.4)},
    {"fill": "color"},
    {"normalization": "paper"},
    {"normalization": "paper", "background_weight": 2.0, "fill": "color"},
    {"soft_z_extent": 0.05},
]


def _ids(options):
    return "-".join(f"{k}={v}" for k, v in options.items()) or "defaults"


@pytest.mark.parametrize("options", OPTIONS, ids=[_ids(o) for o in OPTIONS])
def test_module_with_a_velocity_equals_the_functional_linear_path(backend, options):
    """A velocity V alone is the segment X - e V ... X + e V (and its point at t = -1/2 for degree 3)."""
    color, depth, velocity = (backend.array(a) for a in (COLOR, DEPTH, VELOCITY))
    layer = backend.ops.MotionBlur("bezier", exposure=EXPOSURE, **options)
    scaled = velocity * EXPOSURE
    mid = {"offset_mid_prev": scaled * -0.5} if options.get("degree") == 3 else {}
    expected = backend.ops.bezier_scatter(color, depth, -scaled, scaled, **mid, **options)
    np.testing.assert_allclose(backend.numpy(layer(color, velocity, depth)), backend.numpy(expected), rtol=1e-12, atol=1e-12)


PATHS = {
    "offsets": ({"offset_prev": PREV, "offset_next": NEXT}, {}),
    "offsets-cubic": ({"offset_prev": PREV, "offset_next": NEXT, "offset_mid_prev": MID}, {"degree": 3}),
    "offsets-background": ({"offset_prev": PREV, "offset_next": NEXT, "fill": BACKGROUND}, {"shutter": "tent"}),
    "arc": ({"arc_center": CENTER, "arc_angle": ANGLE}, {"samples": 6}),
    "arc-background-paper": ({"arc_center": CENTER, "arc_angle": ANGLE, "fill": BACKGROUND}, {"normalization": "paper"}),
}


@pytest.mark.parametrize("path", list(PATHS))
def test_module_with_offsets_or_an_arc_equals_the_functional(backend, path):
    """The exposure multiplies the offsets (the path scaled about X) or the arc's angle, nothing else."""
    inputs, options = PATHS[path]
    color, depth = backend.array(COLOR), backend.array(DEPTH)
    arrays = {k: backend.array(v) for k, v in inputs.items()}
    layer = backend.ops.MotionBlur("bezier", exposure=EXPOSURE, **options)
    scaled = {k: v * EXPOSURE if k.startswith("offset") or k == "arc_angle" else v for k, v in arrays.items()}
    prev, nxt = scaled.pop("offset_prev", None), scaled.pop("offset_next", None)
    expected = backend.ops.bezier_scatter(color, depth, prev, nxt, **scaled, **options)
    out = layer(color, None, depth, **arrays)
    np.testing.assert_allclose(backend.numpy(out), backend.numpy(expected), rtol=1e-12, atol=1e-12)


def test_paths_and_array_options_are_checked(backend):
    color, depth, velocity, prev = (backend.array(a) for a in (COLOR, DEPTH, VELOCITY, PREV))
    layer = backend.ops.MotionBlur("bezier")
    with pytest.raises(ValueError, match=r"needs velocity, or offset_prev and offset_next, or arc_center and arc_angle; got none"):
        layer(color, None, depth)
    with pytest.raises(ValueError, match=r"takes one path: velocity or offsets, got velocity, offset_prev"):
        layer(color, velocity, depth, offset_prev=prev, offset_next=prev)
    with pytest.raises(ValueError, match=r"needs depth"):
        layer(color, velocity)
    with pytest.raises(ValueError, match=r"offset_next must be a \(B, 2, H, W\) array"):
        layer(color, None, depth, offset_prev=prev)
    with pytest.raises(TypeError, match=r"an array fill \(the scene behind\) is an input of the layer's call, not an option"):
        backend.ops.MotionBlur("bezier", fill=COLOR)
    with pytest.raises(TypeError, match=r"unknown option 'sampling'; valid options: degree, samples, max_samples"):
        backend.ops.MotionBlur("bezier", sampling="nearest")
    with pytest.raises(TypeError, match=r"MotionBlur\(method='gather'\) takes offset_prev only with method='bezier'"):
        backend.ops.MotionBlur("gather")(color, velocity, offset_prev=prev)


def test_learnable_shutter_of_the_scatter(backend):
    """learn_shutter with shutter="gaussian" learns seed 003's window (its sigma), and its gradient and
    the exposure's are nonzero. Without a shutter option the scatter's default is the box, as every
    op's, which has no shape to learn: refused as for the other methods."""
    color, depth, velocity = (backend.array(a) for a in (COLOR, DEPTH, VELOCITY))
    with pytest.raises(ValueError, match="learn_shutter needs a window with a shape parameter"):
        backend.ops.MotionBlur("bezier", samples=5, learn_shutter=True)
    layer = backend.ops.MotionBlur("bezier", samples=5, shutter="gaussian", learn_shutter=True, learn_exposure=True)
    expected = backend.ops.bezier_scatter(color, depth, -velocity, velocity, samples=5, shutter=Gaussian(0.5))
    np.testing.assert_allclose(backend.numpy(layer(color, velocity, depth)), backend.numpy(expected), rtol=1e-12, atol=1e-12)
    if backend.name == "torch":
        layer(color, velocity, depth).square().sum().backward()
        grads = {name: float(p.grad) for name, p in layer.named_parameters()}
        assert set(grads) == {"exposure", "shutter_shape.sigma"}
    else:
        import equinox as eqx

        g = eqx.filter_grad(lambda m: (m(color, velocity, depth) ** 2).sum())(layer)
        grads = {"exposure": float(g.exposure), "shutter_shape.sigma": float(g.shutter_shape["sigma"])}
    assert all(v != 0.0 and np.isfinite(v) for v in grads.values()), grads


def test_layer_fits_an_exposure_on_curved_offsets(backend):
    """Adam on the layer's exposure, from 1.0, against the same layer's output at exposure 0.7 on
    curved offsets (quadratic paths), lands within 0.01 of 0.7; in JAX under jit."""
    color, depth, prev, nxt = (backend.array(a, "float32") for a in (COLOR, DEPTH, PREV * 2, NEXT * 2))
    paths = {"offset_prev": prev, "offset_next": nxt}
    target = backend.ops.MotionBlur("bezier", samples=8, exposure=0.7, learn_exposure=False)(color, None, depth, **paths)
    layer = backend.ops.MotionBlur("bezier", samples=8, exposure=1.0, learn_exposure=True)
    if backend.name == "torch":
        import torch

        optimizer = torch.optim.Adam(layer.parameters(), lr=0.03)
        for _ in range(60):
            optimizer.zero_grad()
            ((layer(color, None, depth, **paths) - target) ** 2).mean().backward()
            optimizer.step()
        exposure = float(layer.exposure.detach())
    else:
        import equinox as eqx
        import jax
        import jax.numpy as jnp
        import optax

        optimizer = optax.adam(0.03)
        state = optimizer.init(eqx.filter(layer, eqx.is_inexact_array))

        @eqx.filter_jit
        def step(layer, state):
            grads = eqx.filter_grad(lambda m: jnp.mean((m(color, None, depth, **paths) - target) ** 2))(layer)
            updates, state = optimizer.update(grads, state)
            return eqx.apply_updates(layer, updates), state

        with jax.numpy_dtype_promotion("standard"):  # optax's step counter mixes int32 and floats
            for _ in range(60):
                layer, state = step(layer, state)
        exposure = float(layer.exposure)
    assert abs(exposure - 0.7) < 0.01, exposure


def test_torch_bezier_layer_compiles():
    import torch

    import torch_impl

    color, depth, velocity = (torch.tensor(a, dtype=torch.float32) for a in (COLOR, DEPTH, VELOCITY))
    layer = torch_impl.MotionBlur("bezier", samples=5)
    compiled = torch.compile(layer, backend="aot_eager", fullgraph=True)
    torch.testing.assert_close(compiled(color, velocity, depth), layer(color, velocity, depth), rtol=1e-5, atol=1e-6)
