"""`reconstruct` on the fused CPU kernel (`diffblur._fused`) as an `autograd.Function`.

NeighborMax and the tile classes stay tensor ops (small, at tile resolution), so autograd carries
the kernel's NeighborMax gradient back to the velocity exactly as on the pure path.
"""

from __future__ import annotations

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from diffblur import _fused
from torch_impl._primitives import _safe_length, neighbor_max, tile_max


def unfused_reason(o, color: Tensor, jitter: Tensor) -> str | None:
    """Why the fused kernel cannot run these inputs and options, or None when it can."""
    reason = _fused.reconstruct_unfused_reason(o, str(color.dtype).removeprefix("torch."))
    if reason is not None:
        return reason
    if color.device.type != "cpu":
        return f"device {color.device} (the fused kernel runs on the CPU)"
    if torch.compiler.is_compiling():
        return "torch.compile is tracing (the kernel is opaque to it)"
    if jitter.requires_grad:
        return "jitter requires grad (the fused kernel gives jitter no gradient)"
    return None


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
        grads = _fused.reconstruct_backward(*arrays, _array(grad_out), **ctx.settings)
        return (*(torch.from_numpy(g) for g in grads), None, None, None)


def fused_reconstruct(color: Tensor, velocity: Tensor, depth: Tensor, jitter: Tensor, o) -> Tensor:
    """reconstruct (options `o`, adaptive or not) on the fused kernel; see `unfused_reason`."""
    neighbors = neighbor_max(tile_max(velocity, o.tile))
    speed = _safe_length(neighbors.detach())[:, 0]
    counts = _fused.tile_counts(speed, o, torch)
    settings = dict(tile=o.tile, soft_z_extent=o.soft_z_extent, min_radius=o.min_radius, own_odd=o.directions == "neighbor_and_own")
    return _FusedReconstruct.apply(color, velocity, depth, neighbors, counts.to(torch.int32), jitter.expand(-1, 1, -1, -1), settings)
