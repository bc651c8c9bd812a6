"""`bezier_scatter` in PyTorch, seed 003's curve scatter (defined in `diffblur.ops.scatter`)."""

from __future__ import annotations

from jaxtyping import Float
from torch import Tensor

from diffblur.ops import scatter
from diffblur.ops._options import public
from torch_impl._backend import TORCH

EXAMPLE = """
    >>> import torch
    >>> color = torch.zeros(1, 1, 1, 5); color[..., 2] = 1.0
    >>> offset = torch.zeros(1, 2, 1, 5); offset[:, 0, :, 2] = 1.0
    >>> depth = torch.ones(1, 1, 1, 5)
    >>> bezier_scatter(color, depth, -offset, offset, samples=3, fill=torch.zeros_like(color))  # the scene behind: black
    tensor([[[[0.0000, 0.2222, 0.5556, 0.2222, 0.0000]]]])
    >>> bezier_scatter(color, depth, -offset, offset, samples=3, fill="color")  # fills with its own colour
    tensor([[[[0.0000, 0.2222, 1.0000, 0.2222, 0.0000]]]])
"""


@public(scatter.DOC, scatter.ScatterOptions, example=EXAMPLE)
def bezier_scatter(
    color: Float[Tensor, "b c h w"], depth: Float[Tensor, "b 1 h w"], offset_prev: Float[Tensor, "b 2 h w"] | None, offset_next: Float[Tensor, "b 2 h w"] | None, *,
    offset_mid_prev: Float[Tensor, "b 2 h w"] | None = None, arc_center: Float[Tensor, "b 2 h w"] | None = None, arc_angle: Float[Tensor, "b 1 h w"] | None = None, **options,
) -> Float[Tensor, "b c h w"]:
    return scatter.bezier_scatter(TORCH, color, depth, offset_prev, offset_next, offset_mid_prev=offset_mid_prev, arc_center=arc_center, arc_angle=arc_angle, **options)
