"""The MotionBlur layers: module == functional for every option, the exposure and shutter shape
learnable, and a small training loop through the layer, in both frameworks."""

from __future__ import annotations

import numpy as np
import pytest

from diffblur.shutters import Tukey

RNG = np.random.default_rng(11)
COLOR = RNG.random((2, 3, 10, 11))
VELOCITY = RNG.normal(size=(2, 2, 10, 11)) * 2.0
DEPTH = RNG.uniform(1.0, 1.3, size=(2, 1, 10, 11))

OPTIONS = {
    "reconstruct": [
        {},
        {"samples": 3},
        {"max_radius": 3.0},
        {"soft_z_extent": 0.05},
        {"jitter": "none"},
        {"sampling": "nearest"},
        {"shutter": "tent"},
        {"early_out": True},
        {"directions": "neighbor_and_own"},
    ],
    "gather": [{}, {"samples": 5}, {"shutter": "raised_cosine"}, {"sampling": "nearest"}],
}
CALLS = [(method, options) for method, variants in OPTIONS.items() for options in variants]


def functional(backend, method, color, velocity, depth, **options):
    if method == "reconstruct":
        return backend.ops.reconstruct(color, velocity, depth, **options)
    return backend.ops.gather_blur(color, velocity, **options)


@pytest.mark.parametrize("method,options", CALLS, ids=[f"{m}-{'-'.join(o) or 'defaults'}" for m, o in CALLS])
def test_module_equals_functional_for_every_option(backend, method, options):
    color, velocity, depth = (backend.array(a) for a in (COLOR, VELOCITY, DEPTH))
    # 0.625 is exact in every float width, so the stored exposure multiplies exactly.
    layer = backend.ops.MotionBlur(method, exposure=0.625, **options)
    expected = functional(backend, method, color, velocity * 0.625, depth, **options)
    np.testing.assert_allclose(backend.numpy(layer(color, velocity, depth)), backend.numpy(expected), rtol=1e-12, atol=1e-12)


def test_unknown_option_and_missing_input_are_named(backend):
    with pytest.raises(TypeError, match=r"unknown option 'sample'; valid options: .*samples"):
        backend.ops.MotionBlur("gather", sample=5)
    with pytest.raises(ValueError, match=r"method must be one of 'reconstruct', 'gather'"):
        backend.ops.MotionBlur("blur")
    with pytest.raises(ValueError, match=r"needs depth"):
        backend.ops.MotionBlur("reconstruct")(backend.array(COLOR), backend.array(VELOCITY))
    with pytest.raises(ValueError, match=r"exposure must be > 0, got 0"):
        backend.ops.MotionBlur("gather", exposure=0)


@pytest.mark.parametrize("channels", [1, 5])
def test_any_number_of_channels(backend, channels):
    color = backend.array(RNG.random((2, channels, 10, 11)))
    out = backend.ops.MotionBlur("reconstruct", samples=5)(color, backend.array(VELOCITY), backend.array(DEPTH))
    assert tuple(out.shape) == (2, channels, 10, 11)


def test_torch_layer_trains_its_exposure_and_compiles():
    import torch

    import torch_impl

    color, velocity, depth = (torch.tensor(a, dtype=torch.float32) for a in (COLOR, VELOCITY * 2, DEPTH))
    target = torch_impl.reconstruct(color, velocity * 0.6, depth, samples=7)
    layer = torch_impl.MotionBlur("reconstruct", samples=7, exposure=1.0, learn_exposure=True)
    optimizer = torch.optim.Adam(layer.parameters(), lr=0.03)
    for _ in range(80):
        optimizer.zero_grad()
        loss = ((layer(color, velocity, depth) - target) ** 2).mean()
        loss.backward()
        optimizer.step()
    assert abs(layer.exposure.item() - 0.6) < 0.02
    compiled = torch.compile(layer, backend="aot_eager", fullgraph=True)
    # Compiled, the layer runs the tensor ops; eager, the fused kernel: float32 rounding apart.
    torch.testing.assert_close(compiled(color, velocity, depth), layer(color, velocity, depth), rtol=1e-5, atol=2e-5)


def test_torch_layer_learns_a_shutter_shape():
    import torch

    import torch_impl

    color, velocity = torch.tensor(COLOR), torch.tensor(VELOCITY * 2)
    layer = torch_impl.MotionBlur("gather", samples=7, shutter=Tukey(0.3), learn_shutter=True)
    assert sorted(name for name, _ in layer.named_parameters()) == ["shutter_shape.taper"]  # exposure: opt-in
    layer(color, velocity).sum().backward()
    assert layer.shutter_shape["taper"].grad != 0


def test_jax_layer_trains_under_jit_grad_and_vmaps():
    import equinox as eqx
    import jax
    import jax.numpy as jnp
    import optax

    import jax_impl

    color, velocity, depth = (jnp.asarray(a, dtype=jnp.float32) for a in (COLOR, VELOCITY * 2, DEPTH))
    target = jax_impl.reconstruct(color, velocity * 0.6, depth, samples=7)
    layer = jax_impl.MotionBlur("reconstruct", samples=7, exposure=1.0, learn_exposure=True)

    optimizer = optax.adam(0.03)
    state = optimizer.init(eqx.filter(layer, eqx.is_inexact_array))

    @eqx.filter_jit
    def step(layer, state):
        grads = eqx.filter_grad(lambda m: jnp.mean((m(color, velocity, depth) - target) ** 2))(layer)
        updates, state = optimizer.update(grads, state)
        return eqx.apply_updates(layer, updates), state

    with jax.numpy_dtype_promotion("standard"):  # optax's step counter mixes int32 and floats
        for _ in range(80):
            layer, state = step(layer, state)
    assert abs(float(layer.exposure) - 0.6) < 0.02
    per_image = jax.vmap(lambda c, v, d: layer(c[None], v[None], d[None])[0])(color, velocity, depth)
    np.testing.assert_allclose(per_image, layer(color, velocity, depth), rtol=1e-5, atol=1e-6)


def test_jax_layer_learns_a_shutter_shape():
    import equinox as eqx
    import jax.numpy as jnp

    import jax_impl

    layer = jax_impl.MotionBlur("gather", samples=7, shutter=Tukey(0.3), learn_shutter=True)
    grads = eqx.filter_grad(lambda m: m(jnp.asarray(COLOR), jnp.asarray(VELOCITY * 2)).sum())(layer)
    assert float(grads.shutter_shape["taper"]) != 0.0
    assert grads.exposure is None  # a static float unless learn_exposure=True


def test_exposure_is_learnable_only_when_asked(backend):
    """A network that predicts the velocity needs no second scale on it: the exposure is a constant
    unless learn_exposure=True."""
    for learn in (False, True):
        layer = backend.ops.MotionBlur("gather", samples=3, exposure=0.5, **({"learn_exposure": True} if learn else {}))
        if backend.name == "torch":
            assert [name for name, _ in layer.named_parameters()] == (["exposure"] if learn else [])
        else:
            import equinox as eqx

            assert eqx.is_inexact_array(layer.exposure) is learn
