"""The fused CPU gather_blur (diffblur.kernels.gather) against the pure tensor ops, both frameworks.

The pure ops are the reference: the fused path must give the same image and the same gradients
w.r.t. color, velocity and a shutter's parameters (float64: to rounding; float32: to float32
tolerance), full rate and adaptive, eagerly, under jax.jit and under jax.vmap; it must refuse what
it does not cover when asked for (impl="fused") and quietly use the pure ops otherwise.
"""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
jax = pytest.importorskip("jax")
pytest.importorskip("numba")
import jax.numpy as jnp  # noqa: E402

import jax_impl  # noqa: E402
import torch_impl  # noqa: E402
from diffblur.shutters import LinearRamp  # noqa: E402
from tests.tolerances import tolerance  # noqa: E402

FUSED_FLOAT64, FUSED_FLOAT32 = (tolerance(dtype, "fused", "gather_blur") for dtype in ("float64", "float32"))

#: 2 x 3 tiles of 16 px for the adaptive classes, the last ones partial.
BATCH, CHANNELS, HEIGHT, WIDTH = 2, 3, 20, 37

CASES = {
    "box, 7 taps": dict(samples=7),
    "gaussian shutter": dict(samples=5, shutter="gaussian"),
    "one tap": dict(samples=1),
    "adaptive": dict(samples=15, adaptive=True),
    "adaptive, own classes": dict(samples=9, adaptive=(1, 3), shutter="tent"),
}


def _scene(dtype=np.float64, seed=0):
    """A fast block (reaching past the border) over a slow drift, and a still tile."""
    rng = np.random.default_rng(seed)
    color = rng.random((BATCH, CHANNELS, HEIGHT, WIDTH))
    velocity = rng.normal(0, 0.4, size=(BATCH, 2, HEIGHT, WIDTH))
    velocity[:, :, 2:9, 18:30] = np.array([[8.3, -5.2], [-6.1, 7.4]])[:BATCH, :, None, None]  # |V| > 7.5: 15 taps
    velocity[:, :, 2:9, 18:30] += rng.normal(0, 0.2, size=(BATCH, 2, 7, 12))  # off the integer kinks of floor
    velocity[:, :, :16, :16] = 0.0  # a still tile
    cotangent = rng.standard_normal((BATCH, CHANNELS, HEIGHT, WIDTH))
    return [a.astype(dtype) for a in (color, velocity, cotangent)]


def _torch_run(arrays, options, impl):
    color, velocity = (torch.tensor(a, requires_grad=True) for a in arrays[:2])
    out = torch_impl.gather_blur(color, velocity, impl=impl, **options)
    grads = torch.autograd.grad(out, (color, velocity), torch.tensor(arrays[2]))
    return out.detach().numpy(), [g.numpy() for g in grads]


def _jax_run(arrays, options, impl, transform=lambda f: f):
    cotangent = jnp.asarray(arrays[2])

    def loss(color, velocity):
        return jnp.sum(jax_impl.gather_blur(color, velocity, impl=impl, **options) * cotangent)

    out = transform(lambda c, v: jax_impl.gather_blur(c, v, impl=impl, **options))(*arrays[:2])
    grads = transform(jax.grad(loss, argnums=(0, 1)))(*arrays[:2])
    return np.asarray(out), [np.asarray(g) for g in grads]


def _assert_close(fused, pure, tolerance, *, velocity_matters=True):
    out_f, grads_f = fused
    out_p, grads_p = pure
    np.testing.assert_allclose(out_f, out_p, rtol=0, atol=tolerance)
    for name, gf, gp in zip(("color", "velocity"), grads_f, grads_p):
        if name == "color" or velocity_matters:
            assert np.abs(gp).max() > 0.1, f"the scene gives no gradient w.r.t. {name}"
        scale = max(1.0, float(np.abs(gp).max()))
        np.testing.assert_allclose(gf, gp, rtol=0, atol=tolerance * scale, err_msg=f"gradient w.r.t. {name}")


@pytest.mark.parametrize("case", list(CASES))
def test_torch_fused_matches_pure_float64(case):
    arrays = _scene()
    matters = CASES[case]["samples"] > 1  # one tap reads X itself: no gradient w.r.t. V
    _assert_close(_torch_run(arrays, CASES[case], "fused"), _torch_run(arrays, CASES[case], "tensor"), FUSED_FLOAT64, velocity_matters=matters)


@pytest.mark.parametrize("case", list(CASES))
def test_jax_fused_matches_pure_float64_under_jit(case):
    arrays = _scene()
    matters = CASES[case]["samples"] > 1
    _assert_close(_jax_run(arrays, CASES[case], "fused", jax.jit), _jax_run(arrays, CASES[case], "tensor"), FUSED_FLOAT64, velocity_matters=matters)


def test_jax_eager_adaptive_matches_pure():
    arrays = _scene()
    _assert_close(_jax_run(arrays, CASES["adaptive"], "fused"), _jax_run(arrays, CASES["adaptive"], "tensor"), FUSED_FLOAT64)


