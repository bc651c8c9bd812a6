"""`reconstruct` and `gather_blur` on the fused CPU kernels (`diffblur.kernels.reconstruct`,
`diffblur.kernels.gather`) as PyTorch custom operators (`torch.library.custom_op`).

Each kernel is an operator of its own, forward and backward (`diffblur::reconstruct_forward`,
`diffblur::reconstruct_backward`, `diffblur::gather_forward`, `diffblur::gather_backward`), with a
fake implementation (the outputs' shapes) and the forward's gradient formula registered as the
backward operator. `torch.compile` then keeps each kernel as one opaque call in its graph, forward
and backward, instead of tracing the tensor ops tap by tap; in eager mode the operators run the same
kernels on the same arrays as before they were operators. Options are plain int/float/bool
arguments, so that they are part of the operator's schema.

NeighborMax, the tile classes and the shutter's masses stay tensor ops (small: at tile resolution,
or one number per tap), so autograd carries the kernels' gradients w.r.t. NeighborMax and the masses
back to the velocity and the shutter's parameters exactly as on the pure path.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from diffblur.kernels import gather as gather_kernel
from diffblur.kernels import reconstruct as reconstruct_kernel
from diffblur.ops import primitives
from diffblur.ops.adaptive import ADAPTIVE_TILE, STILL_SPEED
from diffblur.ops.scatter import has_constant_parameters
from torch_impl._backend import TORCH


def _dtype_name(x: Tensor) -> str:
    return str(x.dtype).removeprefix("torch.")


def _placement_reason(color: Tensor) -> str | None:
    """Why the inputs' device keeps any fused kernel from running, or None. Under torch.compile the
    kernels run too: they are custom operators, opaque to the compiler."""
    if color.device.type != "cpu":
        return f"device {color.device} (the fused kernel runs on the CPU)"
    return None


def unfused_reason(o, color: Tensor, jitter: Tensor) -> str | None:
    """Why the fused reconstruct cannot run these inputs and options, or None when it can."""
    reason = reconstruct_kernel.reconstruct_unfused_reason(o, _dtype_name(color)) or _placement_reason(color)
    if reason is None and jitter.requires_grad:
        return "jitter requires grad (the fused kernel gives jitter no gradient)"
    return reason


def gather_unfused_reason(color: Tensor, sampling: str) -> str | None:
    """Why the fused gather_blur cannot run these inputs and options, or None when it can."""
    return gather_kernel.gather_unfused_reason(sampling, _dtype_name(color)) or _placement_reason(color)


def _array(tensor: Tensor):
    return tensor.detach().contiguous().numpy()


def _tensor(array) -> Tensor:
    return torch.from_numpy(array)


def _nothing(like: Tensor) -> Tensor:
    """What a backward operator returns in place of a gradient not asked for (a schema has no
    optional outputs): an empty tensor, which the gradient formula turns into None."""
    return like.new_empty((0,))


def _first_order_only(backward_op, op: str) -> None:
    """Make a backward operator refuse to be differentiated itself, saying so (the kernels have
    first-order gradients only)."""

    def refuse(ctx, *grads):
        raise RuntimeError(f"{op}'s fused kernel has first-order gradients only (no double backward); pass impl='tensor' for higher orders")

    backward_op.register_autograd(refuse)


# -- reconstruct --------------------------------------------------------------------------------------


@torch.library.custom_op("diffblur::reconstruct_forward", mutates_args=(), device_types="cpu")
def reconstruct_forward(
    color: Tensor,
    velocity: Tensor,
    depth: Tensor,
    neighbors: Tensor,
    counts: Tensor,
    jitter: Tensor,
    tile: int,
    soft_z_extent: float,
    min_radius: float,
    own_odd: bool,
) -> tuple[Tensor, Tensor]:
    """`diffblur.kernels.reconstruct.reconstruct_forward`: the image and the per-pixel weight sum (B, H, W)."""
    settings = dict(tile=tile, soft_z_extent=soft_z_extent, min_radius=min_radius, own_odd=own_odd)
    out, weight = reconstruct_kernel.reconstruct_forward(*(_array(t) for t in (color, velocity, depth, neighbors, counts, jitter)), **settings)
    return _tensor(out), _tensor(weight)


@reconstruct_forward.register_fake
def _(color, velocity, depth, neighbors, counts, jitter, tile, soft_z_extent, min_radius, own_odd):
    batch, _, height, width = color.shape
    return color.new_empty(color.shape), color.new_empty((batch, height, width))


@torch.library.custom_op("diffblur::reconstruct_backward", mutates_args=(), device_types="cpu")
def reconstruct_backward(
    color: Tensor,
    velocity: Tensor,
    depth: Tensor,
    neighbors: Tensor,
    counts: Tensor,
    jitter: Tensor,
    out: Tensor,
    weight: Tensor,
    grad_out: Tensor,
    tile: int,
    soft_z_extent: float,
    min_radius: float,
    own_odd: bool,
    need_color: bool,
    need_velocity: bool,
    need_depth: bool,
) -> tuple[Tensor, Tensor]:
    """`diffblur.kernels.reconstruct.reconstruct_backward`: (B, C + 3, H, W), the gradients w.r.t. colour,
    velocity and depth stacked along the channels as the kernel writes them (those not asked for
    hold no meaning), and NeighborMax's (empty unless the velocity's is asked for)."""
    settings = dict(tile=tile, soft_z_extent=soft_z_extent, min_radius=min_radius, own_odd=own_odd)
    arrays = (_array(t) for t in (color, velocity, depth, neighbors, counts, jitter, out, weight, grad_out))
    total, grad_neighbors = reconstruct_kernel.reconstruct_backward_stacked(*arrays, needs=(need_color, need_velocity, need_depth), **settings)
    return _tensor(total), _nothing(color) if grad_neighbors is None else _tensor(grad_neighbors)


@reconstruct_backward.register_fake
def _(color, velocity, depth, neighbors, counts, jitter, out, weight, grad_out, tile, soft_z_extent, min_radius, own_odd, need_color, need_velocity, need_depth):
    batch, channels, height, width = color.shape
    grad_neighbors = neighbors.new_empty(neighbors.shape) if need_velocity else _nothing(color)
    return color.new_empty((batch, channels + 3, height, width)), grad_neighbors


def _reconstruct_setup(ctx, inputs, output):
    color, velocity, depth, neighbors, counts, jitter, *settings = inputs
    out, weight = output
    ctx.save_for_backward(color, velocity, depth, neighbors, counts, jitter, out, weight)
    ctx.settings = settings


def _reconstruct_gradient(ctx, grad_out, grad_weight):
    # The weight sum is an auxiliary output for the backward; nothing reads it as a result.
    need_color, need_velocity, need_depth, need_neighbors = ctx.needs_input_grad[:4]
    # Only the gradients asked for: fitting a velocity skips the colour's and depth's scatter.
    needs = (need_color, need_velocity or need_neighbors, need_depth)
    total, grad_neighbors = reconstruct_backward(*ctx.saved_tensors, grad_out, *ctx.settings, *needs)
    channels = total.shape[1] - 3
    return (
        total[:, :channels] if needs[0] else None,
        total[:, channels : channels + 2] if needs[1] else None,
        total[:, channels + 2 :] if needs[2] else None,
        grad_neighbors if needs[1] else None,
        *(None,) * 6,
    )


reconstruct_forward.register_autograd(_reconstruct_gradient, setup_context=_reconstruct_setup)
_first_order_only(reconstruct_backward, "reconstruct")


def fused_reconstruct(color: Tensor, velocity: Tensor, depth: Tensor, jitter: Tensor, o) -> Tensor:
    """reconstruct (options `o`, adaptive or not) on the fused kernel; see `unfused_reason`."""
    neighbors = primitives.neighbor_max_of_velocity(TORCH, velocity, o.tile)
    speed = primitives.safe_length(TORCH, neighbors.detach())[:, 0]
    counts = reconstruct_kernel.tile_counts(speed, o, torch)
    settings = (int(o.tile), float(o.band), float(o.min_radius), o.directions == "neighbor_and_own")
    out, _ = reconstruct_forward(color, velocity, depth, neighbors, counts.to(torch.int32), jitter.expand(-1, 1, -1, -1), *settings)
    return out


# -- gather_blur --------------------------------------------------------------------------------------


def _gather_settings(samples: int, classes: list[int], still: float, tile: int) -> dict:
    return dict(samples=samples, classes=tuple(classes) or None, still=still, tile=tile)


@torch.library.custom_op("diffblur::gather_forward", mutates_args=(), device_types="cpu")
def gather_forward(color: Tensor, velocity: Tensor, masses: Tensor, samples: int, classes: list[int], still: float, tile: int) -> Tensor:
    """`diffblur.kernels.gather.gather_forward`. classes: the adaptive tap counts, empty for the full rate."""
    arrays = (_array(t) for t in (color, velocity, masses))
    return _tensor(gather_kernel.gather_forward(*arrays, **_gather_settings(samples, classes, still, tile)))


@gather_forward.register_fake
def _(color, velocity, masses, samples, classes, still, tile):
    return color.new_empty(color.shape)


@torch.library.custom_op("diffblur::gather_backward", mutates_args=(), device_types="cpu")
def gather_backward(
    color: Tensor,
    velocity: Tensor,
    masses: Tensor,
    grad_out: Tensor,
    samples: int,
    classes: list[int],
    still: float,
    tile: int,
    need_color: bool,
    need_velocity: bool,
    need_masses: bool,
) -> tuple[Tensor, Tensor, Tensor]:
    """`diffblur.kernels.gather.gather_backward`: the gradients w.r.t. colour, velocity and masses, each
    empty where it is not asked for."""
    arrays = (_array(t) for t in (color, velocity, masses, grad_out))
    needs = (need_color, need_velocity, need_masses)
    grads = gather_kernel.gather_backward(*arrays, needs=needs, **_gather_settings(samples, classes, still, tile))
    return tuple(_nothing(color) if g is None else _tensor(g) for g in grads)


@gather_backward.register_fake
def _(color, velocity, masses, grad_out, samples, classes, still, tile, need_color, need_velocity, need_masses):
    return tuple(x.new_empty(x.shape) if need else _nothing(color) for x, need in ((color, need_color), (velocity, need_velocity), (masses, need_masses)))


def _gather_setup(ctx, inputs, output):
    color, velocity, masses, *settings = inputs
    ctx.save_for_backward(color, velocity, masses)
    ctx.settings = settings


def _gather_gradient(ctx, grad_out):
    # Only the gradients asked for: fitting a velocity skips the colour's scatter.
    needs = tuple(ctx.needs_input_grad[:3])
    grads = gather_backward(*ctx.saved_tensors, grad_out, *ctx.settings, *needs)
    return (*(g if need else None for g, need in zip(grads, needs)), *(None,) * 4)


gather_forward.register_autograd(_gather_gradient, setup_context=_gather_setup)
_first_order_only(gather_backward, "gather_blur")


@torch.compiler.assume_constant_result
def _constant_mass_table(window, samples: int, classes: tuple[int, ...]) -> tuple[tuple[float, ...], ...]:
    """`diffblur.kernels.gather.gather_mass_table` of a window with constant parameters, computed in NumPy
    (float64) as Python numbers, which torch.compile runs as Python and keeps as constants (it
    cannot trace the NumPy code)."""
    return tuple(tuple(row) for row in gather_kernel.gather_mass_table(window, samples, classes, np, np.float64).tolist())


def fused_gather(color: Tensor, velocity: Tensor, window, samples: int, classes: tuple[int, ...] | None, wide: torch.dtype) -> Tensor:
    """gather_blur (full rate, or the adaptive `classes`) on the fused kernel; see `gather_unfused_reason`.
    The kernel sizes the adaptive classes itself, from the velocity."""
    classes_used = classes or (samples,)
    if has_constant_parameters(window):
        table = torch.tensor(_constant_mass_table(window, samples, classes_used), dtype=wide, device=color.device)
    else:  # a shape parameter being fitted: the masses carry its gradient
        table = gather_kernel.gather_mass_table(window, samples, classes_used, torch, wide)
    table = table.to(color.dtype)
    return gather_forward(color, velocity, table, int(samples), list(classes or ()), float(STILL_SPEED), int(ADAPTIVE_TILE))
