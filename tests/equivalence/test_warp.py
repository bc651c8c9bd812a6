"""seed 002's image-warping methods, `accumulate_warps` and `warp_blend`, in both backends: values by
construction (the box filter of warp_blend, accumulate = gather), the ghosting at few instants, the
asymmetric trail, and bad input. Outputs and gradients against NumPy are in the equivalence harness
(cases_warp.py)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.backends import backend  # noqa: F401


def _field(b, shape, fill=1.0, dtype="float64"):
    return b.array(np.full(shape, fill), dtype)


def _translation(height, width, vx, vy=0.0, batch=1):
    velocity = np.zeros((batch, 2, height, width))
    velocity[:, 0], velocity[:, 1] = vx, vy
    return velocity


def test_accumulate_warps_with_an_odd_count_is_the_gather(backend):
    rng = np.random.default_rng(11)
    color = backend.array(rng.random((2, 3, 12, 13)))
    velocity = backend.array(rng.normal(size=(2, 2, 12, 13)) * 3.0)
    for count, shutter in ((5, "box"), (7, "tent")):
        accumulated = backend.numpy(backend.ops.accumulate_warps(color, velocity, instants=count, shutter=shutter))
        gathered = backend.numpy(backend.ops.gather_blur(color, velocity, samples=count, shutter=shutter))
        np.testing.assert_allclose(accumulated, gathered, rtol=1e-12, atol=1e-12)


def test_accumulate_warps_ghosts_at_few_instants(backend):
    """A 1 px bright bar moving 12 px (half-spread 6): with 2 instants the pixels see two separate
    copies with nothing between; with 25 instants the streak is continuous."""
    color = np.zeros((1, 1, 1, 41))
    color[..., 20] = 1.0
    velocity = backend.array(_translation(1, 41, 6.0))
    two = backend.numpy(backend.ops.accumulate_warps(backend.array(color), velocity, instants=2))[0, 0, 0]
    # instants t = -1/2, +1/2: pixel X reads C[X - t 6], i.e. C[X + 3] and C[X - 3].
    expected = np.zeros(41)
    expected[[17, 23]] = 0.5
    np.testing.assert_allclose(two, expected, atol=1e-12)
    many = backend.numpy(backend.ops.accumulate_warps(backend.array(color), velocity, instants=25))[0, 0, 0]
    assert np.all(many[15:26] > 0.02), "the streak must be continuous with enough instants"
    np.testing.assert_allclose(many.sum(), 1.0, rtol=1e-12)  # energy kept


def _turning_texture():
    """A smooth texture covering a 32 x 32 image, turning 0.5 rad each way about its centre over the
    exposure (box shutter), rendered by `diffblur.scenes` (88 instants): exact offsets and target."""
    from diffblur.scenes import FunctionTexture, Layer, Rotation, Scene, render_buffers

    def paint(x, y):
        c = 0.5 + 0.4 * np.sin(0.9 * x + 0.3 * y) * np.cos(0.5 * y)
        return np.stack([c, 0.5 + 0.3 * np.cos(0.7 * x), 1.0 - c], axis=-1), np.ones_like(x)

    texture = FunctionTexture(paint, (np.zeros(1), np.zeros(1)), opaque=True)
    return render_buffers(Scene(32, 32, (Layer(texture, 2.0, Rotation((15.5, 15.5), 0.5)),)), shutter="box")


def test_accumulate_warps_follows_a_curved_path_the_right_way_round(backend):
    """On a rotation the curved offsets must beat the straight line through them: 41.7 against
    29.6 dB PSNR (8 instants, border of 4 px left out). Reading C[X - p(t)] mirrors the bend and
    scored 24.5 dB, below the line."""
    from diffblur.metrics import psnr

    buffers = _turning_texture()
    a, inner = backend.array, (..., slice(4, -4), slice(4, -4))
    straight = backend.numpy(backend.ops.accumulate_warps(a(buffers.color), a(buffers.velocity), instants=8))
    curved = backend.numpy(
        backend.ops.accumulate_warps(a(buffers.color), None, instants=8, offset_prev=a(buffers.offset_prev), offset_next=a(buffers.offset_next))
    )
    line, curve = psnr(straight[inner], buffers.target[inner]), psnr(curved[inner], buffers.target[inner])
    assert curve > line + 6.0, (curve, line)


def test_reference_accumulate_warps_follows_a_curved_path_the_right_way_round():
    """The NumPy reference on one pixel X = (2, 2) of a 5 x 5 image: offsets (-8, 4) and (8, 4) give
    the path p(t) = (8 t, 4 t^2), bent downwards. At the instants -1/2 and +1/2 the point at X comes
    from X + p(-t) = (2 -/+ 4, 3), below X (clamped to the border columns): it reads the 1s of row 3,
    not the 5s of row 1 that the mirrored bend X - p(t) = (2 -/+ 4, 1) would read."""
    from diffblur import reference

    color = np.zeros((1, 1, 5, 5))
    color[0, 0, 3, 0] = color[0, 0, 3, 4] = 1.0
    color[0, 0, 1, 0] = color[0, 0, 1, 4] = 5.0
    prev, nxt = np.zeros((1, 2, 5, 5)), np.zeros((1, 2, 5, 5))
    prev[0, :, 2, 2], nxt[0, :, 2, 2] = (-8.0, 4.0), (8.0, 4.0)
    out = reference.accumulate_warps(color, None, instants=2, shutter="box", sampling="nearest", offset_prev=prev, offset_next=nxt)
    assert out[0, 0, 2, 2] == pytest.approx(1.0)


def test_accumulate_warps_linear_offsets_equal_the_velocity(backend):
    rng = np.random.default_rng(12)
    color = backend.array(rng.random((1, 2, 9, 10)))
    v = rng.normal(size=(1, 2, 9, 10)) * 2.0
    by_velocity = backend.ops.accumulate_warps(color, backend.array(v), instants=4)
    by_offsets = backend.ops.accumulate_warps(color, None, instants=4, offset_prev=backend.array(-v), offset_next=backend.array(v))
    np.testing.assert_allclose(backend.numpy(by_offsets), backend.numpy(by_velocity), atol=1e-12)


def test_warp_blend_on_a_uniform_translation_is_the_box_of_3_to_the_n_taps(backend):
    """Warps of 2/3 and 2/9 of V = 9 px are whole pixels (6 and 2), so bilinear reads are exact and
    two iterations equal the 9-sample gather wherever no read reaches the border (8 px)."""
    rng = np.random.default_rng(13)
    color = backend.array(rng.random((1, 3, 3, 40)))
    velocity = backend.array(_translation(3, 40, 9.0))
    blended = backend.numpy(backend.ops.warp_blend(color, velocity, iterations=2))
    gathered = backend.numpy(backend.ops.gather_blur(color, velocity, samples=9))
    np.testing.assert_allclose(blended[..., 8:32], gathered[..., 8:32], rtol=1e-12, atol=1e-12)
    assert not np.allclose(blended[..., 8:32], backend.numpy(color)[..., 8:32], atol=1e-3)


def test_warp_blend_backward_scale_shortens_the_leading_side(backend):
    """An impulse moving right: pixels ahead of it (x > 30) see it through the warp against the
    velocity, pixels behind (x < 30) through the warp along it (trail). backward_scale = 0.5 halves
    the reach ahead and keeps the trail."""
    color = np.zeros((1, 1, 1, 61))
    color[..., 30] = 1.0
    velocity = backend.array(_translation(1, 61, 9.0))
    out = backend.numpy(backend.ops.warp_blend(backend.array(color), velocity, iterations=2, backward_scale=0.5))[0, 0, 0]
    support = np.nonzero(out > 1e-12)[0]
    assert support.min() == 30 - 8 and support.max() == 30 + 4
    symmetric = backend.numpy(backend.ops.warp_blend(backend.array(color), velocity, iterations=2))[0, 0, 0]
    support = np.nonzero(symmetric > 1e-12)[0]
    assert support.min() == 30 - 8 and support.max() == 30 + 8


def test_warp_blend_alpha_ramp_weights_small_warps_more(backend):
    """A growing ramp (the document's) concentrates the blur near the sharp position. By hand, for an
    impulse and warps of 6 and 2 px: the first pass keeps 1 - a0 at 0 and moves a0 / 2 to each of
    +-6, the second keeps 1 - a1 and moves a1 / 2 to +-2; the result is their convolution."""
    color = np.zeros((1, 1, 1, 61))
    color[..., 30] = 1.0
    velocity = backend.array(_translation(1, 61, 9.0))
    flat = backend.numpy(backend.ops.warp_blend(backend.array(color), velocity, iterations=2))[0, 0, 0]
    ramp = backend.numpy(backend.ops.warp_blend(backend.array(color), velocity, iterations=2, alpha=(0.3, 0.9)))[0, 0, 0]
    expected_flat = np.zeros(61)
    expected_flat[30 - 8 : 30 + 9 : 2] = 1.0 / 9.0
    np.testing.assert_allclose(flat, expected_flat, atol=1e-12)
    expected_ramp = np.zeros(61)
    for coarse, p_coarse in ((-6, 0.15), (0, 0.7), (6, 0.15)):
        for fine, p_fine in ((-2, 0.45), (0, 0.1), (2, 0.45)):
            expected_ramp[30 + coarse + fine] += p_coarse * p_fine
    np.testing.assert_allclose(ramp, expected_ramp, atol=1e-12)
    assert ramp[28:33].sum() > 2 * flat[28:33].sum()


def test_warp_ops_keep_dtype_and_give_finite_gradients_at_zero_velocity(backend):
    rng = np.random.default_rng(14)
    color = backend.array(rng.random((1, 3, 8, 8)), "float32")
    zero = backend.array(np.zeros((1, 2, 8, 8)), "float32")
    for op, options in ((backend.ops.accumulate_warps, dict(instants=4)), (backend.ops.warp_blend, dict(iterations=2))):
        out = op(color, zero, **options)
        assert backend.numpy(out).dtype == np.float32
        np.testing.assert_allclose(backend.numpy(out), backend.numpy(color), atol=1e-6)
        grads = backend.grad(lambda c, v: op(c, v, **options) ** 2, color, zero)
        assert all(np.all(np.isfinite(g)) for g in grads)


def _acc(o, b, **options):
    return o.accumulate_warps(_field(b, (1, 3, 4, 4)), _field(b, (1, 2, 4, 4)), **options)


def _wb(o, b, **options):
    return o.warp_blend(_field(b, (1, 3, 4, 4)), _field(b, (1, 2, 4, 4)), **options)


BAD_CALLS = [
    ("accumulate instants 0", lambda o, b: _acc(o, b, instants=0), ValueError, r"instants must be an integer >= 1, got 0"),
    ("accumulate instants float", lambda o, b: _acc(o, b, instants=2.5), TypeError, r"instants must be an integer >= 1, got 2.5"),
    ("accumulate sampling", lambda o, b: _acc(o, b, sampling="cubic"), ValueError, r"sampling must be one of 'bilinear', 'nearest'; got 'cubic'"),
    ("accumulate shutter", lambda o, b: _acc(o, b, shutter="rolling"), ValueError, r"shutter must be one of"),
    ("accumulate both paths", lambda o, b: _acc(o, b, offset_prev=_field(b, (1, 2, 4, 4)), offset_next=_field(b, (1, 2, 4, 4))), ValueError, r"velocity or \(offset_prev, offset_next\), not both"),
    ("accumulate one offset", lambda o, b: o.accumulate_warps(_field(b, (1, 3, 4, 4)), None, offset_prev=_field(b, (1, 2, 4, 4))), ValueError, r"needs velocity, or both offset_prev and offset_next; got offset_prev=given, offset_next=None"),
    ("accumulate no path", lambda o, b: o.accumulate_warps(_field(b, (1, 3, 4, 4)), None), ValueError, r"needs velocity, or both"),
    ("accumulate offset size", lambda o, b: o.accumulate_warps(_field(b, (1, 3, 4, 4)), None, offset_prev=_field(b, (1, 2, 4, 5)), offset_next=_field(b, (1, 2, 4, 4))), ValueError, r"offset_prev must match color in batch and size"),
    ("accumulate NaN velocity", lambda o, b: o.accumulate_warps(_field(b, (1, 3, 4, 4)), _field(b, (1, 2, 4, 4), np.nan)), ValueError, r"velocity must be finite everywhere"),
    ("accumulate velocity channels", lambda o, b: o.accumulate_warps(_field(b, (1, 3, 4, 4)), _field(b, (1, 3, 4, 4))), ValueError, r"velocity must have 2 channel"),
    ("accumulate dtype", lambda o, b: o.accumulate_warps(_field(b, (1, 3, 4, 4), dtype="float32"), _field(b, (1, 2, 4, 4))), TypeError, r"velocity must have the dtype of color"),
    ("accumulate integer color", lambda o, b: o.accumulate_warps(_field(b, (1, 3, 4, 4), dtype="int32"), _field(b, (1, 2, 4, 4))), TypeError, r"color must have a floating dtype"),
    ("warp_blend iterations 0", lambda o, b: _wb(o, b, iterations=0), ValueError, r"iterations must be an integer >= 1, got 0"),
    ("warp_blend iterations bool", lambda o, b: _wb(o, b, iterations=True), TypeError, r"iterations must be an integer >= 1, got True"),
    ("warp_blend backward_scale", lambda o, b: _wb(o, b, backward_scale=1.5), ValueError, r"backward_scale must be in \[0.0, 1.0\], got 1.5"),
    ("warp_blend alpha 0", lambda o, b: _wb(o, b, alpha=0.0), ValueError, r"alpha must be in \(0, 1\], got \(0.0, 0.0\)"),
    ("warp_blend alpha pair", lambda o, b: _wb(o, b, alpha=(0.5, 1.2)), ValueError, r"alpha must be in \(0, 1\], got \(0.5, 1.2\)"),
    ("warp_blend alpha triple", lambda o, b: _wb(o, b, alpha=(0.5, 0.6, 0.7)), TypeError, r"alpha must be a number or a pair \(first, last\)"),
    ("warp_blend alpha string", lambda o, b: _wb(o, b, alpha="0.5"), TypeError, r"alpha must be a number or a pair"),
    ("warp_blend sampling", lambda o, b: _wb(o, b, sampling="area"), ValueError, r"sampling must be one of"),
    ("warp_blend inf velocity", lambda o, b: o.warp_blend(_field(b, (1, 3, 4, 4)), _field(b, (1, 2, 4, 4), np.inf)), ValueError, r"velocity must be finite everywhere"),
    ("warp_blend velocity size", lambda o, b: o.warp_blend(_field(b, (1, 3, 4, 4)), _field(b, (2, 2, 4, 4))), ValueError, r"velocity must match color in batch and size"),
]


@pytest.mark.parametrize("call, error, pattern", [c[1:] for c in BAD_CALLS], ids=[c[0] for c in BAD_CALLS])
def test_bad_input(backend, call, error, pattern):
    with pytest.raises(error, match=pattern):
        call(backend.ops, backend)


LAYER_CALLS = [
    ("warp_blend", {}),
    ("warp_blend", {"iterations": 2, "backward_scale": 0.5, "alpha": (0.5, 0.8), "sampling": "nearest"}),
    ("accumulate", {}),
    ("accumulate", {"instants": 3, "shutter": "tent", "sampling": "nearest"}),
]


@pytest.mark.parametrize("method,options", LAYER_CALLS, ids=[f"{m}-{'-'.join(o) or 'defaults'}" for m, o in LAYER_CALLS])
def test_layer_equals_functional(backend, method, options):
    rng = np.random.default_rng(15)
    color, velocity = backend.array(rng.random((2, 3, 7, 8))), backend.array(rng.normal(size=(2, 2, 7, 8)) * 2.0)
    layer = backend.ops.MotionBlur(method, exposure=0.625, **options)
    op = backend.ops.warp_blend if method == "warp_blend" else backend.ops.accumulate_warps
    expected = op(color, velocity * 0.625, **options)
    np.testing.assert_allclose(backend.numpy(layer(color, velocity)), backend.numpy(expected), rtol=1e-12, atol=1e-12)


def test_layer_refuses_arrays_as_options_and_a_shutter_it_does_not_have(backend):
    with pytest.raises(TypeError, match=r"offset_prev is an array input of the layer's call, not an option"):
        backend.ops.MotionBlur("accumulate", offset_prev=1.0)
    with pytest.raises(ValueError, match=r"warp_blend has no shutter"):
        backend.ops.MotionBlur("warp_blend", learn_shutter=True)
    with pytest.raises(ValueError, match=r"needs velocity"):
        backend.ops.MotionBlur("warp_blend")(backend.array(np.ones((1, 3, 4, 4))))
