"""`reconstruct` and `gather_blur` on the fused CPU kernels (`diffblur._fused`) as `autograd.Function`s.

NeighborMax, the tile classes and the shutter's masses stay tensor ops (small: at tile resolution,
or one number per tap), so autograd carries the kernels' gradients w.r.t. NeighborMax and the masses
back to the velocity and the shutter's parameters exactly as on the pure path.
"""

from __future__ import annotations

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from diffblur import _fused
from diffblur._adaptive import ADAPTIVE_TILE, STILL_SPEED
from torch_impl._primitives import _safe_length, neighbor_max, tile_max


def _dtype_name(x: Tensor) -> str:
    return str(x.dtype).removeprefix("torch.")


def _placement_reason(color: Tensor) -> str | None:
    """Why the inputs' device or the tracing state keeps any fused kernel from running, or None."""
    if color.device.type != "cpu":
        return f"device {color.device} (the fused kernel runs on the CPU)"
    if torch.compiler.is_compiling():
        return "torch.compile is tracing (the kernel is opaque to it)"
    return None


def unfused_reason(o, color: Tensor, jitter: Tensor) -> str | None:
    """Why the fused reconstruct cannot run these inputs and options, or None when it can."""
    reason = _fused.reconstruct_unfused_reason(o, _dtype_name(color)) or _placement_reason(color)
    if reason is None and jitter.requires_grad:
        return "jitter requires grad (the fused kernel gives jitter no gradient)"
    return reason


def gather_unfused_reason(color: Tensor, sampling: str, pyramid: bool) -> str | None:
    """Why the fused gather_blur cannot run these inputs and options, or None when it can."""
    return _fused.gather_unfused_reason(sampling, pyramid, _dtype_name(color)) or _placement_reason(color)


def _array(tensor: Tensor):
    return tensor.detach().contiguous().numpy()


class _FusedReconstruct(torch.autograd.Function):
    @staticmethod
    def forward(ctx, color, velocity, depth, neighbors, counts, jitter, settings):
        out, weight = _fused.reconstruct_forward(*(_array(t) for t in (color, velocity, depth, neighbors, counts, jitter)), **settings)
        out, weight = torch.from_numpy(out), torch.from_numpy(weight)
        ctx.save_for_backward(color, velocity, depth, neighbors, counts, jitter, out, weight)
        ctx.settings = settings
        return out

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_out):
        arrays = [_array(t) for t in ctx.saved_tensors]
        color, velocity, depth, neighbors = ctx.needs_input_grad[:4]
        # Only the gradients asked for: fitting a velocity skips the colour's and depth's scatter.
        grads = _fused.reconstruct_backward(*arrays, _array(grad_out), needs=(color, velocity or neighbors, depth), **ctx.settings)
        return (*(None if g is None else torch.from_numpy(g) for g in grads), None, None, None)


def fused_reconstruct(color: Tensor, velocity: Tensor, depth: Tensor, jitter: Tensor, o) -> Tensor:
    """reconstruct (options `o`, adaptive or not) on the fused kernel; see `unfused_reason`."""
    neighbors = neighbor_max(tile_max(velocity, o.tile))
    speed = _safe_length(neighbors.detach())[:, 0]
    counts = _fused.tile_counts(speed, o, torch)
    settings = dict(tile=o.tile, soft_z_extent=o.soft_z_extent, min_radius=o.min_radius, own_odd=o.directions == "neighbor_and_own")
    return _FusedReconstruct.apply(color, velocity, depth, neighbors, counts.to(torch.int32), jitter.expand(-1, 1, -1, -1), settings)


class _FusedGather(torch.autograd.Function):
    @staticmethod
    def forward(ctx, color, velocity, masses, settings):
        out = torch.from_numpy(_fused.gather_forward(*(_array(t) for t in (color, velocity, masses)), **settings))
        ctx.save_for_backward(color, velocity, masses)
        ctx.settings = settings
        return out

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_out):
        arrays = [_array(t) for t in ctx.saved_tensors]
        # Only the gradients asked for: fitting a velocity skips the colour's scatter.
        grads = _fused.gather_backward(*arrays, _array(grad_out), needs=ctx.needs_input_grad[:3], **ctx.settings)
        return (*(None if g is None else torch.from_numpy(g) for g in grads), None)


def fused_gather(color: Tensor, velocity: Tensor, window, samples: int, classes: tuple[int, ...] | None, wide: torch.dtype) -> Tensor:
    """gather_blur (full rate, or the adaptive `classes`) on the fused kernel; see `gather_unfused_reason`.
    The kernel sizes the adaptive classes itself, from the velocity."""
    settings = dict(samples=samples, classes=classes, still=STILL_SPEED, tile=ADAPTIVE_TILE)
    table = _fused.gather_mass_table(window, samples, classes or (samples,), torch, wide).to(color.dtype)
    return _FusedGather.apply(color, velocity, table, settings)
