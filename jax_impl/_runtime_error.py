"""Raise a data error under `jax.jit` with the library's message first.

A check on traced values can only fail when the computation runs. Through a host callback (what
`equinox.error_if` uses) XLA reports the failure as "INTERNAL: CpuCallback error calling callback:
Traceback ...", the message buried after a traceback. An XLA FFI handler can instead return an
error status of its own: XLA raises `JaxRuntimeError("INVALID_ARGUMENT: <message>")`, the same
under `jax.jit`, `eqx.filter_jit`, `vmap`, `grad` and `checkpoint`.

The handler is a ctypes function that reads XLA's call frame (`jax_impl._ffi`): argument 0 holds
the per-example flags, argument 1 the message as NUL-terminated bytes, and the one result is zeros
that pass through an optimization barrier with the checked array, which orders the check before
anything that reads the array.
"""

from __future__ import annotations

import ctypes
import os

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jax_impl._ffi import Handler, answered_metadata, error, size

_TARGET = "diffblur_raise_if"


def _handle(frame_pointer):
    frame = frame_pointer.contents
    if answered_metadata(frame):
        return None
    flags, message = frame.args.buffers[0].contents, frame.args.buffers[1].contents
    zeros = frame.rets.buffers[0].contents
    ctypes.memset(zeros.data, 0, size(zeros))
    if not any(ctypes.cast(flags.data, ctypes.POINTER(ctypes.c_uint8))[: size(flags)]):
        return None
    return error(frame, ctypes.cast(message.data, ctypes.c_char_p).value)


_HANDLER = Handler(_handle)  # kept alive for as long as XLA may call it


def _register() -> bool:
    try:
        jax.ffi.register_ffi_target(_TARGET, jax.ffi.pycapsule(ctypes.cast(_HANDLER, ctypes.c_void_p).value), platform="cpu")
    except Exception:  # an XLA without this FFI API: equinox's callback still raises, message later
        return False
    return True


_REGISTERED = _register()


def raise_if(x: jax.Array, bad: jax.Array, message: str) -> jax.Array:
    """`x`, made to depend on a check that raises `JaxRuntimeError("INVALID_ARGUMENT: " + message)`
    when the computation runs with `bad` true. Use the returned array in place of `x`.

    Falls back to `equinox.error_if` off the CPU, where the handler is not registered; with more
    than one device, where XLA's SPMD partitioner refuses a side-effecting call without a sharding;
    and when `EQX_ON_ERROR` asks equinox for something other than raising (e.g. `nan`)."""
    if not _REGISTERED or jax.default_backend() != "cpu" or jax.device_count() > 1 or os.environ.get("EQX_ON_ERROR", "raise") != "raise":
        return eqx.error_if(x, bad, message)
    text = np.frombuffer(message.encode() + b"\0", np.uint8)
    flags = jax.lax.stop_gradient(bad).astype(jnp.uint8)
    call = jax.ffi.ffi_call(_TARGET, jax.ShapeDtypeStruct(flags.shape, jnp.uint8), has_side_effect=True, vmap_method="expand_dims")
    # The handler (Python, under the GIL) runs only when a flag is set; under vmap the predicate is
    # batched and both branches run, the handler then checking the flags itself.
    zeros = jax.lax.cond(jnp.any(flags), lambda: call(flags, text), lambda: jnp.zeros_like(flags))
    # The barrier makes x's readers wait for the check without a copy of x (adding the zeros to x
    # wrote one: a 720p velocity's 7 MB before a kernel that reads it).
    checked, _ = jax.lax.optimization_barrier((x, zeros))
    return checked
