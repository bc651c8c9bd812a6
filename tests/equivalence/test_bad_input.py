"""Bad input raises ValueError or TypeError naming the argument, the same way in both backends."""

from __future__ import annotations

import numpy as np
import pytest


def field(shape, dtype="float64", backend=None):
    return backend.array(np.ones(shape), dtype)


def reconstruct_call(b, *, color=(1, 3, 6, 7), velocity=(1, 2, 6, 7), depth=(1, 1, 6, 7), velocity_fill=1.0, depth_fill=1.0, **options):
    return lambda o: o.reconstruct(
        b.array(np.ones(color)), b.array(np.full(velocity, velocity_fill)), b.array(np.full(depth, depth_fill)), **options
    )


BAD_CALLS = [
    ("reconstruct color rank", lambda o, b: reconstruct_call(b, color=(3, 6, 7))(o), ValueError, r"color must be a 4-d"),
    ("reconstruct depth channels", lambda o, b: reconstruct_call(b, depth=(1, 2, 6, 7))(o), ValueError, r"depth must have 1 channel"),
    ("reconstruct size mismatch", lambda o, b: reconstruct_call(b, velocity=(1, 2, 6, 8))(o), ValueError, r"velocity must match color in batch and size \(B=1, H=6, W=7\), got shape \(1, 2, 6, 8\)"),
    ("reconstruct batch mismatch", lambda o, b: reconstruct_call(b, depth=(2, 1, 6, 7))(o), ValueError, r"depth must match color in batch and size"),
    ("reconstruct even samples", lambda o, b: reconstruct_call(b, samples=4)(o), ValueError, r"samples must be an odd integer >= 1, got 4"),
    ("reconstruct zero samples", lambda o, b: reconstruct_call(b, samples=0)(o), ValueError, r"samples must be an odd integer >= 1, got 0"),
    ("reconstruct max_radius", lambda o, b: reconstruct_call(b, max_radius=0)(o), ValueError, r"max_radius must be > 0, got 0"),
    ("reconstruct extent", lambda o, b: reconstruct_call(b, soft_z_extent=-0.1)(o), ValueError, r"soft_z_extent must be > 0, got -0.1"),
    ("reconstruct sampling", lambda o, b: reconstruct_call(b, sampling="cubic")(o), ValueError, r"sampling must be one of 'bilinear', 'nearest', 'pyramid'; got 'cubic'"),
    ("reconstruct jitter", lambda o, b: reconstruct_call(b, jitter="random")(o), ValueError, r"jitter must be one of 'noise', 'none'; got 'random'"),
    ("reconstruct directions", lambda o, b: reconstruct_call(b, directions="own")(o), ValueError, r"directions must be one of"),
    ("reconstruct shutter", lambda o, b: reconstruct_call(b, shutter="rolling")(o), ValueError, r"shutter must be one of"),
    ("reconstruct NaN velocity", lambda o, b: reconstruct_call(b, velocity_fill=np.nan)(o), ValueError, r"velocity must be finite everywhere"),
    ("reconstruct inf depth", lambda o, b: reconstruct_call(b, depth_fill=np.inf)(o), ValueError, r"depth must be finite everywhere"),
    ("reconstruct NaN depth", lambda o, b: reconstruct_call(b, depth_fill=np.nan)(o), ValueError, r"depth must be > 0 everywhere"),
    ("reconstruct zero depth", lambda o, b: reconstruct_call(b, depth_fill=0.0)(o), ValueError, r"depth must be > 0 everywhere"),
    ("gather even samples", lambda o, b: o.gather_blur(field((1, 3, 4, 4), backend=b), field((1, 2, 4, 4), backend=b), samples=2), ValueError, r"samples must be an odd integer >= 1, got 2"),
    ("gather velocity size", lambda o, b: o.gather_blur(field((1, 3, 4, 4), backend=b), field((1, 2, 4, 5), backend=b)), ValueError, r"velocity must match color"),
    ("gather dtype mismatch", lambda o, b: o.gather_blur(field((1, 3, 4, 4), "float32", b), field((1, 2, 4, 4), "float64", b)), TypeError, r"velocity must have the dtype of color"),
    ("gather NaN velocity", lambda o, b: o.gather_blur(field((1, 3, 4, 4), backend=b), b.array(np.full((1, 2, 4, 4), np.nan))), ValueError, r"velocity must be finite everywhere"),
    ("gather inf velocity", lambda o, b: o.gather_blur(field((1, 3, 4, 4), backend=b), b.array(np.full((1, 2, 4, 4), -np.inf))), ValueError, r"velocity must be finite everywhere"),
    ("gather integer color", lambda o, b: o.gather_blur(b.array(np.ones((1, 3, 4, 4)), "uint8"), field((1, 2, 4, 4), backend=b)), TypeError, r"color must have a floating dtype.*uint8; convert integer images"),
    ("gather velocity rank", lambda o, b: o.gather_blur(field((1, 3, 4, 4), backend=b), field((2, 4, 4), backend=b)), ValueError, r"velocity must be a 4-d \(B, 2, H, W\) array"),
    ("gather velocity channels", lambda o, b: o.gather_blur(field((1, 3, 4, 4), backend=b), field((1, 3, 4, 4), backend=b)), ValueError, r"velocity must have 2 channel"),
    ("reconstruct integer color", lambda o, b: o.reconstruct(b.array(np.ones((1, 3, 4, 4)), "int32"), field((1, 2, 4, 4), backend=b), field((1, 1, 4, 4), backend=b)), TypeError, r"color must have a floating dtype"),
    ("reconstruct depth dtype", lambda o, b: o.reconstruct(field((1, 3, 4, 4), backend=b), field((1, 2, 4, 4), backend=b), field((1, 1, 4, 4), "float32", b)), TypeError, r"depth must have the dtype of color"),
    ("reconstruct negative depth", lambda o, b: reconstruct_call(b, depth_fill=-1.0)(o), ValueError, r"depth must be > 0 everywhere"),
    ("bezier inf depth", lambda o, b: o.bezier_scatter(field((1, 3, 4, 4), backend=b), b.array(np.full((1, 1, 4, 4), np.inf)), field((1, 2, 4, 4), backend=b), field((1, 2, 4, 4), backend=b), samples=3), ValueError, r"depth must be finite everywhere"),
    ("bezier zero depth", lambda o, b: o.bezier_scatter(field((1, 3, 4, 4), backend=b), b.array(np.zeros((1, 1, 4, 4))), field((1, 2, 4, 4), backend=b), field((1, 2, 4, 4), backend=b), samples=3), ValueError, r"depth must be > 0 everywhere"),
    ("bezier offsets size", lambda o, b: o.bezier_scatter(field((1, 3, 4, 4), backend=b), field((1, 1, 4, 4), backend=b), field((1, 2, 4, 5), backend=b), field((1, 2, 4, 4), backend=b), samples=3), ValueError, r"offset_prev must match color in batch and size"),
    ("displacement NaN", lambda o, b: o.velocity_from_motion(b.array(np.full((1, 2, 4, 4), np.nan))), ValueError, r"displacement must be finite everywhere"),
    ("displacement inf", lambda o, b: o.velocity_from_motion(b.array(np.full((1, 2, 4, 4), np.inf))), ValueError, r"displacement must be finite everywhere"),
    ("layer NaN velocity", lambda o, b: o.MotionBlur("gather")(field((1, 3, 4, 4), backend=b), b.array(np.full((1, 2, 4, 4), np.nan))), ValueError, r"velocity must be finite everywhere"),
    ("layer zero depth", lambda o, b: o.MotionBlur("reconstruct")(field((1, 3, 4, 4), backend=b), field((1, 2, 4, 4), backend=b), b.array(np.zeros((1, 1, 4, 4)))), ValueError, r"depth must be > 0 everywhere"),
    # (id, call(ops, backend), exception, message pattern)
    ("velocity rank 3", lambda o, b: o.tile_max(field((2, 7, 11), backend=b), 4), ValueError, r"velocity must be a 4-d \(B, 2, H, W\) array, got shape \(2, 7, 11\)"),
    ("velocity 3 channels", lambda o, b: o.tile_max(field((1, 3, 7, 11), backend=b), 4), ValueError, r"velocity must have 2 channel\(s\).*got shape \(1, 3, 7, 11\)"),
    ("velocity empty", lambda o, b: o.tile_max(field((1, 2, 0, 11), backend=b), 4), ValueError, r"velocity must not be empty"),
    ("tile 0", lambda o, b: o.tile_max(field((1, 2, 4, 4), backend=b), 0), ValueError, r"tile must be an integer >= 1, got 0"),
    ("tile float", lambda o, b: o.tile_max(field((1, 2, 4, 4), backend=b), 2.5), TypeError, r"tile must be an integer >= 1, got 2.5"),
    ("tile bool", lambda o, b: o.tile_max(field((1, 2, 4, 4), backend=b), True), TypeError, r"tile must be an integer"),
    ("integer velocity", lambda o, b: o.tile_max(b.array(np.ones((1, 2, 4, 4)), "int32"), 2), TypeError, r"velocity must have a floating dtype.*int32"),
    ("tile_velocity 1 channel", lambda o, b: o.neighbor_max(field((1, 1, 4, 4), backend=b)), ValueError, r"tile_velocity must have 2 channel"),
    ("z shapes differ", lambda o, b: o.soft_depth_compare(field((1, 1, 4, 4), backend=b), field((1, 1, 4, 5), backend=b), 0.1), ValueError, r"z_b must have the shape of z_a \(1, 1, 4, 4\), got \(1, 1, 4, 5\)"),
    ("z dtypes differ", lambda o, b: o.soft_depth_compare(field((3,), "float32", b), field((3,), "float64", b), 0.1), TypeError, r"z_b must have the dtype of z_a"),
    ("extent 0", lambda o, b: o.soft_depth_compare(field((3,), backend=b), field((3,), backend=b), 0.0), ValueError, r"extent must be > 0, got 0.0"),
    ("extent negative", lambda o, b: o.soft_depth_compare(field((3,), backend=b), field((3,), backend=b), -1), ValueError, r"extent must be > 0, got -1"),
    ("extent NaN", lambda o, b: o.soft_depth_compare(field((3,), backend=b), field((3,), backend=b), float("nan")), ValueError, r"extent must be > 0, got nan"),
    ("extent string", lambda o, b: o.soft_depth_compare(field((3,), backend=b), field((3,), backend=b), "0.1"), TypeError, r"extent must be a real number > 0, got '0.1'"),
    ("extent array negative", lambda o, b: o.soft_depth_compare(field((3,), backend=b), field((3,), backend=b), b.array(-0.5)), ValueError, r"extent must be > 0 everywhere"),
    ("extent array wrong shape", lambda o, b: o.soft_depth_compare(field((3,), backend=b), field((3,), backend=b), field((2,), backend=b)), ValueError, r"extent must have the shape"),
    ("integer depth", lambda o, b: o.soft_depth_compare(b.array([1, 2], "int64"), b.array([1, 2], "int64"), 0.1), TypeError, r"z_a must have a floating dtype"),
    ("speed shape", lambda o, b: o.cone(field((4,), backend=b), field((1, 4), backend=b)), ValueError, r"speed must have the shape of distance"),
    ("cylinder integer", lambda o, b: o.cylinder(b.array([1, 2], "int32"), field((2,), backend=b)), TypeError, r"distance must have a floating dtype"),
    ("not an array", lambda o, b: o.cone([1.0, 2.0], field((2,), backend=b)), TypeError, r"distance must be a (torch.Tensor|jax.Array), got list"),
    ("displacement rank", lambda o, b: o.velocity_from_motion(field((2, 4, 4), backend=b)), ValueError, r"displacement must be a 4-d"),
    ("max_radius 0", lambda o, b: o.velocity_from_motion(field((1, 2, 4, 4), backend=b), max_radius=0.0), ValueError, r"max_radius must be > 0, got 0.0"),
    ("min_radius negative", lambda o, b: o.velocity_from_motion(field((1, 2, 4, 4), backend=b), min_radius=-0.5), ValueError, r"min_radius must be >= 0, got -0.5"),
    ("min above max", lambda o, b: o.velocity_from_motion(field((1, 2, 4, 4), backend=b), min_radius=3.0, max_radius=2.0), ValueError, r"min_radius must be <= max_radius \(2.0\), got 3.0"),
    ("exposure shape", lambda o, b: o.velocity_from_motion(field((2, 2, 4, 4), backend=b), exposure=field((3,), backend=b)), ValueError, r"exposure must be a number, a 0-d .* or a \(B,\) .* with B=2, got shape \(3,\)"),
    ("exposure dtype", lambda o, b: o.velocity_from_motion(field((1, 2, 4, 4), "float32", b), exposure=b.array(1.0, "float64")), TypeError, r"exposure must have the dtype of the input"),
    ("exposure string", lambda o, b: o.velocity_from_motion(field((1, 2, 4, 4), backend=b), exposure="1"), TypeError, r"exposure must be a real number"),
    ("axis out of range", lambda o, b: o.safe_length(field((1, 2, 4, 4), backend=b), axis=4), ValueError, r"axis must be in \[-4, 4\)"),
    ("noise height 0", lambda o, b: o.interleaved_gradient_noise(0, 4), ValueError, r"height must be an integer >= 1, got 0"),
    # An unknown keyword names the valid options, as MotionBlur's do.
    ("gather unknown option", lambda o, b: o.gather_blur(field((1, 3, 4, 4), backend=b), field((1, 2, 4, 4), backend=b), sample=3), TypeError, r"gather_blur\(\) got an unknown option 'sample'; valid options: samples, shutter, sampling, adaptive, impl"),
    ("reconstruct unknown option", lambda o, b: reconstruct_call(b, radius=3)(o), TypeError, r"reconstruct\(\) got an unknown option 'radius'; valid options: max_radius, samples, .*impl"),
    ("bezier unknown option", lambda o, b: o.bezier_scatter(field((1, 3, 4, 4), backend=b), field((1, 1, 4, 4), backend=b), field((1, 2, 4, 4), backend=b), field((1, 2, 4, 4), backend=b), points=3), TypeError, r"bezier_scatter\(\) got an unknown option 'points'; valid options: degree, .*samples"),
    ("accumulate unknown option", lambda o, b: o.accumulate_warps(field((1, 3, 4, 4), backend=b), field((1, 2, 4, 4), backend=b), samples=3), TypeError, r"accumulate_warps\(\) got an unknown option 'samples'; valid options: instants, shutter"),
    ("warp_blend unknown option", lambda o, b: o.warp_blend(field((1, 3, 4, 4), backend=b), field((1, 2, 4, 4), backend=b), samples=3), TypeError, r"warp_blend\(\) got an unknown option 'samples'; valid options: iterations"),
    ("motion unknown option", lambda o, b: o.velocity_from_motion(field((1, 2, 4, 4), backend=b), radius=1.0), TypeError, r"velocity_from_motion\(\) got an unknown option 'radius'; valid options: exposure, max_radius, min_radius"),
    # A channels-last colour is named as such, not reported as a bad velocity.
    ("gather NHWC color", lambda o, b: o.gather_blur(field((1, 4, 5, 3), backend=b), field((1, 2, 4, 5), backend=b)), ValueError, r"color looks channels-last \(B, H, W, C\), got shape \(1, 4, 5, 3\).*NCHW \(B, C, H, W\)"),
    ("reconstruct NHWC color", lambda o, b: reconstruct_call(b, color=(1, 6, 7, 3))(o), ValueError, r"color looks channels-last"),
    ("layer NHWC color", lambda o, b: o.MotionBlur("gather")(field((1, 4, 5, 3), backend=b), field((1, 2, 4, 5), backend=b)), ValueError, r"color looks channels-last"),
]


