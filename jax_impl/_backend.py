"""The JAX `Backend` (`diffblur.ops.backend`): what the ops, written once in `diffblur.ops`, need from
JAX that torch spells or does differently.

Value checks (signs, finiteness) raise ValueError on concrete arrays; under `jax.jit` (traced
arrays) they raise when the computation runs, through `_runtime_error.raise_if` (XLA's
`JaxRuntimeError` whose text starts with the library's message). A checked array must be used in
place of the input, or the check is dropped with it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from diffblur import checks

from ._runtime_error import raise_if


def _data_check(x: Array, bad: Array, message: str) -> Array:
    """Raise ValueError(message) now if `bad`, or JaxRuntimeError("INVALID_ARGUMENT: " + message) at
    run time under jit. Tests `bad`, not `x`: inside jit even a concrete x gives a traced `bad`."""
    if isinstance(bad, jax.core.Tracer):
        return raise_if(x, bad, message)
    if bool(bad):
        raise ValueError(message)
    return x


class JaxBackend:
    name = "jax"
    xp = jnp
    half = (jnp.float16, jnp.bfloat16)
    compiler = "jax.jit"
    array_word = "array"
    array_type_name = "jax.Array"

    # -- argument facts and value checks ------------------------------------------------------------

    @staticmethod
    def array(name: str, x: object) -> Array:
        """A jax.Array; a NumPy array is converted (as jax.numpy functions do), anything else refused."""
        if isinstance(x, np.ndarray):
            return jnp.asarray(x)
        if not isinstance(x, jax.Array):
            raise TypeError(f"{name} must be a jax.Array, got {type(x).__name__}")
        return x

    @staticmethod
    def is_array(x: object) -> bool:
        return isinstance(x, (jax.Array, np.ndarray))

    @staticmethod
    def is_floating(x: Array) -> bool:
        return bool(jnp.issubdtype(x.dtype, jnp.floating))

    @staticmethod
    def require_same_device(name: str, x: Array, reference_name: str, reference: Array) -> None:
        """JAX places arrays itself; nothing to check."""

    @staticmethod
    def check_positive(name: str, x: Array) -> Array:
        """x with the check that every element is > 0 (not NaN) attached."""
        return _data_check(x, jnp.logical_not(jnp.all(x > 0)), checks.nonpositive_message(name))

    @staticmethod
    def check_finite(name: str, x: Array, *, carry: Array | None = None) -> Array:
        """x, or `carry`, with the check that every element of x is finite attached. Under a sharded
        jax.jit the array a check returns is gathered onto one device, so the colour, whose sharding
        the output follows, carries its check on an argument the other checks gather anyway
        (velocity, depth): only a flag crosses devices."""
        return _data_check(x if carry is None else carry, jnp.logical_not(jnp.all(jnp.isfinite(x))), checks.nonfinite_message(name))

    @staticmethod
    def is_tracing(x: object = None) -> bool:
        """Whether x is traced (under jax.jit, its values are not known now)."""
        return isinstance(x, jax.core.Tracer)

    @staticmethod
    def values(x: Array) -> np.ndarray | None:
        """x's values as NumPy when they are known now (not under jax.jit), else None."""
        try:
            return np.asarray(jax.lax.stop_gradient(x))
        except jax.errors.TracerArrayConversionError:
            return None

    # -- arrays -------------------------------------------------------------------------------------

    @property
    def default_float(self) -> Any:
        return jnp.zeros(()).dtype

    @staticmethod
    def astype(x: Array, dtype: Any) -> Array:
        return x.astype(dtype)

    @staticmethod
    def index(x: Array) -> Array:
        """Integer positions (for indexing) from floats already rounded."""
        return x.astype(jnp.int32)

    stop_gradient = staticmethod(jax.lax.stop_gradient)

    @staticmethod
    def arange(n: int, dtype: Any, like: Array | None = None) -> Array:
        return jnp.arange(n, dtype=dtype)

    @staticmethod
    def asarray(value: Any, dtype: Any, like: Array | None = None) -> Array:
        return jnp.asarray(value, dtype=dtype)

    @staticmethod
    def zeros(shape: tuple[int, ...], dtype: Any, like: Array | None = None) -> Array:
        return jnp.zeros(shape, dtype=dtype)

    @staticmethod
    def on_device(x: Array, device: Any) -> Array:
        return jax.device_put(x, device)

    @staticmethod
    def concat(arrays: list[Array], axis: int) -> Array:
        return jnp.concatenate(arrays, axis=axis)

    @staticmethod
    def permute(x: Array, axes: tuple[int, ...]) -> Array:
        return x.transpose(axes)

    @staticmethod
    def repeat(x: Array, count: int, axis: int) -> Array:
        return jnp.repeat(x, count, axis=axis)

    @staticmethod
    def pad(x: Array, widths: tuple[tuple[int, int], ...], *, value: float = 0.0, mode: str = "constant") -> Array:
        """x padded by (before, after) per axis; mode "constant" (value) or "edge"."""
        if mode == "edge":
            return jnp.pad(x, widths, mode="edge")
        return jnp.pad(x, widths, constant_values=value)

    @staticmethod
    def argmax(x: Array, axis: int) -> Array:
        return jnp.argmax(x, axis=axis, keepdims=True)

    @staticmethod
    def pick_along(x: Array, index: Array, axis: int) -> Array:
        """x's values at `index` along `axis` (index has size 1 there and broadcasts elsewhere), the
        axis removed."""
        return jnp.squeeze(jnp.take_along_axis(x, index, axis=axis), axis)

    @staticmethod
    def read_pixels(flat: Array, index: Array) -> Array:
        """flat (B, C, N) at integer indices (B, ...) into N -> (B, C, ...).

        Reads whole pixels (C values) channels-last: one index per pixel, not one per value. The same
        values as a per-channel take_along_axis, but XLA's CPU scatter-add (the gradient) and gather
        then move C-vectors: measured 1.6x faster forward+backward and 3x faster forward for
        reconstruct at 640x360, S=15."""
        batch, channels, _ = flat.shape
        pixels = jnp.take_along_axis(jnp.swapaxes(flat, 1, 2), index.reshape(batch, -1, 1), axis=1)  # (B, N', C)
        return jnp.swapaxes(pixels, 1, 2).reshape(batch, channels, *index.shape[1:])

    @staticmethod
    def constant(function: Callable, *args: Any) -> Any:
        """function(*args) of Python values (computed at trace time: a constant to XLA)."""
        return function(*args)


JAX = JaxBackend()
