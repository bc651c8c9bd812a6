"""`bezier_scatter`'s splats on the fused CPU kernels (`diffblur.kernels.scatter`) as PyTorch custom
operators (`diffblur::splat_forward` and `diffblur::instant_forward`, with `diffblur::splat_backward`
and `diffblur::instant_backward` registered as their gradients), which `torch.compile` keeps as opaque calls in its graph instead of tracing the
splats.

The kernel takes the path as the Bezier's power-basis terms (or the arc's centre and angle) and the
shutter's masses as tensors: building them stays a tensor op, so autograd carries the kernel's
gradients w.r.t. them back to the offsets and the shutter's parameters as on the pure path.
"""

from __future__ import annotations

import torch
from torch import Tensor

from diffblur.kernels import scatter as scatter_kernel
from torch_impl._fused import _first_order_only
from diffblur.ops.primitives import floor_extent
from torch_impl._backend import TORCH


def unfused_reason(color: Tensor) -> str | None:
    """Why the fused splats cannot run on these inputs now, or None when they can (under
    torch.compile too: the kernel is a custom operator)."""
    reason = scatter_kernel.splat_unfused_reason(str(color.dtype).removeprefix("torch."))
    if reason is not None:
        return reason
    if color.device.type != "cpu":
        return f"device {color.device} (the fused kernel runs on the CPU)"
    return None


def _array(tensor: Tensor):
    return tensor.detach().contiguous().numpy()


@torch.library.custom_op("diffblur::splat_forward", mutates_args=(), device_types="cpu")
def splat_forward(color: Tensor, depth: Tensor, path: Tensor, masses: Tensor, extent: Tensor, moving: Tensor, arc: bool, paper: bool) -> Tensor:
    """`diffblur.kernels.scatter.splat_forward`: the sums (B, C + 1, H, W)."""
    arrays = (_array(t) for t in (color, depth, path, masses, extent, moving))
    return torch.from_numpy(scatter_kernel.splat_forward(*arrays, arc=arc, paper=paper))


@splat_forward.register_fake
def _(color, depth, path, masses, extent, moving, arc, paper):
    batch, channels, height, width = color.shape
    return color.new_empty((batch, channels + 1, height, width))


