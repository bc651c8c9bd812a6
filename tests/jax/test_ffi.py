"""`jax_impl._ffi.host_target`: a Python function as an XLA FFI handler writes its results straight
into XLA's buffers, under jit and vmap, and its exceptions reach the caller as XLA errors with
their message."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jax_impl._ffi import host_target


def _scaled_and_summed(arguments, results):
    values, scale = arguments
    assert not values.flags.writeable and results[0].flags.writeable
    np.multiply(values, scale, out=results[0])
    results[1][...] = values.sum(axis=-1)


def _call(values, scale):
    shapes = (jax.ShapeDtypeStruct(values.shape, values.dtype), jax.ShapeDtypeStruct(values.shape[:-1], values.dtype))
    return jax.ffi.ffi_call(host_target(_scaled_and_summed), shapes, vmap_method="sequential")(values, scale)


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int32])
def test_results_are_written_in_place_under_jit_and_vmap(dtype):
    values = jnp.asarray(np.arange(24).reshape(2, 3, 4).astype(dtype))
    scale = jnp.asarray(3, dtype=dtype)
    scaled, sums = jax.jit(_call)(values, scale)
    np.testing.assert_array_equal(np.asarray(scaled), np.asarray(values) * 3)
    np.testing.assert_array_equal(np.asarray(sums), np.asarray(values).sum(axis=-1))
    batched, batched_sums = jax.jit(jax.vmap(_call, in_axes=(0, None)))(values, scale)
    np.testing.assert_array_equal(np.asarray(batched), np.asarray(scaled))
    np.testing.assert_array_equal(np.asarray(batched_sums), np.asarray(sums))


def _refuse(arguments, results):
    raise ValueError(f"refused {arguments[0].shape}")


def test_an_exception_becomes_an_error_with_its_message():
    call = jax.ffi.ffi_call(host_target(_refuse), jax.ShapeDtypeStruct((2,), jnp.float32))
    with pytest.raises(jax.errors.JaxRuntimeError, match=r"ValueError: refused \(2,\)"):
        jax.block_until_ready(jax.jit(call)(jnp.zeros(2, jnp.float32)))


def test_one_target_per_function():
    assert host_target(_scaled_and_summed) == host_target(_scaled_and_summed)
    assert host_target(_scaled_and_summed) != host_target(_refuse)
