"""The building blocks of seed 000 as batched, differentiable PyTorch ops (defined in
`diffblur.ops.primitives`)."""

from __future__ import annotations

import torch
from jaxtyping import Float
from torch import Tensor

from diffblur.conventions import DEFAULT_MAX_RADIUS, DEFAULT_MIN_RADIUS
from diffblur.ops import primitives as p
from diffblur.ops._options import public
from torch_impl._backend import TORCH

__all__ = ["cone", "cylinder", "interleaved_gradient_noise", "neighbor_max", "safe_length", "soft_depth_compare", "tile_max", "velocity_from_motion"]


@public(p.SOFT_DEPTH_COMPARE_DOC, example="""
    >>> import torch
    >>> soft_depth_compare(torch.tensor([2.0, 2.0, 2.0]), torch.tensor([1.0, 2.5, 4.0]), 1.0)
    tensor([1.0000, 0.5000, 0.0000])""")
def soft_depth_compare(z_a: Float[Tensor, "*shape"], z_b: Float[Tensor, "*shape"], extent: float | Tensor) -> Float[Tensor, "*shape"]:
    return p.soft_depth_compare_op(TORCH, z_a, z_b, extent)


@public(p.CONE_DOC, example="""
    >>> import torch
    >>> cone(torch.tensor([0.0, 1.0, 3.0]), torch.tensor([2.0, 2.0, 2.0]))
    tensor([1.0000, 0.5000, 0.0000])""")
def cone(distance: Float[Tensor, "*shape"], speed: Float[Tensor, "*shape"]) -> Float[Tensor, "*shape"]:
    return p.cone_op(TORCH, distance, speed)


@public(p.CYLINDER_DOC, example="""
    >>> import torch
    >>> cylinder(torch.tensor([0.0, 2.0, 3.0]), torch.tensor([2.0, 2.0, 2.0]))
    tensor([1.0000, 0.5000, 0.0000])""")
def cylinder(distance: Float[Tensor, "*shape"], speed: Float[Tensor, "*shape"]) -> Float[Tensor, "*shape"]:
    return p.cylinder_op(TORCH, distance, speed)


@public(p.SAFE_LENGTH_DOC, example="""
    >>> import torch
    >>> v = torch.zeros(1, 2, 1, 1, requires_grad=True)
    >>> safe_length(v).sum().backward()
    >>> v.grad.flatten().tolist()
    [0.0, 0.0]""")
def safe_length(vector: Float[Tensor, "b c h w"], *, axis: int = 1) -> Float[Tensor, "b 1 h w"]:
    return p.safe_length_op(TORCH, vector, axis)


@public(p.TILE_MAX_DOC, example="""
    >>> import torch
    >>> v = torch.zeros(1, 2, 2, 4); v[0, 0, 1, 1] = 3.0; v[0, 1, 0, 3] = -1.0
    >>> tile_max(v, 2)[0].tolist()  # the longest vector of each 2 x 2 tile
    [[[3.0, 0.0]], [[0.0, -1.0]]]""")
def tile_max(velocity: Float[Tensor, "b 2 h w"], tile: int) -> Float[Tensor, "b 2 th tw"]:
    return p.tile_max_op(TORCH, velocity, tile)


@public(p.NEIGHBOR_MAX_DOC, example="""
    >>> import torch
    >>> tiles = torch.zeros(1, 2, 1, 4); tiles[0, 0, 0, 0] = 2.0
    >>> neighbor_max(tiles)[0, 0].tolist()  # the longest of each tile's 3 x 3 neighbours
    [[2.0, 2.0, 0.0, 0.0]]""")
def neighbor_max(tile_velocity: Float[Tensor, "b 2 th tw"]) -> Float[Tensor, "b 2 th tw"]:
    return p.neighbor_max_op(TORCH, tile_velocity)


@public(p.INTERLEAVED_GRADIENT_NOISE_DOC, example="""
    >>> import torch
    >>> noise = interleaved_gradient_noise(4, 6, dtype=torch.float64)
    >>> noise.shape, bool(((noise >= 0) & (noise < 1)).all())
    (torch.Size([4, 6]), True)""")
def interleaved_gradient_noise(height: int, width: int, *, dtype: torch.dtype | None = None, device: torch.device | str | None = None) -> Float[Tensor, "h w"]:
    return p.interleaved_gradient_noise_op(TORCH, height, width, dtype=dtype, device=device)


@public(p.VELOCITY_FROM_MOTION_DOC, example="""
    >>> import torch
    >>> d = torch.tensor([[3.0, 0.2, 60.0], [4.0, 0.0, 80.0]]).reshape(1, 2, 1, 3)
    >>> velocity_from_motion(d, exposure=1.0, max_radius=20.0)[0, :, 0].T.tolist()
    [[1.5, 2.0], [0.5, 0.0], [12.0, 16.0]]""")
def velocity_from_motion(displacement: Float[Tensor, "b 2 h w"], *, exposure: float | Tensor = 1.0, max_radius: float = DEFAULT_MAX_RADIUS, min_radius: float = DEFAULT_MIN_RADIUS) -> Float[Tensor, "b 2 h w"]:
    return p.velocity_from_motion_op(TORCH, displacement, exposure=exposure, max_radius=max_radius, min_radius=min_radius)