@torch.library.custom_op("diffblur::splat_backward", mutates_args=(), device_types="cpu")
def splat_backward(
    color: Tensor, depth: Tensor, path: Tensor, masses: Tensor, extent: Tensor, moving: Tensor, grad_sums: Tensor, arc: bool, paper: bool
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """`diffblur.kernels.scatter.splat_backward`: the gradients w.r.t. color, depth, path, masses and
    extent."""
    arrays = (_array(t) for t in (color, depth, path, masses, extent, moving, grad_sums))
    return tuple(torch.from_numpy(g) for g in scatter_kernel.splat_backward(*arrays, arc=arc, paper=paper))


@splat_backward.register_fake
def _(color, depth, path, masses, extent, moving, grad_sums, arc, paper):
    return tuple(x.new_empty(x.shape, dtype=color.dtype) for x in (color, depth, path, masses, extent))


def _setup(ctx, inputs, output):
    color, depth, path, masses, extent, moving, arc, paper = inputs
    ctx.save_for_backward(color, depth, path, masses, extent, moving)
    ctx.arc, ctx.paper = arc, paper


def _gradient(ctx, grad_sums):
    grads = splat_backward(*ctx.saved_tensors, grad_sums, ctx.arc, ctx.paper)
    return (*grads, None, None, None)


splat_forward.register_autograd(_gradient, setup_context=_setup)
_first_order_only(splat_backward, "bezier_scatter")


def _path(kind: str, terms: tuple) -> Tensor:
    """The kernel's (B, P, H, W) path: the arc's centre and angle, or the four power-basis terms
    (zeros for those the degree lacks; see `diffblur.kernels.scatter.BEZIER_CHANNELS`)."""
    if kind == "arc":
        return torch.cat(terms, dim=1)
    like = next(term for term in terms if term is not None)
    return torch.cat([torch.zeros_like(like) if term is None else term for term in terms], dim=1)


def fused_splat(color: Tensor, depth: Tensor, kind: str, terms: tuple, masses: Tensor, extent: float | Tensor, moving: Tensor, paper: bool) -> Tensor:
    """The sums (B, C + 1, H, W) of omega * [color, 1] over every moving pixel's points (`_scatter`'s
    accumulation, cropped to the image), on the fused kernel; see `unfused_reason`."""
    extent = floor_extent(TORCH, extent)
    if not isinstance(extent, Tensor):  # a number: the tensor ops compare in the depth's dtype
        extent = torch.tensor(extent, dtype=depth.dtype)
    return splat_forward(color, depth, _path(kind, terms), masses, extent.to(depth.dtype), moving, kind == "arc", bool(paper))


@torch.library.custom_op("diffblur::instant_forward", mutates_args=(), device_types="cpu")
def instant_forward(color: Tensor, log_depth: Tensor, depth: Tensor, path: Tensor, times: Tensor, extent: Tensor, moving: Tensor, arc: bool) -> Tensor:
    """`diffblur.kernels.scatter.instant_forward`: the sums (K, B, 2 C + 3, H, W) at each instant."""
    arrays = (_array(t) for t in (color, log_depth, depth, path, times, extent, moving))
    return torch.from_numpy(scatter_kernel.instant_forward(*arrays, arc=arc))


@instant_forward.register_fake
def _(color, log_depth, depth, path, times, extent, moving, arc):
    batch, channels, height, width = color.shape
    return color.new_empty((times.shape[0], batch, 2 * channels + 3, height, width))


@torch.library.custom_op("diffblur::instant_backward", mutates_args=(), device_types="cpu")
def instant_backward(
    color: Tensor, log_depth: Tensor, depth: Tensor, path: Tensor, times: Tensor, extent: Tensor, moving: Tensor, grad_sums: Tensor, arc: bool
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """`diffblur.kernels.scatter.instant_backward`: the gradients w.r.t. color, log_depth, depth,
    path and extent."""
    arrays = (_array(t) for t in (color, log_depth, depth, path, times, extent, moving, grad_sums))
    return tuple(torch.from_numpy(g) for g in scatter_kernel.instant_backward(*arrays, arc=arc))


@instant_backward.register_fake
def _(color, log_depth, depth, path, times, extent, moving, grad_sums, arc):
    return tuple(x.new_empty(x.shape, dtype=color.dtype) for x in (color, log_depth, depth, path, extent))


def _instant_setup(ctx, inputs, output):
    color, log_depth, depth, path, times, extent, moving, arc = inputs
    ctx.save_for_backward(color, log_depth, depth, path, times, extent, moving)
    ctx.arc = arc


def _instant_gradient(ctx, grad_sums):
    grad_color, grad_log, grad_depth, grad_path, grad_extent = instant_backward(*ctx.saved_tensors, grad_sums, ctx.arc)
    return grad_color, grad_log, grad_depth, grad_path, None, grad_extent, None, None


instant_forward.register_autograd(_instant_gradient, setup_context=_instant_setup)
_first_order_only(instant_backward, "bezier_scatter")


def fused_instants(color: Tensor, log_depth: Tensor, depth: Tensor, kind: str, terms: tuple, times: Tensor, extent: float | Tensor, moving: Tensor) -> Tensor:
    """composite="instants"'s sums (K, B, 2 C + 3, H, W) at `times` (K,) on the fused kernel
    (`diffblur.ops.scatter._instant_sums`); color, log_depth and depth in one dtype."""
    extent = floor_extent(TORCH, extent)
    if not isinstance(extent, Tensor):
        extent = torch.tensor(extent, dtype=depth.dtype)
    return instant_forward(color, log_depth, depth, _path(kind, terms), times.to(depth.dtype), extent.to(depth.dtype), moving, kind == "arc")
