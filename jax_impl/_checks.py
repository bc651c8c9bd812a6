"""Reads the facts the shared checks in `diffblur.checks` need off JAX arrays.

Checks that look at the data (signs, finiteness) raise ValueError on concrete arrays; under
`jax.jit` (traced arrays) they raise when the computation runs, through `_runtime_error.raise_if`
(XLA's `JaxRuntimeError` whose text starts with the library's message).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from diffblur import checks

from ._runtime_error import raise_if


def array(name: str, x: object) -> jax.Array:
    """A jax.Array; a NumPy array is converted (as jax.numpy functions do), anything else refused."""
    if isinstance(x, np.ndarray):
        return jnp.asarray(x)
    if not isinstance(x, jax.Array):
        raise TypeError(f"{name} must be a jax.Array, got {type(x).__name__}")
    return x


def floating_array(name: str, x: object) -> jax.Array:
    x = array(name, x)
    checks.require_floating(name, x.dtype, jnp.issubdtype(x.dtype, jnp.floating))
    return x


def image(name: str, x: object, *, channels: int | None = None) -> jax.Array:
    """A floating (B, C, H, W) array, with `channels` channels if given."""
    x = floating_array(name, x)
    checks.require_image(name, x.shape, channels=channels)
    return x


def same_dtype(name: str, x: jax.Array, reference_name: str, reference: jax.Array) -> None:
    checks.require_same_dtype(name, x.dtype, reference_name, reference.dtype)


def same_shape(name: str, x: jax.Array, reference_name: str, reference: jax.Array) -> None:
    checks.require_same_shape(name, x.shape, reference_name, reference.shape)
    same_dtype(name, x, reference_name, reference)


def data_check(x: jax.Array, bad: jax.Array, message: str) -> jax.Array:
    """Raise ValueError(message) now if `bad`, or JaxRuntimeError("INVALID_ARGUMENT: " + message)
    at run time under jit.

    Tests `bad`, not `x`: inside jit even a concrete x gives a traced `bad`. Returns `x`, which
    under jit must be used in place of the input to keep the check alive."""
    if isinstance(bad, jax.core.Tracer):
        return raise_if(x, bad, message)
    if bool(bad):
        raise ValueError(message)
    return x


def positive_values(name: str, x: jax.Array) -> jax.Array:
    """Raise if any element is <= 0 or NaN (see `data_check`)."""
    return data_check(x, jnp.logical_not(jnp.all(x > 0)), checks.nonpositive_message(name))


def finite_values(name: str, x: jax.Array, *, carry: jax.Array | None = None) -> jax.Array:
    """Raise if any element is NaN or infinite (see `data_check`). Returns x, or `carry` with the check
    attached when given: under a sharded jax.jit the array a check returns is gathered onto one
    device, and the colour, whose sharding the output follows, must keep its own. Its check rides on
    an argument the other checks gather anyway (velocity, depth); only a flag crosses devices."""
    return data_check(x if carry is None else carry, jnp.logical_not(jnp.all(jnp.isfinite(x))), checks.nonfinite_message(name))


def positive_scalar(name: str, value: object, like: jax.Array) -> float | jax.Array:
    """A Python number > 0, or a 0-d array / array of `like`'s shape with values > 0."""
    if isinstance(value, (jax.Array, np.ndarray)):
        value = array(name, value)
        if value.ndim != 0:
            same_shape(name, value, "the compared arrays", like)
        else:
            same_dtype(name, floating_array(name, value), "the compared arrays", like)
        return positive_values(name, value)
    return checks.require_positive_number(name, value)


def per_batch_scalar(name: str, value: object, like: jax.Array) -> float | jax.Array:
    """A Python number, a 0-d array, or a (B,) array reshaped to broadcast over (B, C, H, W)."""
    if isinstance(value, (jax.Array, np.ndarray)):
        value = floating_array(name, value)
        same_dtype(name, value, "the input", like)
        if value.ndim == 0:
            return value
        if value.ndim == 1 and value.shape[0] == like.shape[0]:
            return value.reshape(-1, 1, 1, 1)
        raise ValueError(f"{name} must be a number, a 0-d array or a (B,) array with B={like.shape[0]}, got shape {tuple(value.shape)}")
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        raise TypeError(f"{name} must be a real number or a jax.Array, got {value!r}")
    return float(value)
