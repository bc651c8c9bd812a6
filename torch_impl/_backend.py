"""The PyTorch `Backend` (`diffblur.ops.backend`): what the ops, written once in `diffblur.ops`, need
from torch that jax.numpy spells or does differently.

Value checks (signs, finiteness) raise ValueError in eager mode. Under `torch.compile` they stay in
the graph as `torch._assert_async` on CPU tensors (RuntimeError with the same message when the
compiled code runs; no graph break, also with fullgraph=True) and are skipped on other devices,
where a failed device-side assert would leave the CUDA context unusable.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor
from torch.utils.checkpoint import checkpoint

from diffblur import checks, reference
from diffblur.ops.backend import Backend
from diffblur.ops.primitives import interleaved_gradient_noise


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


#: `TorchBackend.outside_compiler`'s functions, by (function, reason).
_EAGER: dict[tuple[Callable, str], Callable] = {}


@functools.lru_cache(maxsize=16)
def _noise_jitter(height: int, width: int, dtype: torch.dtype, device: torch.device) -> Tensor:
    # A normal tensor even when first asked for under torch.inference_mode: a later call with
    # gradients saves it for the backward, which an inference tensor refuses.
    with torch.inference_mode(False):
        return torch.tensor(reference.noise_jitter(height, width), device=device).to(dtype).reshape(1, 1, height, width)


class TorchBackend(Backend):

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
    def is_integer(x: Tensor) -> bool:
        return not x.dtype.is_floating_point and not x.dtype.is_complex and x.dtype != torch.bool

    @staticmethod
    def require_same_device(name: str, x: Tensor, reference_name: str, reference: Tensor) -> None:
        if x.device != reference.device:
            raise ValueError(f"{name} must be on the device of {reference_name} ({reference.device}), got {x.device}")

    @staticmethod
    def check_values(x: Tensor, ok: Tensor, message: str) -> Tensor:
        """x, after checking that `ok` (a bool tensor of one element, computed from data) holds; on
        the meta device, which has shapes but no values, nothing to check."""
        if ok.device.type == "meta":
            return x
        # The switch is read only eagerly: torch.compile cannot trace a ContextVar.
        if not _assert_in_graph(ok, message) and checks.host_reads_allowed() and not bool(ok):
            raise ValueError(message)
        return x

    @classmethod
    def check_positive(cls, name: str, x: Tensor) -> Tensor:
        """x, after checking that every element is > 0 (not NaN)."""
        return cls.check_values(x, torch.all(x > 0), checks.nonpositive_message(name))

    @staticmethod
    def check_finite(name: str, x: Tensor, *, carry: Tensor | None = None) -> Tensor:
        """x (or `carry`, as JAX's checks return), after checking that every element is finite.

        Eagerly one sum screens the array: NaN or infinity anywhere makes it non-finite, and only a
        non-finite sum (bad data, or huge finite values that overflow it) pays for the elementwise
        test, which took ~5x the sum's time on a 1280x720 colour (the checks run on every call)."""
        message = checks.nonfinite_message(name)
        if x.device.type == "meta":  # shapes without values: nothing to check
            pass
        elif torch.compiler.is_compiling():
            _assert_in_graph(torch.isfinite(x).all(), message)
        elif not checks.host_reads_allowed():
            pass
        elif not bool(torch.isfinite(x.sum(dtype=torch.promote_types(x.dtype, torch.float32)))) and not bool(torch.isfinite(x).all()):
            raise ValueError(message)
        return x if carry is None else carry

    @staticmethod
    def is_tracing(x: object = None) -> bool:
        """Whether the op is being compiled (its values are not known now)."""
        return torch.compiler.is_compiling()

    @staticmethod
    def values(x: Tensor) -> np.ndarray | None:
        """x's values as NumPy when they are known now (eager, on a device with data), else None
        (under torch.compile, on the meta device, or inside `diffblur.without_host_reads`)."""
        if torch.compiler.is_compiling() or x.device.type == "meta" or not checks.host_reads_allowed():
            return None
        x = x.detach().cpu()
        return (x.float() if x.dtype == torch.bfloat16 else x).numpy()  # NumPy has no bfloat16

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
    def argmax(x: Tensor, axis: int) -> Tensor:
        return torch.argmax(x, dim=axis, keepdim=True)

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
        flat = [side for before_after in reversed(widths) for side in before_after]  # F.pad's order
        if mode == "edge":  # replicate pads the last two axes of a 4-d tensor, no others
            return F.pad(x, flat[:4], mode="replicate")
        while flat and flat[-2:] == [0, 0]:
            flat = flat[:-2]
        return F.pad(x, flat, value=value) if flat else x

    @staticmethod
    def take_along(x: Tensor, index: Tensor, axis: int) -> Tensor:
        return torch.take_along_dim(x, index, dim=axis)

    @staticmethod
    def read_pixels(flat: Tensor, index: Tensor) -> Tensor:
        """flat (B, C, N) at integer indices (B, ...) into N -> (B, C, ...)."""
        batch, channels, _ = flat.shape
        gathered = torch.gather(flat, 2, index.reshape(batch, 1, -1).expand(batch, channels, -1))
        return gathered.reshape(batch, channels, *index.shape[1:])

    @staticmethod
    def contiguous(x: Tensor) -> Tensor:
        return x.contiguous()

    @staticmethod
    def row_indices(pixels: np.ndarray, total: int, like: Tensor) -> tuple[Tensor, Tensor]:
        """A class's flat pixel indices as the rows to read and to write."""
        index = torch.from_numpy(pixels).to(like.device)
        return index, index

    @staticmethod
    def write_rows(rows: Tensor, index: Tensor, values: Tensor) -> Tensor:
        return rows.index_copy(0, index, values)

    @staticmethod
    def constant(function: Callable, *args: Any) -> Any:
        """function(*args) of Python values, which a compiler keeps as a constant."""
        return _constant(function, *args)

    @staticmethod
    def outside_compiler(function: Callable, reason: str) -> Callable:
        """The function, run eagerly under torch.compile (a graph break; outside it the same). Kept
        in a dict, not an lru_cache, which Dynamo warns it traces through."""
        key = (function, reason)
        if key not in _EAGER:
            _EAGER[key] = torch.compiler.disable(function, reason=reason)
        return _EAGER[key]

    @staticmethod
    def compiled(function: Callable, static_argnames: tuple[str, ...]) -> Callable:
        """The function as it is: PyTorch runs eagerly (under torch.compile the whole op is compiled)."""
        return function

    @staticmethod
    def needs_gradient(*arrays: Tensor) -> bool:
        """Whether autograd will differentiate through arrays computed from these."""
        return torch.is_grad_enabled() and any(a.requires_grad for a in arrays)

    @staticmethod
    def sum_taps(tap: Callable, taps: list[int], carry: tuple[Tensor, Tensor], arrays: tuple, *, recompute: bool) -> tuple[Tensor, Tensor]:
        """carry + the sum of tap(k, *arrays) over the taps, a Python loop; with `recompute` each tap
        is recomputed in the backward pass (activation checkpointing), which keeps only its inputs."""
        weight, total = carry
        for k in taps:
            if recompute:
                alpha, contribution = checkpoint(tap, k, *arrays, use_reentrant=False)
            else:
                alpha, contribution = tap(k, *arrays)
            weight, total = weight + alpha, total + contribution
        return weight, total

    @staticmethod
    def noise_jitter(height: int, width: int, like: Tensor) -> Tensor:
        """reconstruct's "noise" jitter (1, 1, H, W) in like's dtype, on its device: kept per size,
        dtype and device, so that a call creates nothing on the host; under torch.compile computed
        in the graph."""
        if torch.compiler.is_compiling():
            noise = interleaved_gradient_noise(TORCH, height, width, torch.float64, like) - 0.5
            return noise.to(like.dtype).reshape(1, 1, height, width)
        return _noise_jitter(height, width, like.dtype, like.device)

    @staticmethod
    def band(number: float, like: Tensor) -> float:
        """A depth band given as a number, as the ops compute with it: a Python float."""
        return number

    @staticmethod
    def per_channel(alpha: Tensor, channels: int) -> Tensor:
        """The scatter's weight (B, 1, H, W) for `channels` colour channels: broadcast as it is."""
        return alpha

    @staticmethod
    def scatter_add(size: int, index: Tensor, values: Tensor) -> Tensor:
        """(size, V) zeros with values (N, V) added at the rows `index` (N,)."""
        return torch.zeros(size, values.shape[1], dtype=values.dtype, device=values.device).index_add(0, index, values)

    @staticmethod
    def scatter_min(size: int, index: Tensor, values: Tensor) -> Tensor:
        """(size,) of +inf holding the smallest of values (N,) at each row `index` (N,)."""
        start = torch.full((size,), math.inf, dtype=values.dtype, device=values.device)
        return start.scatter_reduce(0, index, values, "amin")

    @staticmethod
    def sum_chunks(splat: Callable, times: Tensor, masses: Tensor, chunk: int, fixed: tuple, start: Tensor) -> Tensor:
        """start + the sum of splat(times, masses, *fixed) over chunks of `chunk` points, a Python
        loop. With more than one chunk and a gradient to take, each chunk is recomputed in the
        backward (activation checkpointing), which keeps O(pixels) memory, not O(pixels x points);
        under torch.compile the compiler chooses what the backward keeps."""
        samples = times.shape[0]
        recompute = chunk < samples and torch.is_grad_enabled() and not torch.compiler.is_compiling()
        total = start
        for first in range(0, samples, chunk):
            part = (times[first : first + chunk], masses[first : first + chunk], *fixed)
            if recompute:
                total = total + checkpoint(splat, *part, use_reentrant=False, preserve_rng_state=False)
            else:
                total = total + splat(*part)
        return total

    @staticmethod
    def widen_window(window: Any, dtype: torch.dtype) -> Any:
        """The shutter window as it is (torch promotes a fitted parameter's dtype by itself)."""
        return window

    # -- the fused CPU kernels (`torch_impl._fused`, `torch_impl._fused_scatter`) ----------------------

    def bindings(self) -> tuple[Any, Any]:
        from torch_impl import _fused, _fused_scatter

        return _fused, _fused_scatter


TORCH = TorchBackend("torch", torch, half=(torch.float16, torch.bfloat16), compiler="torch.compile", integer=torch.int64, array_word="tensor", array_type_name="torch.Tensor")

