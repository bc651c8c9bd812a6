"""`bezier_scatter`'s splats on the fused CPU kernel (`diffblur._fused_scatter`) as an `autograd.Function`.

The kernel takes the path as the Bezier's power-basis terms (or the arc's centre and angle) and the
shutter's masses as tensors: building them stays a tensor op, so autograd carries the kernel's
gradients w.r.t. them back to the offsets and the shutter's parameters as on the pure path.
"""

from __future__ import annotations

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from diffblur import _fused_scatter
from torch_impl._primitives import _floor_extent


def unfused_reason(color: Tensor) -> str | None:
    """Why the fused splats cannot run on these inputs now, or None when they can."""
    reason = _fused_scatter.splat_unfused_reason(str(color.dtype).removeprefix("torch."))
    if reason is not None:
        return reason
    if color.device.type != "cpu":
        return f"device {color.device} (the fused kernel runs on the CPU)"
    if torch.compiler.is_compiling():
        return "torch.compile is tracing (the kernel is opaque to it)"
    return None


def _array(tensor: Tensor):
    return tensor.detach().contiguous().numpy()


class _FusedSplat(torch.autograd.Function):
    @staticmethod
    def forward(ctx, color, depth, path, masses, extent, moving, arc, paper):
        sums = _fused_scatter.splat_forward(*(_array(t) for t in (color, depth, path, masses, extent, moving)), arc=arc, paper=paper)
        ctx.save_for_backward(color, depth, path, masses, extent, moving)
        ctx.arc, ctx.paper = arc, paper
        return torch.from_numpy(sums)

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_sums):
        arrays = [_array(t) for t in ctx.saved_tensors]
        grads = _fused_scatter.splat_backward(*arrays, _array(grad_sums), arc=ctx.arc, paper=ctx.paper)
        return (*(torch.from_numpy(g) for g in grads), None, None, None)


def _path(kind: str, terms: tuple) -> Tensor:
    """The kernel's (B, P, H, W) path: the arc's centre and angle, or the four power-basis terms
    (zeros for those the degree lacks; see `diffblur._fused_scatter.BEZIER_CHANNELS`)."""
    if kind == "arc":
        return torch.cat(terms, dim=1)
    like = next(term for term in terms if term is not None)
    return torch.cat([torch.zeros_like(like) if term is None else term for term in terms], dim=1)


def fused_splat(color: Tensor, depth: Tensor, kind: str, terms: tuple, masses: Tensor, extent: float | Tensor, moving: Tensor, paper: bool) -> Tensor:
    """The sums (B, C + 1, H, W) of omega * [color, 1] over every moving pixel's points (`_scatter`'s
    accumulation, cropped to the image), on the fused kernel; see `unfused_reason`."""
    extent = _floor_extent(extent)
    if not isinstance(extent, Tensor):  # a number: the tensor ops compare in the depth's dtype
        extent = torch.tensor(extent, dtype=depth.dtype)
    return _FusedSplat.apply(color, depth, _path(kind, terms), masses, extent.to(depth.dtype), moving, kind == "arc", paper)