@pytest.mark.parametrize("call,exception,pattern", [c[1:] for c in BAD_CALLS], ids=[c[0] for c in BAD_CALLS])
def test_bad_input_raises_naming_the_argument(backend, call, exception, pattern):
    with pytest.raises(exception, match=pattern):
        call(backend.ops, backend)


# Under jax.jit the data checks raise when the computation runs: XLA's JaxRuntimeError, whose text
# is the library's message after XLA's status code (jax_impl/_runtime_error.py), the same under
# eqx.filter_jit and through vmap and grad. Under torch.compile they raise RuntimeError with the
# same message (CPU; tests/torch/test_compile_guards.py).
JIT_BAD_CALLS = [
    ("gather NaN velocity", lambda o, c, v, z: o.gather_blur(c, v * np.nan, samples=3), r"velocity must be finite everywhere"),
    ("displacement inf", lambda o, c, v, z: o.velocity_from_motion(v * np.inf), r"displacement must be finite everywhere"),
    ("reconstruct zero depth", lambda o, c, v, z: o.reconstruct(c, v, z * 0.0, samples=3, max_radius=2.0), r"depth must be > 0 everywhere"),
    ("bezier inf depth", lambda o, c, v, z: o.bezier_scatter(c, z * np.inf, -v, v, samples=3), r"depth must be finite everywhere"),
]


