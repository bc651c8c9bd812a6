"""The PyTorch `Backend` (`diffblur.ops.backend`): what the ops, written once in `diffblur.ops`, need
from torch that jax.numpy spells or does differently.

Value checks (signs, finiteness) raise ValueError in eager mode. Under `torch.compile` they stay in
the graph as `torch._assert_async` on CPU tensors (RuntimeError with the same message when the
compiled code runs; no graph break, also with fullgraph=True) and are skipped on other devices,
where a failed device-side assert would leave the CUDA context unusable.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor
from torch.utils.checkpoint import checkpoint

from diffblur import checks


def _assert_in_graph(ok: Tensor, message: str) -> bool:
    """Under torch.compile, assert `ok` in the graph (CPU tensors; see the module docstring) and
    return True: the eager check is then not to run."""
    if not torch.compiler.is_compiling():
        return False
    if ok.device.type == "cpu":
        torch._assert_async(ok, message)
    return True


@torch.compiler.assume_constant_result
def _constant(function: Callable, *args: Any) -> Any:
    """function(*args), which torch.compile runs as Python and keeps as a constant (e.g. the shutter's
    masses, which NumPy computes)."""
    return function(*args)


class TorchBackend:
    name = "torch"
    xp = torch
    half = (torch.float16, torch.bfloat16)
    compiler = "torch.compile"
    array_word = "tensor"
    array_type_name = "torch.Tensor"

    # -- argument facts and value checks ------------------------------------------------------------

    @staticmethod
    def array(name: str, x: object) -> Tensor:
        if not isinstance(x, Tensor):
            raise TypeError(f"{name} must be a torch.Tensor, got {type(x).__name__}")
        return x

    @staticmethod
    def is_array(x: object) -> bool:
        return isinstance(x, Tensor)

    @staticmethod
    def is_floating(x: Tensor) -> bool:
        return x.dtype.is_floating_point

    @staticmethod
    def require_same_device(name: str, x: Tensor, reference_name: str, reference: Tensor) -> None:
        if x.device != reference.device:
            raise ValueError(f"{name} must be on the device of {reference_name} ({reference.device}), got {x.device}")

    @staticmethod
    def require(ok_of: Callable[[], Tensor], message: str) -> None:
        """Raise ValueError(message) eagerly, or assert under torch.compile, unless `ok_of()` is true."""
        ok = ok_of()
        if not _assert_in_graph(ok, message) and not bool(ok):
            raise ValueError(message)

    @classmethod
    def check_positive(cls, name: str, x: Tensor) -> Tensor:
        """x, after checking that every element is > 0 (not NaN)."""
        cls.require(lambda: torch.all(x > 0), checks.nonpositive_message(name))
        return x

    @staticmethod
    def check_finite(name: str, x: Tensor, *, carry: Tensor | None = None) -> Tensor:
        """x (or `carry`, as JAX's checks return), after checking that every element is finite.

        Eagerly one sum screens the array: NaN or infinity anywhere makes it non-finite, and only a
        non-finite sum (bad data, or huge finite values that overflow it) pays for the elementwise
        test, which took ~5x the sum's time on a 1280x720 colour (the checks run on every call)."""
        message = checks.nonfinite_message(name)
        if torch.compiler.is_compiling():
            _assert_in_graph(torch.isfinite(x).all(), message)
        elif not bool(torch.isfinite(x.sum(dtype=torch.promote_types(x.dtype, torch.float32)))) and not bool(torch.isfinite(x).all()):
            raise ValueError(message)
        return x if carry is None else carry

    @staticmethod
    def is_tracing(x: object = None) -> bool:
        """Whether the op is being compiled (its values are not known now)."""
        return torch.compiler.is_compiling()

    @staticmethod
    def values(x: Tensor) -> np.ndarray | None:
        """x's values as NumPy when they are known now (eager), else None."""
        return None if torch.compiler.is_compiling() else x.detach().cpu().numpy()

    # -- arrays -------------------------------------------------------------------------------------

    @property
    def default_float(self) -> torch.dtype:
        return torch.get_default_dtype()

    @staticmethod
    def astype(x: Tensor, dtype: torch.dtype) -> Tensor:
        return x.to(dtype)

    @staticmethod
    def index(x: Tensor) -> Tensor:
        """Integer positions (for indexing) from floats already rounded."""
        return x.long()

    @staticmethod
    def stop_gradient(x: Tensor) -> Tensor:
        return x.detach()

    @staticmethod
    def arange(n: int, dtype: torch.dtype, like: Tensor | None = None) -> Tensor:
        return torch.arange(n, dtype=dtype, device=None if like is None else like.device)

    @staticmethod
    def asarray(value: Any, dtype: torch.dtype, like: Tensor | None = None) -> Tensor:
        return torch.as_tensor(value, dtype=dtype, device=None if like is None else like.device)

    @staticmethod
    def zeros(shape: tuple[int, ...], dtype: torch.dtype, like: Tensor) -> Tensor:
        return torch.zeros(shape, dtype=dtype, device=like.device)

    @staticmethod
    def on_device(x: Tensor, device: Any) -> Tensor:
        return x if device is None else x.to(device)

    @staticmethod
    def concat(arrays: list[Tensor], axis: int) -> Tensor:
        return torch.cat(arrays, dim=axis)

    @staticmethod
    def permute(x: Tensor, axes: tuple[int, ...]) -> Tensor:
        return x.permute(*axes)

    @staticmethod
    def repeat(x: Tensor, count: int, axis: int) -> Tensor:
        return x.repeat_interleave(count, dim=axis)

    @staticmethod
    def pad(x: Tensor, widths: tuple[tuple[int, int], ...], *, value: float = 0.0, mode: str = "constant") -> Tensor:
        """x padded by (before, after) per axis, NumPy's order; mode "constant" (value) or "edge"."""
        flat = [side for before_after in reversed(widths) for side in before_after]
        while flat and flat[-2:] == [0, 0]:  # F.pad takes the trailing axes only
            flat = flat[:-2]
        if mode == "edge":
            return F.pad(x, flat, mode="replicate")
        return F.pad(x, flat, value=value)

    @staticmethod
    def argmax(x: Tensor, axis: int) -> Tensor:
        return torch.argmax(x, dim=axis, keepdim=True)

    @staticmethod
    def pick_along(x: Tensor, index: Tensor, axis: int) -> Tensor:
        """x's values at `index` along `axis` (index has size 1 there and broadcasts elsewhere), the
        axis removed."""
        index = index.expand(*x.shape[:axis], 1, *x.shape[axis + 1 :])
        return torch.gather(x, axis, index).squeeze(axis)

    @staticmethod
    def read_pixels(flat: Tensor, index: Tensor) -> Tensor:
        """flat (B, C, N) at integer indices (B, ...) into N -> (B, C, ...)."""
        batch, channels, _ = flat.shape
        gathered = torch.gather(flat, 2, index.reshape(batch, 1, -1).expand(batch, channels, -1))
        return gathered.reshape(batch, channels, *index.shape[1:])

    @staticmethod
    def constant(function: Callable, *args: Any) -> Any:
        """function(*args) of Python values, which a compiler keeps as a constant."""
        return _constant(function, *args)


TORCH = TorchBackend()