def test_adaptive_fused_equals_full_rate_on_full_rate_tiles_and_still_tiles():
    color, velocity, _ = (torch.tensor(a) for a in _scene())
    full = torch_impl.gather_blur(color, velocity, samples=15, impl="fused")
    adaptive = torch_impl.gather_blur(color, velocity, samples=15, adaptive=True, impl="fused")
    torch.testing.assert_close(adaptive[..., :16, :16], color[..., :16, :16], rtol=0, atol=0)
    # Tile (0, 1) holds the fast block (|V| > 7.5 px): the full-rate class.
    torch.testing.assert_close(adaptive[..., :16, 16:32], full[..., :16, 16:32], rtol=0, atol=0)


def test_shutter_parameter_gradient_matches_pure_in_both_frameworks():
    color, velocity, cotangent = _scene()
    grads = {}
    for impl in ("fused", "tensor"):
        slope = torch.tensor(0.6, dtype=torch.float64, requires_grad=True)
        out = torch_impl.gather_blur(torch.tensor(color), torch.tensor(velocity), samples=7, shutter=LinearRamp(slope), impl=impl)
        (grads["torch", impl],) = torch.autograd.grad(out, slope, torch.tensor(cotangent))

        def loss(s, impl=impl):
            return jnp.sum(jax_impl.gather_blur(jnp.asarray(color), jnp.asarray(velocity), samples=7, shutter=LinearRamp(s), impl=impl) * cotangent)

        grads["jax", impl] = jax.jit(jax.grad(loss))(jnp.asarray(0.6))
    assert abs(float(grads["torch", "tensor"])) > 0.1
    for framework in ("torch", "jax"):
        np.testing.assert_allclose(float(grads[framework, "fused"]), float(grads[framework, "tensor"]), rtol=1e-12)
    np.testing.assert_allclose(float(grads["jax", "fused"]), float(grads["torch", "fused"]), rtol=1e-12)


def test_float32_both_frameworks_agree():
    arrays = _scene(np.float32, seed=1)
    options = dict(samples=9)
    torch_fused = _torch_run(arrays, options, "fused")
    _assert_close(torch_fused, _torch_run(arrays, options, "tensor"), FUSED_FLOAT32)
    _assert_close(_jax_run(arrays, options, "fused"), torch_fused, FUSED_FLOAT32)


def test_default_takes_the_fused_path_and_it_is_the_pure_result():
    color, velocity, _ = (torch.tensor(a, requires_grad=True) for a in _scene(np.float32))
    out = torch_impl.gather_blur(color, velocity, samples=9)
    assert "diffblur_gather_forward" in type(out.grad_fn).__name__  # the custom operator's autograd node
    pure = torch_impl.gather_blur(color, velocity, samples=9, impl="tensor")
    assert "diffblur" not in type(pure.grad_fn).__name__
    torch.testing.assert_close(out, pure, rtol=0, atol=2e-5)


def test_jax_vmap_over_a_leading_axis():
    arrays = _scene()
    stacked = [np.stack([a, a[::-1]]) for a in arrays]
    out = jax.vmap(lambda c, v: jax_impl.gather_blur(c, v, samples=7, adaptive=True, impl="fused"))(*stacked[:2])
    for i in range(2):
        reference = jax_impl.gather_blur(stacked[0][i], stacked[1][i], samples=7, adaptive=True, impl="tensor")
        np.testing.assert_allclose(np.asarray(out[i]), np.asarray(reference), rtol=0, atol=1e-12)


@pytest.mark.parametrize("options, words", [(dict(sampling="nearest"), "sampling='nearest'"), (dict(sampling="pyramid"), "sampling='pyramid'")])
def test_fused_true_refuses_what_it_does_not_cover_and_none_falls_back(options, words):
    color, velocity, _ = (torch.tensor(a) for a in _scene(np.float32))
    with pytest.raises(ValueError, match=words):
        torch_impl.gather_blur(color, velocity, impl="fused", **options)
    with pytest.raises(ValueError, match=words):
        jax_impl.gather_blur(jnp.asarray(color.numpy()), jnp.asarray(velocity.numpy()), impl="fused", **options)
    fallback = torch_impl.gather_blur(color, velocity, **options)
    pure = torch_impl.gather_blur(color, velocity, impl="tensor", **options)
    torch.testing.assert_close(fallback, pure, rtol=0, atol=0)


def test_half_precision_falls_back_to_the_tensor_ops():
    color, velocity, _ = (torch.tensor(a).to(torch.float16) for a in _scene(np.float32))
    with pytest.raises(ValueError, match="float16"):
        torch_impl.gather_blur(color, velocity, impl="fused")
    assert torch_impl.gather_blur(color, velocity).dtype == torch.float16


def test_jax_forward_mode_needs_fused_false():
    color, velocity, _ = (jnp.asarray(a) for a in _scene())
    with pytest.raises(TypeError, match=r"custom_vjp.*pass gather_blur\(\.\.\., impl='tensor'\)"):
        jax.jvp(lambda v: jax_impl.gather_blur(color, v, impl="fused"), (velocity,), (jnp.ones_like(velocity),))
    _, tangent = jax.jvp(lambda v: jax_impl.gather_blur(color, v, impl="tensor"), (velocity,), (jnp.ones_like(velocity),))
    assert np.abs(np.asarray(tangent)).max() > 0.1


