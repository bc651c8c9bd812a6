"""Reads the facts the shared checks in `diffblur.checks` need off torch tensors.

Checks that look at the data (signs, finiteness) raise ValueError in eager mode. Under
`torch.compile` they stay in the graph as `torch._assert_async` on CPU tensors (RuntimeError with
the same message when the compiled code runs; no graph break, also with fullgraph=True) and are
skipped on other devices, where a failed device-side assert would leave the CUDA context unusable.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from diffblur import checks


def tensor(name: str, x: object) -> torch.Tensor:
    if not isinstance(x, torch.Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(x).__name__}")
    return x


def floating_tensor(name: str, x: object) -> torch.Tensor:
    x = tensor(name, x)
    checks.require_floating(name, x.dtype, x.dtype.is_floating_point)
    return x


def image(name: str, x: object, *, channels: int | None = None) -> torch.Tensor:
    """A floating (B, C, H, W) tensor, with `channels` channels if given."""
    x = floating_tensor(name, x)
    checks.require_image(name, x.shape, channels=channels)
    return x


def same_dtype_and_device(name: str, x: torch.Tensor, reference_name: str, reference: torch.Tensor) -> None:
    checks.require_same_dtype(name, x.dtype, reference_name, reference.dtype)
    if x.device != reference.device:
        raise ValueError(f"{name} must be on the device of {reference_name} ({reference.device}), got {x.device}")


def same_shape(name: str, x: torch.Tensor, reference_name: str, reference: torch.Tensor) -> None:
    checks.require_same_shape(name, x.shape, reference_name, reference.shape)
    same_dtype_and_device(name, x, reference_name, reference)


def compiled_check(ok: torch.Tensor, message: str) -> bool:
    """Under torch.compile, assert `ok` in the graph (CPU tensors; see the module docstring) and
    return True: the caller's eager check is then not to run."""
    if not torch.compiler.is_compiling():
        return False
    if ok.device.type == "cpu":
        torch._assert_async(ok, message)
    return True


def require(ok_of: Callable[[], torch.Tensor], message: str) -> None:
    """Raise ValueError(message) eagerly, or assert under torch.compile, unless `ok_of()` is true."""
    ok = ok_of()
    if not compiled_check(ok, message) and not bool(ok):
        raise ValueError(message)


def positive_values(name: str, x: torch.Tensor) -> None:
    """Raise ValueError if any element is <= 0 or NaN."""
    require(lambda: torch.all(x > 0), checks.nonpositive_message(name))


def finite_values(name: str, x: torch.Tensor) -> None:
    """Raise ValueError if any element is NaN or infinite.

    Eagerly one sum screens the array: NaN or infinity anywhere makes it non-finite, and only a
    non-finite sum (bad data, or huge finite values that overflow it) pays for the elementwise
    test, which took ~5x the sum's time on a 1280x720 colour (the checks run on every call)."""
    message = checks.nonfinite_message(name)
    if torch.compiler.is_compiling():
        compiled_check(torch.isfinite(x).all(), message)
        return
    if bool(torch.isfinite(x.sum(dtype=torch.promote_types(x.dtype, torch.float32)))):
        return
    if not bool(torch.isfinite(x).all()):
        raise ValueError(message)


def positive_scalar(name: str, value: object, like: torch.Tensor) -> float | torch.Tensor:
    """A Python number > 0, or a 0-d tensor / tensor of `like`'s shape with values > 0.

    A tensor keeps its gradient; a tensor of any other shape is refused rather than broadcast.
    """
    if isinstance(value, torch.Tensor):
        if value.ndim != 0:
            same_shape(name, value, "the compared arrays", like)
        else:
            same_dtype_and_device(name, floating_tensor(name, value), "the compared arrays", like)
        positive_values(name, value)
        return value
    return checks.require_positive_number(name, value)


def per_batch_scalar(name: str, value: object, like: torch.Tensor) -> float | torch.Tensor:
    """A Python number, a 0-d tensor, or a (B,) tensor reshaped to broadcast over (B, C, H, W)."""
    if isinstance(value, torch.Tensor):
        floating_tensor(name, value)
        same_dtype_and_device(name, value, "the input", like)
        if value.ndim == 0:
            return value
        if value.ndim == 1 and value.shape[0] == like.shape[0]:
            return value.reshape(-1, 1, 1, 1)
        raise ValueError(f"{name} must be a number, a 0-d tensor or a (B,) tensor with B={like.shape[0]}, got shape {tuple(value.shape)}")
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        raise TypeError(f"{name} must be a real number or a tensor, got {value!r}")
    return float(value)
