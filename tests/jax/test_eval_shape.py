"""Every public JAX op traces to its output's shape and dtype with `jax.eval_shape` (abstract values,
no computation): what jax.jit needs of an op that must not read values on the host to decide what
to compute. What needs values (bezier_scatter's automatic point count) says so."""

from __future__ import annotations

import numpy as np
import pytest

jax = pytest.importorskip("jax")

import jax.numpy as jnp  # noqa: E402

import jax_impl  # noqa: E402

B, H, W = 2, 16, 20


def _inputs() -> dict:
    rng = np.random.default_rng(0)
    return {
        "color": jnp.asarray(rng.random((B, 3, H, W)), jnp.float32),
        "velocity": jnp.asarray(3.0 * rng.random((B, 2, H, W)) - 1.5, jnp.float32),
        "depth": jnp.asarray(rng.random((B, 1, H, W)) + 1.0, jnp.float32),
        "ids": jnp.zeros((B, 1, H, W), jnp.int32),
        "palette": jnp.asarray(rng.random((B, 3, 2)), jnp.float32),
    }


CALLS = {
    "gather_blur": lambda x: jax_impl.gather_blur(x["color"], x["velocity"], samples=5),
    "gather_blur adaptive": lambda x: jax_impl.gather_blur(x["color"], x["velocity"], samples=5, adaptive=True),
    "gather_blur pyramid": lambda x: jax_impl.gather_blur(x["color"], x["velocity"], samples=5, sampling="pyramid"),
    "reconstruct": lambda x: jax_impl.reconstruct(x["color"], x["velocity"], x["depth"], samples=5, max_radius=4.0),
    "reconstruct tensor ops": lambda x: jax_impl.reconstruct(x["color"], x["velocity"], x["depth"], samples=5, max_radius=4.0, impl="tensor"),
    "bezier_scatter": lambda x: jax_impl.bezier_scatter(x["color"], x["depth"], -x["velocity"], x["velocity"], samples=4),
    "warp_blend": lambda x: jax_impl.warp_blend(x["color"], x["velocity"]),
    "accumulate_warps": lambda x: jax_impl.accumulate_warps(x["color"], x["velocity"]),
    "velocity_from_motion": lambda x: jax_impl.velocity_from_motion(x["velocity"]),
    "velocity_from_motion_ids": lambda x: jax_impl.velocity_from_motion_ids(x["ids"], x["palette"]),
    "tile_max": lambda x: jax_impl.tile_max(x["velocity"], 4),
    "neighbor_max": lambda x: jax_impl.neighbor_max(jax_impl.tile_max(x["velocity"], 4)),
    "safe_length": lambda x: jax_impl.safe_length(x["velocity"]),
    "soft_depth_compare": lambda x: jax_impl.soft_depth_compare(x["depth"], x["depth"] * 1.1, 0.3),
    "cone": lambda x: jax_impl.cone(x["depth"], x["depth"]),
    "cylinder": lambda x: jax_impl.cylinder(x["depth"], x["depth"]),
    "interleaved_gradient_noise": lambda x: jax_impl.interleaved_gradient_noise(H, W),
    "MotionBlur": lambda x: jax_impl.MotionBlur("reconstruct", samples=5, max_radius=4.0)(x["color"], x["velocity"], x["depth"]),
}


def test_every_public_op_is_covered():
    assert {name.split()[0] for name in CALLS} == set(jax_impl.__all__)


@pytest.mark.parametrize("name", list(CALLS))
def test_eval_shape_gives_the_eager_shape_and_dtype(name):
    x = _inputs()
    expected = CALLS[name](x)
    traced = jax.eval_shape(CALLS[name], x)
    assert traced.shape == expected.shape and traced.dtype == expected.dtype


def test_automatic_point_count_under_tracing_says_it_needs_values():
    x = _inputs()
    with pytest.raises(ValueError, match=r"samples=None measures the curves .* under jax.jit pass samples=<int>"):
        jax.eval_shape(lambda a: jax_impl.bezier_scatter(a["color"], a["depth"], -a["velocity"], a["velocity"]), x)