def test_batch_items_do_not_mix():
    color, velocity, _ = (torch.tensor(a) for a in _scene(np.float32))
    whole = torch_impl.gather_blur(color, velocity, adaptive=True, impl="fused")
    single = torch_impl.gather_blur(color[1:], velocity[1:], adaptive=True, impl="fused")
    torch.testing.assert_close(whole[1:], single, rtol=0, atol=0)


def test_kernel_tile_classes_are_the_shared_rule():
    """The kernel sizes gather's adaptive classes itself; they must be tile_sample_counts' classes."""
    from diffblur.kernels import gather as gather_kernel
    from diffblur.ops.adaptive import ADAPTIVE_TILE, STILL_SPEED, adaptive_classes, tile_sample_counts

    rng = np.random.default_rng(5)
    scale = np.repeat(np.repeat(rng.uniform(0, 8, size=(3, 1, 5, 3)), 16, axis=2), 16, axis=3)[:, :, :70, :45]
    velocity = rng.uniform(-1, 1, size=(3, 2, 70, 45)) * scale  # each tile its own speed
    velocity[:, :, :16, :16] = 0.0
    classes = adaptive_classes(True, 31)
    speed = torch_impl.tile_max(torch.tensor(velocity), ADAPTIVE_TILE).norm(dim=1).numpy()
    expected = tile_sample_counts(speed, classes, STILL_SPEED, np)
    got = gather_kernel._gather_counts(velocity, 31, classes, STILL_SPEED, ADAPTIVE_TILE)
    assert set(np.unique(expected)) >= {0, 7, 15}
    np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("wanted", [("velocity",), ("color",), ("color", "velocity")])
def test_torch_backward_computes_only_the_gradients_asked_for(wanted):
    """The kernel skips the colour's scatter when the colour needs no gradient (most of the
    backward's time); the gradients asked for still match the tensor ops'."""
    arrays = _scene()
    results = []
    for impl in ("fused", "tensor"):
        tensors = {name: torch.tensor(a, requires_grad=name in wanted) for name, a in zip(("color", "velocity"), arrays[:2])}
        out = torch_impl.gather_blur(tensors["color"], tensors["velocity"], impl=impl, **CASES["adaptive"])
        grads = torch.autograd.grad(out, [tensors[name] for name in wanted], torch.tensor(arrays[2]))
        results.append([g.numpy() for g in grads])
    for name, fused_grad, pure_grad in zip(wanted, *results):
        assert np.abs(pure_grad).max() > 0, name
        np.testing.assert_allclose(fused_grad, pure_grad, rtol=1e-10, atol=1e-10, err_msg=name)


@pytest.mark.parametrize("wanted", [("velocity",), ("color",)])
def test_jax_backward_computes_only_the_gradients_asked_for(wanted, monkeypatch):
    """JAX's rule asks the kernel for the differentiated inputs' gradients only (symbolic zeros),
    under jit too; they match the tensor ops'."""
    from diffblur.kernels import gather as gather_kernel

    arrays = _scene()
    asked = []
    backward = gather_kernel.gather_backward
    monkeypatch.setattr(gather_kernel, "gather_backward", lambda *a, needs, **k: asked.append(needs) or backward(*a, needs=needs, **k))
    argnums = tuple(("color", "velocity").index(name) for name in wanted)
    results = []
    for impl in ("fused", "tensor"):
        cotangent = jnp.asarray(arrays[2])
        loss = lambda c, v: jnp.sum(jax_impl.gather_blur(c, v, impl=impl, **CASES["adaptive"]) * cotangent)  # noqa: E731
        results.append(jax.jit(jax.grad(loss, argnums=argnums))(*(jnp.asarray(a) for a in arrays[:2])))
    assert asked == [("color" in wanted, "velocity" in wanted, False)]
    for name, fused_grad, pure_grad in zip(wanted, *results):
        assert np.abs(pure_grad).max() > 0, name
        np.testing.assert_allclose(fused_grad, pure_grad, rtol=1e-10, atol=1e-10, err_msg=name)


def test_jax_adaptive_tensor_ops_under_jit_stay_tensor_ops():
    """adaptive=True, impl="tensor" under jit (every class computed, then selected) must not call the
    kernel: forward mode works there, and its tangent is the eager path's (classes compacted)."""
    color, velocity, _ = (jnp.asarray(a) for a in _scene())

    def blur(v):
        return jax_impl.gather_blur(color, v, samples=15, adaptive=True, impl="tensor")

    tangent_in = jnp.ones_like(velocity)
    _, jitted = jax.jit(lambda v: jax.jvp(blur, (v,), (tangent_in,)))(velocity)
    _, eager = jax.jvp(blur, (velocity,), (tangent_in,))
    assert np.abs(np.asarray(eager)).max() > 0.1
    np.testing.assert_allclose(np.asarray(jitted), np.asarray(eager), rtol=0, atol=1e-12)