@pytest.mark.parametrize("call,pattern", [c[1:] for c in JIT_BAD_CALLS], ids=[c[0] for c in JIT_BAD_CALLS])
def test_data_checks_raise_under_jax_jit(call, pattern):
    jax = pytest.importorskip("jax")
    import jax.numpy as jnp

    import jax_impl

    c, v, z = jnp.ones((1, 3, 4, 4)), jnp.ones((1, 2, 4, 4)), jnp.ones((1, 1, 4, 4))
    with pytest.raises(jax.errors.JaxRuntimeError, match="^INVALID_ARGUMENT: " + pattern) as raised:
        jax.block_until_ready(jax.jit(lambda c, v, z: call(jax_impl, c, v, z))(c, v, z))
    assert "\n" not in str(raised.value)  # the message alone, no traceback


def test_data_check_reads_the_same_under_filter_jit_vmap_and_grad():
    jax = pytest.importorskip("jax")
    eqx = pytest.importorskip("equinox")
    import jax.numpy as jnp

    import jax_impl

    color = jnp.ones((2, 3, 4, 4))
    velocity = jnp.ones((2, 2, 4, 4)).at[1, 0, 2, 2].set(jnp.nan)  # the second example only

    def loss(c, v):
        return jax_impl.gather_blur(c[None], v[None], samples=3).sum()

    for run in (eqx.filter_jit(jax.vmap(loss)), jax.jit(jax.vmap(jax.grad(loss))), jax.jit(jax.checkpoint(jax.vmap(loss)))):
        with pytest.raises(jax.errors.JaxRuntimeError, match="^INVALID_ARGUMENT: velocity must be finite everywhere"):
            jax.block_until_ready(run(color, velocity))
    # Valid data: the check adds nothing to the result.
    good = jnp.ones_like(velocity)
    assert jnp.array_equal(jax.jit(jax.vmap(loss))(color, good), jax.vmap(loss)(color, good))
