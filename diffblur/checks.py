"""Argument checks shared by both backends.

The `require_*` checks take facts (a shape, a dtype and whether it is floating, a Python value).
The array checks at the end (`floating_array`, `image_array`, ...) take arrays with the `Backend`
that reads those facts off them (`diffblur.ops.backend`), so this module stays free of torch and
jax. Every message names the argument, the value it got and what is allowed, e.g.
``samples must be an odd integer >= 1, got 4``.
"""

from __future__ import annotations

import contextvars
import math
import os
import sys
import numbers
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

__all__ = [
    "host_reads_allowed",
    "nonpositive_message",
    "nonfinite_message",
    "require_choice",
    "require_floating",
    "require_image",
    "require_nonnegative_number",
    "require_odd_int",
    "require_positive_int",
    "require_positive_number",
    "require_same_dtype",
    "require_same_shape",
    "require_same_batch_and_size",
    "without_host_reads",
]

_HOST_READS = contextvars.ContextVar("diffblur_host_reads", default=True)


@contextmanager
def without_host_reads() -> Iterator[None]:
    """A block in which the ops read no array values back to the host (Python), so that on a GPU
    they queue their work without waiting for it: no device-to-host copy, no synchronisation.

    Inside it the ops skip what needs values, as they do when compiled: the data checks (NaN or
    infinity, non-positive depth, id ranges: bad data then gives what the formulas give, never an
    out-of-bounds read), bezier_scatter's warning for an image without still pixels, and the
    compaction of adaptive sampling (every tile class runs on every pixel and each tile keeps its
    own, the same result). bezier_scatter's samples=None, which measures the curves, raises; pass
    an int. Under jax.jit it applies where a function is traced, since the trace is cached; under
    torch.compile it changes nothing (the compiled checks are asserts in the graph, on CPU tensors
    only). The fused CPU kernels run on host arrays and are not affected."""
    token = _HOST_READS.set(False)
    try:
        yield
    finally:
        _HOST_READS.reset(token)


def host_reads_allowed() -> bool:
    """False inside `without_host_reads`."""
    return _HOST_READS.get()


def _is_real_number(value: object) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def require_image(name: str, shape: Sequence[int], *, channels: int | None = None) -> tuple[int, ...]:
    """Check that `shape` is (B, C, H, W), non-empty, with `channels` channels if given."""
    shape = tuple(int(s) for s in shape)
    layout = f"(B, {channels}, H, W)" if channels is not None else "(B, C, H, W)"
    if len(shape) != 4:
        raise ValueError(f"{name} must be a 4-d {layout} array, got shape {shape}")
    if channels is not None and shape[1] != channels:
        raise ValueError(f"{name} must have {channels} channel(s) in dim 1, {layout}, got shape {shape}")
    if min(shape) == 0:
        raise ValueError(f"{name} must not be empty, got shape {shape}")
    return shape


def require_floating(name: str, dtype: object, is_floating: bool) -> None:
    """Check that an array's dtype is floating (integer images must be converted by the caller)."""
    if not is_floating:
        raise TypeError(
            f"{name} must have a floating dtype (float16, bfloat16, float32 or float64), got {dtype}; "
            "convert integer images explicitly, e.g. divide uint8 by 255"
        )


def require_same_dtype(name: str, dtype: object, reference_name: str, reference_dtype: object) -> None:
    """Check that two arrays share a dtype (no silent promotion inside an op)."""
    if str(dtype) != str(reference_dtype):
        raise TypeError(f"{name} must have the dtype of {reference_name} ({reference_dtype}), got {dtype}")


def require_same_shape(name: str, shape: Sequence[int], reference_name: str, reference_shape: Sequence[int]) -> None:
    """Check that two arrays have exactly the same shape (no broadcasting)."""
    if tuple(shape) != tuple(reference_shape):
        raise ValueError(
            f"{name} must have the shape of {reference_name} {tuple(reference_shape)}, got {tuple(shape)}"
        )


