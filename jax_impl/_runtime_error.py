"""Raise a data error under `jax.jit` with the library's message first.

A check on traced values can only fail when the computation runs. Through a host callback (what
`equinox.error_if` uses) XLA reports the failure as "INTERNAL: CpuCallback error calling callback:
Traceback ...", the message buried after a traceback. An XLA FFI handler can instead return an
error status of its own: XLA raises `JaxRuntimeError("INVALID_ARGUMENT: <message>")`, the same
under `jax.jit`, `eqx.filter_jit`, `vmap`, `grad` and `checkpoint`.

The handler is a ctypes function that reads XLA's call frame (the C structs of
xla/ffi/api/c_api.h, FFI API 0.x): argument 0 holds the per-example flags, argument 1 the message
as NUL-terminated bytes, and the one result is zeros that the checked array adds, which orders the
check before anything that reads the array. It runs only in the execute stage; the registration's
metadata query gets the API version it was written against.
"""

from __future__ import annotations

import ctypes
import os

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

_TARGET = "diffblur_raise_if"
_EXTENSION_METADATA = 1  # XLA_FFI_Extension_Metadata
_INVALID_ARGUMENT = 3  # XLA_FFI_Error_Code_INVALID_ARGUMENT
_API_VERSION = (0, 1)  # the oldest FFI API version with everything read here


class _ExtensionBase(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_size_t), ("type", ctypes.c_int), ("next", ctypes.c_void_p)]


class _ApiVersion(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_size_t), ("extension_start", ctypes.c_void_p), ("major", ctypes.c_int), ("minor", ctypes.c_int)]


class _Metadata(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_size_t), ("api_version", _ApiVersion), ("traits", ctypes.c_uint32)]


class _MetadataExtension(ctypes.Structure):
    _fields_ = [("base", _ExtensionBase), ("metadata", ctypes.POINTER(_Metadata))]


class _Buffer(ctypes.Structure):
    _fields_ = [
        ("struct_size", ctypes.c_size_t),
        ("extension_start", ctypes.c_void_p),
        ("dtype", ctypes.c_int),
        ("data", ctypes.c_void_p),
        ("rank", ctypes.c_int64),
        ("dims", ctypes.POINTER(ctypes.c_int64)),
    ]


class _Buffers(ctypes.Structure):  # XLA_FFI_Args and XLA_FFI_Rets share this layout
    _fields_ = [
        ("struct_size", ctypes.c_size_t),
        ("extension_start", ctypes.c_void_p),
        ("size", ctypes.c_int64),
        ("types", ctypes.c_void_p),
        ("buffers", ctypes.POINTER(ctypes.POINTER(_Buffer))),
    ]


class _CallFrame(ctypes.Structure):
    _fields_ = [
        ("struct_size", ctypes.c_size_t),
        ("extension_start", ctypes.POINTER(_ExtensionBase)),
        ("api", ctypes.c_void_p),
        ("ctx", ctypes.c_void_p),
        ("stage", ctypes.c_int),
        ("args", _Buffers),
        ("rets", _Buffers),
    ]


class _ErrorCreateArgs(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_size_t), ("extension_start", ctypes.c_void_p), ("message", ctypes.c_char_p), ("errc", ctypes.c_int)]


_ERROR_CREATE_ARGS_SIZE = 28  # offset of errc + its 4 bytes: XLA's STRUCT_SIZE, without padding
# XLA_FFI_Api: struct_size, extension_start, api_version (24 bytes), internal_api, then
# XLA_FFI_Error_Create, the first function pointer.
_ERROR_CREATE_OFFSET = 8 + 8 + ctypes.sizeof(_ApiVersion) + 8
_ErrorCreate = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.POINTER(_ErrorCreateArgs))
_Handler = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.POINTER(_CallFrame))


def _size(buffer: _Buffer) -> int:
    return int(np.prod([buffer.dims[i] for i in range(buffer.rank)], dtype=np.int64))


def _handle(frame_pointer):
    frame = frame_pointer.contents
    if frame.extension_start and frame.extension_start.contents.type == _EXTENSION_METADATA:
        version = ctypes.cast(frame.extension_start, ctypes.POINTER(_MetadataExtension)).contents.metadata.contents.api_version
        version.major, version.minor = _API_VERSION
        return None
    flags, message = frame.args.buffers[0].contents, frame.args.buffers[1].contents
    zeros = frame.rets.buffers[0].contents
    ctypes.memset(zeros.data, 0, _size(zeros))
    if not any(ctypes.cast(flags.data, ctypes.POINTER(ctypes.c_uint8))[: _size(flags)]):
        return None
    create = _ErrorCreate(ctypes.cast(frame.api + _ERROR_CREATE_OFFSET, ctypes.POINTER(ctypes.c_void_p)).contents.value)
    return create(ctypes.byref(_ErrorCreateArgs(_ERROR_CREATE_ARGS_SIZE, None, ctypes.cast(message.data, ctypes.c_char_p).value, _INVALID_ARGUMENT)))


_HANDLER = _Handler(_handle)  # kept alive for as long as XLA may call it


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
    return x + zeros.sum().astype(x.dtype)
