"""Inside `diffblur.without_host_reads` the JAX ops put no data check into a jitted computation (on a
GPU each is a host callback that waits for the device) and give the same results eagerly."""

from __future__ import annotations

import numpy as np
import pytest

jax = pytest.importorskip("jax")
import jax.numpy as jnp  # noqa: E402

import diffblur  # noqa: E402
import jax_impl  # noqa: E402

B, H, W = 2, 16, 20


def _inputs() -> dict:
    rng = np.random.default_rng(0)
    velocity = 3.0 * rng.random((B, 2, H, W)) - 1.5
    velocity[..., : W // 3] = 0.0  # still pixels: bezier_scatter's fill="still" has some
    return {
        "color": jnp.asarray(rng.random((B, 3, H, W)), jnp.float32),
        "velocity": jnp.asarray(velocity, jnp.float32),
        "depth": jnp.asarray(rng.random((B, 1, H, W)) + 1.0, jnp.float32),
    }


CALLS = {
    "gather_blur adaptive": lambda x: jax_impl.gather_blur(x["color"], x["velocity"], samples=5, adaptive=True, impl="tensor"),
    "reconstruct": lambda x: jax_impl.reconstruct(x["color"], x["velocity"], x["depth"], samples=5, max_radius=4.0, impl="tensor"),
    "reconstruct adaptive": lambda x: jax_impl.reconstruct(x["color"], x["velocity"], x["depth"], samples=5, max_radius=4.0, adaptive=True, impl="tensor"),
    "bezier_scatter": lambda x: jax_impl.bezier_scatter(x["color"], x["depth"], -x["velocity"], x["velocity"], samples=4, impl="tensor"),
    "warp_blend": lambda x: jax_impl.warp_blend(x["color"], x["velocity"]),
}


@pytest.mark.parametrize("name", list(CALLS))
def test_jitted_op_holds_its_data_checks_and_none_inside_without_host_reads(name):
    x = _inputs()
    checked = jax.jit(CALLS[name]).lower(x).as_text()
    with diffblur.without_host_reads():  # a function of its own: jax.jit caches a trace per function
        unchecked = jax.jit(lambda x: CALLS[name](x)).lower(x).as_text()
    assert "diffblur_raise_if" in checked
    assert "diffblur_raise_if" not in unchecked and "callback" not in unchecked


@pytest.mark.parametrize("name", list(CALLS))
def test_eager_op_inside_without_host_reads_gives_the_same_result(name):
    x = _inputs()
    expected = CALLS[name](x)
    with diffblur.without_host_reads():
        out = CALLS[name](x)
    np.testing.assert_allclose(np.asarray(out), np.asarray(expected), rtol=1e-6, atol=1e-6)


def test_without_host_reads_skips_the_data_checks_and_ends_with_its_block():
    x = _inputs()
    x["color"] = x["color"].at[0, 0, 3, 4].set(jnp.nan)
    with diffblur.without_host_reads():
        assert bool(jnp.isnan(CALLS["reconstruct"](x)).any())
    with pytest.raises(ValueError, match="color must be finite everywhere"):
        CALLS["reconstruct"](x)
