"""The fused-path JAX ops' gradients under `jax.jit`, `jax.vmap` and `jax.checkpoint` equal eager's
(issue 25; the sweep of every op is `scripts/measure_compile_vs_eager.py`, its table in
BENCHMARKS.md). Small float64 inputs (the root conftest enables x64); the gradient of a fixed weighted sum of the output."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jax_impl

CALLS = {
    "gather_blur": lambda c, v, z: jax_impl.gather_blur(c, v, samples=5),
    "reconstruct": lambda c, v, z: jax_impl.reconstruct(c, v, z, samples=5, max_radius=4, jitter="none", impl="fused"),
    "reconstruct, per-pixel taps": lambda c, v, z: jax_impl.reconstruct(c, v, z, samples=5, max_radius=4, directions="neighbor_and_own", jitter="none", impl="fused"),
    "bezier_scatter": lambda c, v, z: jax_impl.bezier_scatter(c, z, -v, v, samples=5, fill="color"),
}


@pytest.mark.parametrize("op", list(CALLS))
def test_gradient_under_jit_vmap_and_checkpoint_equals_eager(op):
    rng = np.random.default_rng(0)
    c, v, z = (jnp.asarray(a) for a in (rng.random((1, 3, 8, 9)), rng.normal(size=(1, 2, 8, 9)) * 2.0, rng.uniform(1.0, 2.0, size=(1, 1, 8, 9))))
    weights = jnp.asarray(rng.random((1, 3, 8, 9)))

    def grads(c, v, z):
        return jax.grad(lambda *a: jnp.sum(CALLS[op](*a) * weights), argnums=(0, 1, 2))(c, v, z)

    eager = grads(c, v, z)
    assert any(float(jnp.max(jnp.abs(g))) > 0 for g in eager)
    batched = jax.jit(jax.vmap(grads))(*(jnp.stack([x, 2.0 * x]) for x in (c, v, z)))
    second = grads(2.0 * c, 2.0 * v, 2.0 * z)
    for name, got in (("jit", jax.jit(grads)(c, v, z)), ("checkpoint", jax.jit(jax.checkpoint(grads))(c, v, z)), ("vmap 0", [b[0] for b in batched])):
        for g, e in zip(got, eager):
            np.testing.assert_allclose(np.asarray(g), np.asarray(e), rtol=0, atol=1e-12, err_msg=name)
    for g, e in zip([b[1] for b in batched], second):
        np.testing.assert_allclose(np.asarray(g), np.asarray(e), rtol=0, atol=1e-12, err_msg="vmap 1")
