"""The fused CPU splats of bezier_scatter (diffblur.kernels.scatter) against the pure tensor ops, both
frameworks.

The pure ops are the reference: the fused path must give the same image and the same gradients
w.r.t. color, depth, the path's inputs (offsets or arc), the background, a shutter's parameter and
a soft_z_extent tensor (float64: to rounding; float32: to float32 tolerance), for every path,
normalisation and fill, eagerly, under jax.jit and under jax.vmap; it must refuse what it does not
cover when asked for (impl="fused") and quietly use the pure ops otherwise (impl="auto").
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
from diffblur.kernels import scatter as scatter_kernel  # noqa: E402
from diffblur.shutters import LinearRamp  # noqa: E402
from tests.tolerances import tolerance  # noqa: E402

FUSED_FLOAT64, FUSED_FLOAT32 = (tolerance(dtype, "fused", "bezier_scatter") for dtype in ("float64", "float32"))

BATCH, CHANNELS, HEIGHT, WIDTH = 2, 3, 12, 14

#: The path inputs of each kind of path, and its options.
PATHS = {
    "degree 1": (("offset_prev", "offset_next"), dict(degree=1)),
    "degree 2": (("offset_prev", "offset_next"), dict(degree=2)),
    "degree 3": (("offset_prev", "offset_next", "offset_mid_prev"), dict(degree=3)),
    "arc": (("arc_center", "arc_angle"), dict()),
}
NORMALIZATIONS = ("coverage", "paper")
FILLS = ("still", "color", "background")


def _scene(dtype=np.float64, seed=0):
    """Paths reaching past the border (points off the image, splats on the padding ring), a third of
    the pixels still, and depths at three levels: level (the soft band's edge), inside the band
    (0.04 < the default extent 0.1) and far behind."""
    rng = np.random.default_rng(seed)
    shape = (BATCH, 2, HEIGHT, WIDTH)
    still = rng.random((BATCH, 1, HEIGHT, WIDTH)) < 0.3
    arrays = {
        "color": rng.random((BATCH, CHANNELS, HEIGHT, WIDTH)),
        "depth": rng.choice([1.0, 1.04, 2.0], size=(BATCH, 1, HEIGHT, WIDTH)),
        "offset_prev": np.where(still, 0.0, rng.normal(0, 2.5, size=shape)),
        "offset_next": np.where(still, 0.0, rng.normal(0, 2.5, size=shape)),
        "offset_mid_prev": np.where(still, 0.0, rng.normal(0, 1.5, size=shape)),
        "arc_center": rng.uniform(0.0, 1.0, size=shape) * np.array([WIDTH - 1.0, HEIGHT - 1.0]).reshape(1, 2, 1, 1),
        "arc_angle": np.where(still, 0.0, rng.normal(0, 0.4, size=(BATCH, 1, HEIGHT, WIDTH))),
        "background": rng.random((BATCH, CHANNELS, HEIGHT, WIDTH)),
        "cotangent": rng.standard_normal((BATCH, CHANNELS, HEIGHT, WIDTH)),
    }
    return {name: a.astype(dtype) for name, a in arrays.items()}


def _differentiated(path: str, fill: str) -> tuple[str, ...]:
    return ("color", "depth", *PATHS[path][0], *(("background",) if fill == "background" else ()))


def _call(ops, values: dict, path: str, options: dict, impl: str):
    """bezier_scatter on `values` (arrays of the backend), the path's fields and options."""
    fields, path_options = PATHS[path]
    offsets = (None, None) if path == "arc" else (values["offset_prev"], values["offset_next"])
    given = {name: values[name] for name in fields if name not in ("offset_prev", "offset_next")}
    if "background" in values:  # the scene behind, as the fill (in place of a named one)
        given["fill"] = values["background"]
        options = {name: value for name, value in options.items() if name != "fill"}
    return ops.bezier_scatter(values["color"], values["depth"], *offsets, **given, **path_options, **options, impl=impl)


def _torch_values(arrays, path, fill="still"):
    return {name: torch.tensor(arrays[name]) for name in _differentiated(path, fill)}


def _torch_run(arrays, path, options, impl, fill="still"):
    values = {name: value.requires_grad_() for name, value in _torch_values(arrays, path, fill).items()}
    out = _call(torch_impl, values, path, dict(options, fill="still" if fill == "background" else fill), impl)
    grads = torch.autograd.grad(out, list(values.values()), torch.tensor(arrays["cotangent"]))
    return out.detach().numpy(), dict(zip(values, (g.numpy() for g in grads)))


def _jax_run(arrays, path, options, impl, fill="still", transform=jax.jit):
    names = _differentiated(path, fill)
    fill_option = "still" if fill == "background" else fill
    cotangent = jnp.asarray(arrays["cotangent"])

    def run(*values):
        return _call(jax_impl, dict(zip(names, values)), path, dict(options, fill=fill_option), impl)

    def loss(*values):
        return jnp.sum(run(*values) * cotangent)

    values = [jnp.asarray(arrays[name]) for name in names]
    out = transform(run)(*values)
    grads = transform(jax.grad(loss, argnums=tuple(range(len(names)))))(*values)
    return np.asarray(out), dict(zip(names, (np.asarray(g) for g in grads)))


def _assert_close(fused, pure, tolerance):
    out_f, grads_f = fused
    out_p, grads_p = pure
    np.testing.assert_allclose(out_f, out_p, rtol=0, atol=tolerance)
    assert grads_f.keys() == grads_p.keys()
    for name in grads_p:
        scale = max(1.0, float(np.abs(grads_p[name]).max()))
        np.testing.assert_allclose(grads_f[name], grads_p[name], rtol=0, atol=tolerance * scale, err_msg=f"gradient w.r.t. {name}")
        if name != "background":  # the splats are differentiable in every input that moves them
            assert np.abs(grads_p[name]).max() > 0, f"gradient w.r.t. {name} is all zero: the test would not see it"


@pytest.mark.parametrize("fill", FILLS)
@pytest.mark.parametrize("normalization", NORMALIZATIONS)
@pytest.mark.parametrize("path", list(PATHS))
def test_torch_fused_matches_pure_float64(path, normalization, fill):
    arrays = _scene()
    options = dict(samples=7, normalization=normalization)
    _assert_close(_torch_run(arrays, path, options, "fused", fill), _torch_run(arrays, path, options, "tensor", fill), FUSED_FLOAT64)


@pytest.mark.parametrize("normalization", NORMALIZATIONS)
@pytest.mark.parametrize("path, fill", [("degree 1", "still"), ("degree 2", "background"), ("degree 3", "color"), ("arc", "background")])
def test_jax_fused_matches_pure_float64_under_jit(path, fill, normalization):
    arrays = _scene()
    options = dict(samples=7, normalization=normalization)
    _assert_close(_jax_run(arrays, path, options, "fused", fill), _jax_run(arrays, path, options, "tensor", fill), FUSED_FLOAT64)


def test_automatic_point_count_and_shutters():
    """samples=None (one point per pixel of the longest path: eager only) and other shutters. JAX
    runs the automatic point count only: each shutter compiles the op's inner functions anew (about
    4 s each), and the shutters' masses are the code both frameworks share."""
    arrays = _scene(seed=1)
    for options in (dict(), dict(shutter="box", normalization="paper"), dict(shutter="tent", samples=4)):
        _assert_close(_torch_run(arrays, "degree 2", options, "fused"), _torch_run(arrays, "degree 2", options, "tensor"), FUSED_FLOAT64)
    eager = lambda f: f  # noqa: E731
    _assert_close(_jax_run(arrays, "degree 2", {}, "fused", transform=eager), _jax_run(arrays, "degree 2", {}, "tensor", transform=eager), FUSED_FLOAT64)


@pytest.mark.parametrize("normalization", NORMALIZATIONS)
def test_torch_shutter_parameter_and_extent_tensor_gradients(normalization):
    """A shutter's parameter (through the masses' gradient) and a soft_z_extent tensor."""
    arrays = _scene(seed=2)
    results = []
    for impl in ("fused", "tensor"):
        values = {name: value.requires_grad_() for name, value in _torch_values(arrays, "degree 3").items()}
        parameters = {"slope": torch.tensor(0.6, dtype=torch.float64), "soft_z_extent": torch.tensor(0.07, dtype=torch.float64)}
        parameters = {name: value.requires_grad_() for name, value in parameters.items()}
        options = dict(samples=6, shutter=LinearRamp(parameters["slope"]), soft_z_extent=parameters["soft_z_extent"], normalization=normalization)
        out = _call(torch_impl, values, "degree 3", options, impl)
        inputs = {**values, **parameters}
        grads = torch.autograd.grad(out, list(inputs.values()), torch.tensor(arrays["cotangent"]))
        results.append((out.detach().numpy(), {name: g.numpy() for name, g in zip(inputs, grads)}))
    _assert_close(*results, FUSED_FLOAT64)


def test_jax_shutter_parameter_and_extent_gradients_under_jit():
    arrays = _scene(seed=2)
    values = {name: jnp.asarray(arrays[name]) for name in _differentiated("arc", "still")}
    cotangent = jnp.asarray(arrays["cotangent"])

    def loss(slope, extent, impl):
        options = dict(samples=6, shutter=LinearRamp(slope), soft_z_extent=extent, normalization="paper")
        return jnp.sum(_call(jax_impl, values, "arc", options, impl) * cotangent)

    parameters = (jnp.asarray(0.6), jnp.asarray(0.07))
    fused = jax.jit(jax.grad(lambda s, e: loss(s, e, "fused"), argnums=(0, 1)))(*parameters)
    pure = jax.grad(lambda s, e: loss(s, e, "tensor"), argnums=(0, 1))(*parameters)
    for f, p in zip(fused, pure):
        assert abs(float(p)) > 0
        np.testing.assert_allclose(float(f), float(p), rtol=1e-10)


@pytest.mark.parametrize("band", [dict(), dict(relative_z_extent=0.05)])
def test_instants_without_a_still_pixel(band):
    """composite="instants" in an image without a still pixel fills each instant from its own
    picture (a push-pull weighed by each pixel's log depth from the kernel's sums), under an absolute
    and a relative band, in both frameworks. The depths vary continuously here: the push-pull's
    farthest depth is a maximum, whose gradient frameworks share among exact ties, and the kernel's
    sums, added in another order, break ties that the tensor ops' sums keep."""
    arrays = _scene(seed=6)
    rng = np.random.default_rng(7)
    arrays["depth"] = arrays["depth"] + rng.uniform(0.0, 0.02, arrays["depth"].shape)
    for name in ("offset_prev", "offset_next"):
        arrays[name] = rng.normal(0.0, 2.5, arrays[name].shape)
    options = dict(samples=5, **band)
    pure = _torch_run(arrays, "degree 2", options, "tensor")
    _assert_close(_torch_run(arrays, "degree 2", options, "fused"), pure, FUSED_FLOAT64)
    eager = lambda f: f  # noqa: E731  (whether an image has a still pixel is read from the offsets)
    _assert_close(_jax_run(arrays, "degree 2", options, "fused", transform=eager), pure, FUSED_FLOAT64)


@pytest.mark.parametrize("channels", [1, 4])
def test_channel_counts_other_than_three(channels):
    """The kernels take colour in groups of three channels: one padded group, and a group and a half.
    The groups reach the kernels as read-only arrays, as three channels do: one compiled signature
    per dtype (numba compiles a writable array as a type of its own)."""
    arrays = _scene(seed=4)
    rng = np.random.default_rng(5)
    for name in ("color", "background", "cotangent"):
        arrays[name] = rng.random((BATCH, channels, HEIGHT, WIDTH))
    for path, fill in (("degree 2", "still"), ("arc", "background")):
        options = dict(samples=5, normalization="paper")
        _assert_close(_torch_run(arrays, path, options, "fused", fill), _torch_run(arrays, path, options, "tensor", fill), FUSED_FLOAT64)
    _assert_close(_jax_run(arrays, "degree 1", dict(samples=5), "fused"), _jax_run(arrays, "degree 1", dict(samples=5), "tensor"), FUSED_FLOAT64)
    three_channels = {**arrays, **{name: np.repeat(arrays[name][:, :1], 3, axis=1) for name in ("color", "background", "cotangent")}}
    _torch_run(three_channels, "arc", dict(samples=5, normalization="paper"), "fused", "background")  # no padded groups
    for kernel in (scatter_kernel._splat_forward, scatter_kernel._splat_backward, scatter_kernel._pad_channels_last):
        float64_types = {signature[0] for signature in kernel.signatures if str(signature[0].dtype) == "float64"}
        assert len(float64_types) == 1, (kernel.py_func.__name__, float64_types)


@pytest.mark.parametrize("path", ["degree 2", "arc"])
def test_float32_both_frameworks_agree(path):
    arrays = _scene(np.float32, seed=3)
    options = dict(samples=7)
    torch_fused = _torch_run(arrays, path, options, "fused")
    _assert_close(torch_fused, _torch_run(arrays, path, options, "tensor"), FUSED_FLOAT32)
    _assert_close(_jax_run(arrays, path, options, "fused"), _jax_run(arrays, path, options, "tensor"), FUSED_FLOAT32)
    _assert_close(_jax_run(arrays, path, options, "fused"), torch_fused, FUSED_FLOAT32)
    assert torch_fused[0].dtype == np.float32


@pytest.fixture
def kernel_calls(monkeypatch):
    """Counts the fused kernels' forward and backward runs (JAX's callbacks look them up per call)."""
    calls = {"forward": 0, "backward": 0, "instant forward": 0, "instant backward": 0}
    names = (("splat_forward", "forward"), ("splat_backward", "backward"), ("instant_forward", "instant forward"), ("instant_backward", "instant backward"))
    for name, key in names:
        original = getattr(scatter_kernel, name)

        def counted(*args, _original=original, _key=key, **kwargs):
            calls[_key] += 1
            return _original(*args, **kwargs)

        monkeypatch.setattr(scatter_kernel, name, counted)
    return calls


def test_default_takes_the_fused_path_in_both_frameworks(kernel_calls):
    """impl="auto" on float32 CPU inputs runs the kernel, forward and backward, and impl="tensor" not."""
    arrays = _scene(np.float32)
    default = _torch_run(arrays, "degree 2", dict(samples=5), "auto")
    # composite="instants" (the default) splats on the kernel twice (what passes behind a pixel: the
    # sums with the depths and without a test), and its 5 instants in one chunk (a small image)
    assert kernel_calls == {"forward": 2, "backward": 2, "instant forward": 1, "instant backward": 1}
    _jax_run(arrays, "degree 2", dict(samples=5), "auto")
    assert kernel_calls["forward"] > 2 and kernel_calls["backward"] == 4
    assert kernel_calls["instant forward"] > 1 and kernel_calls["instant backward"] == 2
    counted = dict(kernel_calls)
    pure = _torch_run(arrays, "degree 2", dict(samples=5), "tensor")
    _jax_run(arrays, "degree 2", dict(samples=5), "tensor")
    assert kernel_calls == counted
    _assert_close(default, pure, FUSED_FLOAT32)


def test_jax_vmap_over_a_leading_axis():
    arrays = _scene()
    names = _differentiated("degree 2", "still")
    stacked = [np.stack([arrays[name], arrays[name][::-1]]) for name in names]
    cotangent = jnp.asarray(arrays["cotangent"])

    def loss(*values, impl):
        return jnp.sum(_call(jax_impl, dict(zip(names, values)), "degree 2", dict(samples=5), impl) * cotangent)

    grads = jax.vmap(jax.grad(lambda *v: loss(*v, impl="fused"), argnums=(0, 1, 2, 3)))(*stacked)
    for i in range(2):
        reference = jax.grad(lambda *v: loss(*v, impl="tensor"), argnums=(0, 1, 2, 3))(*(s[i] for s in stacked))
        for g, r in zip(grads, reference):
            np.testing.assert_allclose(np.asarray(g[i]), np.asarray(r), rtol=0, atol=1e-10)


def test_batch_items_do_not_mix():
    """Alone or in a batch, an item gets its own image (to rounding: the rows' chunks, and so the order
    of the sums, depend on the batch)."""
    arrays = _scene(np.float32)
    values = _torch_values(arrays, "degree 2")
    whole = _call(torch_impl, values, "degree 2", dict(samples=5), "fused")
    single = _call(torch_impl, {name: value[1:] for name, value in values.items()}, "degree 2", dict(samples=5), "fused")
    torch.testing.assert_close(whole[1:], single, rtol=0, atol=1e-6)


def _refusals(monkeypatch, cause):
    if cause == "numba":
        monkeypatch.setattr(scatter_kernel, "numba", None)
        return "numba is not installed", "numba is not installed"
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    return None, "JAX's default backend is gpu"


@pytest.mark.parametrize("cause", ["numba", "backend"])
def test_fused_true_refuses_saying_why_and_none_falls_back(monkeypatch, cause):
    arrays = _scene(np.float32)
    torch_values = _torch_values(arrays, "degree 2")
    jax_values = {name: jnp.asarray(arrays[name]) for name in torch_values}
    expected = {
        "torch": _call(torch_impl, torch_values, "degree 2", dict(samples=5), "tensor").numpy(),
        "jax": np.asarray(_call(jax_impl, jax_values, "degree 2", dict(samples=5), "tensor")),
    }
    torch_words, jax_words = _refusals(monkeypatch, cause)
    for framework, ops, values, words in (("torch", torch_impl, torch_values, torch_words), ("jax", jax_impl, jax_values, jax_words)):
        if words is None:
            continue
        with pytest.raises(ValueError, match=f"bezier_scatter\\(impl='fused'\\) cannot run: {words}"):
            _call(ops, values, "degree 2", dict(samples=5), "fused")
        fallback = _call(ops, values, "degree 2", dict(samples=5), "auto")
        np.testing.assert_array_equal(np.asarray(fallback.numpy() if framework == "torch" else fallback), expected[framework])


def test_half_precision_falls_back_to_the_tensor_ops():
    values = {name: value.to(torch.float16) for name, value in _torch_values(_scene(np.float32), "degree 2").items()}
    with pytest.raises(ValueError, match="dtype float16"):
        _call(torch_impl, values, "degree 2", dict(samples=5), "fused")
    assert _call(torch_impl, values, "degree 2", dict(samples=5), "auto").dtype == torch.float16


def test_torch_double_backward_is_refused_clearly():
    values = {name: value.requires_grad_() for name, value in _torch_values(_scene(), "degree 2").items()}
    out = _call(torch_impl, values, "degree 2", dict(samples=5), "fused")
    (grad,) = torch.autograd.grad(out.square().sum(), values["offset_next"], create_graph=True)
    with pytest.raises(RuntimeError, match="double backward"):
        grad.sum().backward()


def test_jax_forward_mode_needs_fused_false():
    arrays = _scene()
    values = {name: jnp.asarray(arrays[name]) for name in _differentiated("degree 2", "still")}

    def along(offset, impl):
        return _call(jax_impl, dict(values, offset_next=offset), "degree 2", dict(samples=5), impl)

    tangent = jnp.ones_like(values["offset_next"])
    with pytest.raises(TypeError, match=r"custom_vjp.*pass bezier_scatter\(\.\.\., impl='tensor'\)"):
        jax.jvp(lambda o: along(o, "fused"), (values["offset_next"],), (tangent,))
    _, pure = jax.jvp(lambda o: along(o, "tensor"), (values["offset_next"],), (tangent,))
    assert np.isfinite(np.asarray(pure)).all()


@pytest.mark.filterwarnings("ignore:recover\\(model='rotation'\\) did not converge:UserWarning")  # one step: the path is the point
def test_fitting_rotation_with_forward_mode_jacobians_takes_the_tensor_ops():
    """fitting's Levenberg-Marquardt with jac="fwd" (JAX jvp) runs the arc scatter: it must not meet
    the custom_vjp, so the rotation model passes impl="tensor" there."""
    import fitting
    from fitting import scenes

    scene, _, _ = scenes.propeller(16, 0.5)
    result = fitting.recover(
        scene.color, scene.target, depth=scene.depth, model=fitting.Rotation(background=scene.background), backend="jax", solver="lm", jac="fwd", iterations=1
    )
    assert np.isfinite(result.params["angle"])