def require_same_batch_and_size(
    reference_name: str, reference_shape: Sequence[int], others: Iterable[tuple[str, Sequence[int]]]
) -> None:
    """Check that (B, C, H, W) arrays share B, H and W with the reference (C may differ)."""
    b, _, h, w = reference_shape
    for name, shape in others:
        if (shape[0], shape[2], shape[3]) != (b, h, w):
            if (shape[0], shape[2], shape[3]) == tuple(reference_shape[:3]):
                # The reference's dims 1 and 2 are the others' H and W: it was given channels last.
                raise ValueError(
                    f"{reference_name} looks channels-last (B, H, W, C), got shape {tuple(reference_shape)} with "
                    f"{name} {tuple(shape)}; the ops take NCHW (B, C, H, W): transpose {reference_name} with (0, 3, 1, 2)"
                )
            raise ValueError(
                f"{name} must match {reference_name} in batch and size (B={b}, H={h}, W={w}), "
                f"got shape {tuple(shape)}"
            )


def require_positive_int(name: str, value: object) -> int:
    """Check that `value` is an integer >= 1 (bools are rejected)."""
    if not isinstance(value, numbers.Integral) or isinstance(value, bool):
        raise TypeError(f"{name} must be an integer >= 1, got {value!r}")
    if value < 1:
        raise ValueError(f"{name} must be an integer >= 1, got {value}")
    return int(value)


def require_odd_int(name: str, value: object) -> int:
    """Check that `value` is an odd integer >= 1, as the filter's tap counts are."""
    if not isinstance(value, numbers.Integral) or isinstance(value, bool):
        raise TypeError(f"{name} must be an odd integer >= 1, got {value!r}")
    if value < 1 or value % 2 == 0:
        raise ValueError(f"{name} must be an odd integer >= 1, got {value}")
    return int(value)


def require_positive_number(name: str, value: object) -> float:
    """Check that a Python number is finite and > 0 (math.inf is allowed only where documented)."""
    if not _is_real_number(value):
        raise TypeError(f"{name} must be a real number > 0, got {value!r}")
    if not value > 0 or math.isnan(value):
        raise ValueError(f"{name} must be > 0, got {value}")
    return float(value)


def require_nonnegative_number(name: str, value: object) -> float:
    """Check that a Python number is >= 0 and not NaN."""
    if not _is_real_number(value):
        raise TypeError(f"{name} must be a real number >= 0, got {value!r}")
    if not value >= 0:
        raise ValueError(f"{name} must be >= 0, got {value}")
    return float(value)


def require_choice(name: str, value: object, allowed: Sequence[str]) -> str:
    """Check that `value` is one of the allowed option strings."""
    if value not in allowed:
        raise ValueError(f"{name} must be one of {', '.join(repr(a) for a in allowed)}; got {value!r}")
    return str(value)


def nonpositive_message(name: str) -> str:
    """The message for an array argument that must be > 0 everywhere (checked on the data)."""
    return f"{name} must be > 0 everywhere, got a value <= 0 (or NaN)"


def nonfinite_message(name: str) -> str:
    """The message for an array argument that must be finite everywhere (checked on the data)."""
    return f"{name} must be finite everywhere, got NaN or infinity"


def require_in_interval(name: str, value: object, low: float, high: float) -> float:
    """Check that a Python number lies in the closed interval [low, high] (NaN is rejected)."""
    if not _is_real_number(value):
        raise TypeError(f"{name} must be a real number in [{low}, {high}], got {value!r}")
    if not low <= value <= high:
        raise ValueError(f"{name} must be in [{low}, {high}], got {value}")
    return float(value)


__all__ += ["require_in_interval"]


def require_finite_number(name: str, value: object) -> float:
    """Check that `value` is a finite real Python number (bools are rejected)."""
    if not _is_real_number(value):
        raise TypeError(f"{name} must be a finite real number, got {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value}")
    return float(value)


__all__ += ["require_finite_number"]


def require_int_choice(name: str, value: object, allowed: Sequence[int]) -> int:
    """Check that `value` is an integer (not a bool) among `allowed`, e.g. a curve degree."""
    listed = ", ".join(str(a) for a in allowed)
    if not isinstance(value, numbers.Integral) or isinstance(value, bool):
        raise TypeError(f"{name} must be an integer, one of {listed}; got {value!r}")
    if int(value) not in allowed:
        raise ValueError(f"{name} must be one of {listed}; got {value}")
    return int(value)


