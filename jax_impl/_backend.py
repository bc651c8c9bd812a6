"""The JAX `Backend` (`diffblur.ops.backend`): what the ops, written once in `diffblur.ops`, need from
JAX that torch spells or does differently.

Value checks (signs, finiteness) raise ValueError on concrete arrays; under `jax.jit` (traced
arrays) they raise when the computation runs, through `_runtime_error.raise_if` (XLA's
`JaxRuntimeError` whose text starts with the library's message). A checked array must be used in
place of the input, or the check is dropped with it.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from diffblur import checks, reference
from diffblur.ops.backend import Backend

from ._runtime_error import raise_if


def _data_check(x: Array, bad: Array, message: str) -> Array:
    """Raise ValueError(message) now if `bad`, or JaxRuntimeError("INVALID_ARGUMENT: " + message) at
    run time under jit; nothing inside `diffblur.without_host_reads`. Tests `bad`, not `x`: inside
    jit even a concrete x gives a traced `bad`."""
    if not checks.host_reads_allowed():
        return x
    if isinstance(bad, jax.core.Tracer):
        return raise_if(x, bad, message)
    if bool(bad):
        raise ValueError(message)
    return x


@functools.lru_cache(maxsize=16)
def _noise_jitter(height: int, width: int, dtype: Any) -> Array:
    with jax.ensure_compile_time_eval():  # a concrete array, also when first asked for under jax.jit
        return jnp.asarray(reference.noise_jitter(height, width).astype(dtype)).reshape(1, 1, height, width)


class JaxBackend(Backend):

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
    def is_integer(x: Array) -> bool:
        return bool(jnp.issubdtype(x.dtype, jnp.integer))

    @staticmethod
    def require_same_device(name: str, x: Array, reference_name: str, reference: Array) -> None:
        """JAX places arrays itself; nothing to check."""

    @staticmethod
    def check_values(x: Array, ok: Array, message: str) -> Array:
        """x with the check that `ok` (a bool of one element, computed from data) holds attached."""
        return _data_check(x, jnp.logical_not(ok), message)

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
        """x's values as NumPy when they are known now (not under jax.jit, not inside
        `diffblur.without_host_reads`), else None."""
        if not checks.host_reads_allowed():
            return None
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

    @staticmethod
    def argmax(x: Array, axis: int) -> Array:
        return jnp.argmax(x, axis=axis, keepdims=True)

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
    def take_along(x: Array, index: Array, axis: int) -> Array:
        return jnp.take_along_axis(x, index, axis=axis)

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
    def contiguous(x: Array) -> Array:
        return x

    @staticmethod
    def row_indices(pixels: np.ndarray, total: int, like: Array) -> tuple[Array, Array]:
        """A class's flat pixel indices, padded up to one of 8 sizes per octave (at most 1/8 more
        work, few sizes to compile): the rows to read (the padding reads pixel 0) and to write (the
        padding points past the end, which `write_rows` drops)."""
        step = 1 << max(int(pixels.size).bit_length() - 4, 0)
        size = -(-pixels.size // step) * step
        read = np.zeros(size, dtype=np.int32)
        write = np.full(size, total, dtype=np.int32)
        read[: pixels.size] = pixels
        write[: pixels.size] = pixels
        return jnp.asarray(read), jnp.asarray(write)

    @staticmethod
    def write_rows(rows: Array, index: Array, values: Array) -> Array:
        return rows.at[index].set(values, mode="drop")

    @staticmethod
    def constant(function: Callable, *args: Any) -> Any:
        """function(*args) of Python values (computed at trace time: a constant to XLA)."""
        return function(*args)

    @staticmethod
    def outside_compiler(function: Callable, reason: str) -> Callable:
        """The function as it is: what torch.compile miscompiles, XLA compiles right."""
        return function

    @staticmethod
    @functools.cache
    def compiled(function: Callable, static_argnames: tuple[str, ...]) -> Callable:
        """The function under jax.jit (one per function and static names), so that an eager call runs
        one compiled program."""
        return jax.jit(function, static_argnames=static_argnames)

    @staticmethod
    def needs_gradient(*arrays: Array) -> bool:
        """True: JAX may differentiate any computation later (jax.grad, jax.vjp of the caller's)."""
        return True

    @staticmethod
    def sum_taps(tap: Callable, taps: list[int], carry: tuple[Array, Array], arrays: tuple, *, recompute: bool) -> tuple[Array, Array]:
        """carry + the sum of tap(k, *arrays) over the taps. With `recompute`, a `lax.scan` over the
        tap indices (traced, not unrolled) of the checkpointed tap: each tap is recomputed in the
        backward pass, which keeps only the loop's inputs, and the accumulation is a sum, so its VJP
        needs none of the carries. Else a Python loop."""
        if not recompute or not taps:
            weight, total = carry
            for k in taps:
                alpha, contribution = tap(k, *arrays)
                weight, total = weight + alpha, total + contribution
            return weight, total
        step = jax.checkpoint(tap)

        def accumulate(sums, k):
            alpha, contribution = step(k, *arrays)
            return (sums[0] + alpha, sums[1] + contribution), None

        sums, _ = jax.lax.scan(accumulate, carry, jnp.asarray(taps, dtype=jnp.int32))
        return sums

    @staticmethod
    def noise_jitter(height: int, width: int, like: Array) -> Array:
        """reconstruct's "noise" jitter (1, 1, H, W) in like's dtype: the NumPy oracle's array (float64,
        which JAX without x64 cannot compute), kept per size and dtype; a constant under jax.jit."""
        return _noise_jitter(height, width, jnp.dtype(like.dtype))

    @staticmethod
    def band(number: float, like: Array) -> Array:
        """A depth band given as a number, as the ops compute with it: a 0-d array of like's dtype
        (an argument of the compiled op, not a constant baked into it)."""
        return jnp.asarray(number, dtype=like.dtype)

    @staticmethod
    def per_channel(alpha: Array, channels: int) -> Array:
        """The scatter's weight (B, 1, H, W) copied for `channels` colour channels rather than
        broadcast: the gradient of a broadcast over the channel axis is a reduce over that leading
        axis, two of which took 72 ms of the backward at 1280x720 (XLA:CPU)."""
        return jnp.concatenate([alpha] * channels, axis=1)

    @staticmethod
    def scatter_add(size: int, index: Array, values: Array) -> Array:
        """(size, V) zeros with values (N, V) added at the rows `index` (N,)."""
        return jnp.zeros((size, values.shape[1]), dtype=values.dtype).at[index].add(values)

    @staticmethod
    def scatter_min(size: int, index: Array, values: Array) -> Array:
        """(size,) of +inf holding the smallest of values (N,) at each row `index` (N,)."""
        return jnp.full((size,), jnp.inf, dtype=values.dtype).at[index].min(values)

    @staticmethod
    def sum_chunks(splat: Callable, times: Array, masses: Array, chunk: int, fixed: tuple, start: Array) -> Array:
        """start + the sum of splat(times, masses, *fixed) over chunks of `chunk` points. One call
        when one chunk holds them all; else a `lax.scan` over the chunks, which XLA runs one after
        the other (one chunk's buffers at a time), each checkpointed so that the backward keeps only
        the loop's inputs. The last chunk is padded with points of mass 0."""
        samples = times.shape[0]
        if chunk >= samples:
            return start + splat(times, masses, *fixed)
        count = -(-samples // chunk)
        pad = count * chunk - samples
        times = jnp.concatenate([times, jnp.zeros(pad, dtype=times.dtype)]).reshape(count, chunk)
        masses = jnp.concatenate([masses, jnp.zeros(pad, dtype=masses.dtype)]).reshape(count, chunk)
        step = jax.checkpoint(lambda total, part: (total + splat(*part, *fixed), None))
        total, _ = jax.lax.scan(step, start, (times, masses))
        return total

    @staticmethod
    def widen_window(window: Any, dtype: Any) -> Any:
        """The shutter window with its array parameters (being fitted) cast to `dtype`, so that its
        weights at times of that dtype need no mixed-type arithmetic (strict dtype promotion)."""
        if not dataclasses.is_dataclass(window):
            return window
        arrays = {f.name: getattr(window, f.name) for f in dataclasses.fields(window) if isinstance(getattr(window, f.name), jax.Array)}
        return dataclasses.replace(window, **{name: value.astype(dtype) for name, value in arrays.items()}) if arrays else window

    # -- the fused CPU kernels (`jax_impl._fused`, `jax_impl._fused_scatter`) --------------------------

    def bindings(self) -> tuple[Any, Any]:
        from jax_impl import _fused, _fused_scatter

        return _fused, _fused_scatter


JAX = JaxBackend("jax", jnp, half=(jnp.float16, jnp.bfloat16), compiler="jax.jit", integer=jnp.int32, array_word="array", array_type_name="jax.Array")
