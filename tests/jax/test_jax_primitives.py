"""JAX specifics: jit, vmap and grad compose with the ops, data checks raise under jit with
the library's message, NumPy input is accepted, dtypes are kept."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

import jax_impl


@pytest.mark.parametrize("dtype", [jnp.float16, jnp.bfloat16, jnp.float32, jnp.float64])
def test_dtype_is_kept(dtype):
    velocity = (jax.random.normal(jax.random.key(0), (2, 2, 7, 8)) * 3).astype(dtype)
    depth = jnp.abs(velocity[:, :1]) + 1.0
    speed = jax_impl.safe_length(velocity)
    outs = [
        jax_impl.soft_depth_compare(depth, depth[..., ::-1], 0.1),
        jax_impl.cone(speed[..., ::-1], speed),
        jax_impl.cylinder(speed[..., ::-1], speed),
        speed,
        jax_impl.velocity_from_motion(velocity, exposure=0.5),
        jax_impl.neighbor_max(jax_impl.tile_max(velocity, 3)),
        jax_impl.interleaved_gradient_noise(4, 5, dtype=dtype),
    ]
    for out in outs:
        assert out.dtype == dtype
        assert jnp.all(jnp.isfinite(out))


def test_data_check_raises_under_jit():
    z = jnp.ones(3)
    fn = eqx.filter_jit(jax_impl.soft_depth_compare)
    np.testing.assert_allclose(fn(z, z + 0.05, jnp.asarray(0.1)), 0.5, rtol=1e-12)
    with pytest.raises(Exception, match="extent must be > 0 everywhere"):
        jax.block_until_ready(fn(z, z, jnp.asarray(-0.1)))
    with pytest.raises(ValueError, match="extent must be > 0 everywhere"):
        jax_impl.soft_depth_compare(z, z, jnp.asarray(-0.1))


def test_vmap_over_batches_equals_the_batched_call():
    velocity = jax.random.normal(jax.random.key(1), (3, 2, 9, 10)) * 4
    batched = jax_impl.neighbor_max(jax_impl.tile_max(velocity, 4))
    mapped = jax.vmap(lambda v: jax_impl.neighbor_max(jax_impl.tile_max(v[None], 4))[0])(velocity)
    np.testing.assert_array_equal(mapped, batched)


def test_numpy_input_is_accepted():
    z = np.array([1.0, 2.0])
    np.testing.assert_allclose(jax_impl.soft_depth_compare(z, z + 0.25, 0.5), [0.5, 0.5])


def test_fit_exposure_through_velocity_from_motion():
    """A useful gradient: optax Adam recovers an exposure of 0.6 from the velocity it produces."""
    displacement = jax.random.normal(jax.random.key(2), (1, 2, 6, 6)) * 8
    target = jax_impl.velocity_from_motion(displacement, exposure=0.6)

    def loss(exposure):
        return jnp.mean((jax_impl.velocity_from_motion(displacement, exposure=exposure) - target) ** 2)

    optimizer = optax.adam(0.05)
    exposure = jnp.asarray(1.0)
    state = optimizer.init(exposure)

    @jax.jit
    def step(exposure, state):
        updates, state = optimizer.update(jax.grad(loss)(exposure), state)
        return optax.apply_updates(exposure, updates), state

    with jax.numpy_dtype_promotion("standard"):  # optax's own step counter mixes int32 and floats
        for _ in range(200):
            exposure, state = step(exposure, state)
    assert abs(float(exposure) - 0.6) < 1e-3


def _backward_temp_bytes(samples: int) -> int:
    color = jnp.ones((1, 3, 24, 40), jnp.float32)
    velocity = jnp.ones((1, 2, 24, 40), jnp.float32) * 3.0
    depth = jnp.ones((1, 1, 24, 40), jnp.float32)
    loss = lambda c, v, z: jax_impl.reconstruct(c, v, z, samples=samples, max_radius=8.0).sum()  # noqa: E731
    compiled = jax.jit(jax.grad(loss, argnums=(0, 1, 2))).lower(color, velocity, depth).compile()
    return compiled.memory_analysis().temp_size_in_bytes


def test_reconstruct_backward_memory_does_not_grow_with_taps():
    """The taps run in a scan with a checkpointed body, so XLA's temporaries for the backward are
    O(pixels): the same for 3 taps as for 31 (within 10 %)."""
    few, many = _backward_temp_bytes(3), _backward_temp_bytes(31)
    plane = 24 * 40 * 4
    assert many < 1.1 * few
    assert few < 200 * plane



#: gather_blur's and bezier_scatter's forward-mode errors are checked in tests/test_fused_gather.py
#: and tests/test_fused_scatter.py, with impl="tensor"'s forward mode.
FORWARD_MODE_CALLS = {
    "reconstruct": lambda c, v, d: jax_impl.reconstruct(c, v, d, samples=3, max_radius=2.0),
    "MotionBlur": lambda c, v, d: jax_impl.MotionBlur("gather", samples=3)(c, v),
}


@pytest.mark.parametrize("name", sorted(FORWARD_MODE_CALLS))
def test_forward_mode_through_a_fused_kernel_says_to_pass_fused_false(name):
    """The fused kernels are custom_vjps (reverse mode only): jacfwd names the way out."""
    rng = np.random.default_rng(3)
    color, velocity = jnp.asarray(rng.random((1, 2, 5, 6))), jnp.asarray(rng.normal(size=(1, 2, 5, 6)))
    with pytest.raises(TypeError, match=r"reverse-mode gradient only .* pass \w+\(\.\.\., impl='tensor'\)"):
        jax.jacfwd(lambda v: FORWARD_MODE_CALLS[name](color, v, jnp.ones((1, 1, 5, 6))).sum())(velocity)