__all__ += ["require_int_choice"]


def depth_band(soft_z_extent: object, relative_z_extent: object) -> tuple[bool, object]:
    """Which depth band soft_depth_compare takes: (relative, extent).

    soft_z_extent given (not None): the band in depth units, (False, soft_z_extent). Else the band
    relative to depth, (True, relative_z_extent): the backends compare log depths with the band
    log(1 + relative_z_extent), so that z_b counts as in front of z_a up to z_b = z_a (1 + r) and
    rescaling depth changes nothing. Numbers are checked here (> 0); arrays by the backend."""
    if soft_z_extent is not None:
        if _is_real_number(soft_z_extent) or isinstance(soft_z_extent, bool):
            soft_z_extent = require_positive_number("soft_z_extent", soft_z_extent)
        return False, soft_z_extent
    if _is_real_number(relative_z_extent) or isinstance(relative_z_extent, bool):
        relative_z_extent = require_positive_number("relative_z_extent", relative_z_extent)
    return True, relative_z_extent


def floating_array(be, name: str, x: object):
    """x as the backend's array (`be.array` refuses other types), with a floating dtype."""
    x = be.array(name, x)
    require_floating(name, x.dtype, be.is_floating(x))
    return x


def image_array(be, name: str, x: object, *, channels: int | None = None):
    """A floating (B, C, H, W) array, with `channels` channels if given."""
    x = floating_array(be, name, x)
    require_image(name, x.shape, channels=channels)
    return x


def same_dtype_and_device(be, name: str, x, reference_name: str, reference) -> None:
    """x has the dtype of the reference array, and its device (where the framework has devices)."""
    require_same_dtype(name, x.dtype, reference_name, reference.dtype)
    be.require_same_device(name, x, reference_name, reference)


def same_shape(be, name: str, x, reference_name: str, reference) -> None:
    """x has the shape, dtype and device of the reference array."""
    require_same_shape(name, x.shape, reference_name, reference.shape)
    same_dtype_and_device(be, name, x, reference_name, reference)


def positive_scalar(be, name: str, value: object, like):
    """A Python number > 0, or a 0-d array / an array of `like`'s shape with values > 0. An array
    keeps its gradient; one of any other shape is refused rather than broadcast."""
    if be.is_array(value):
        value = be.array(name, value)
        if value.ndim != 0:
            same_shape(be, name, value, "the compared arrays", like)
        else:
            same_dtype_and_device(be, name, floating_array(be, name, value), "the compared arrays", like)
        return be.check_positive(name, value)
    return require_positive_number(name, value)


def per_batch_scalar(be, name: str, value: object, like):
    """A Python number, a 0-d array, or a (B,) array reshaped to broadcast over (B, C, H, W)."""
    if be.is_array(value):
        value = floating_array(be, name, value)
        same_dtype_and_device(be, name, value, "the input", like)
        if value.ndim == 0:
            return value
        if value.ndim == 1 and value.shape[0] == like.shape[0]:
            return value.reshape(-1, 1, 1, 1)
        raise ValueError(
            f"{name} must be a number, a 0-d {be.array_word} or a (B,) {be.array_word} with B={like.shape[0]}, "
            f"got shape {tuple(value.shape)}"
        )
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        raise TypeError(f"{name} must be a real number or a {be.array_type_name}, got {value!r}")
    return float(value)


__all__ += ["floating_array", "image_array", "per_batch_scalar", "positive_scalar", "same_dtype_and_device", "same_shape"]


#: The library's own folders: a warning points at the first frame outside them.
_LIBRARY_DIRS = tuple(str(Path(__file__).resolve().parents[1] / name) + os.sep for name in ("diffblur", "torch_impl", "jax_impl"))


def caller_stacklevel() -> int:
    """The `stacklevel` for a `warnings.warn` called from the library that points at the user's line:
    the first frame outside diffblur, torch_impl and jax_impl, however many wrappers lie between
    (the warning's caller counts as level 1)."""
    frame, level = sys._getframe(1), 1
    while frame is not None and os.path.abspath(frame.f_code.co_filename).startswith(_LIBRARY_DIRS):
        frame, level = frame.f_back, level + 1
    return level


__all__ += ["caller_stacklevel"]
