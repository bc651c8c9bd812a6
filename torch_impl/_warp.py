"""Seed 002's image-warping methods in PyTorch, `accumulate_warps` and `warp_blend` (defined in
`diffblur.ops.warp`)."""

from __future__ import annotations

from jaxtyping import Float
from torch import Tensor

from diffblur.ops import warp
from diffblur.ops._options import public
from torch_impl._backend import TORCH

ACCUMULATE_EXAMPLE = """
    >>> import torch
    >>> color = torch.tensor([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]).reshape(1, 1, 1, 7)
    >>> velocity = torch.zeros(1, 2, 1, 7); velocity[:, 0] = 4.0
    >>> accumulate_warps(color, velocity, instants=2)  # two ghosts, 4 px apart
    tensor([[[[0.0000, 0.5000, 0.0000, 0.0000, 0.0000, 0.5000, 0.0000]]]])
"""


@public(warp.ACCUMULATE_DOC, warp.AccumulateOptions, example=ACCUMULATE_EXAMPLE)
def accumulate_warps(
    color: Float[Tensor, "b c h w"], velocity: Float[Tensor, "b 2 h w"] | None, *, offset_prev: Float[Tensor, "b 2 h w"] | None = None, offset_next: Float[Tensor, "b 2 h w"] | None = None, **options
) -> Float[Tensor, "b c h w"]:
    return warp.accumulate_warps(TORCH, color, velocity, offset_prev=offset_prev, offset_next=offset_next, **options)


WARP_BLEND_EXAMPLE = """
    >>> import torch
    >>> color = torch.zeros(1, 1, 1, 9); color[..., 4] = 1.0
    >>> velocity = torch.zeros(1, 2, 1, 9); velocity[:, 0] = 3.0
    >>> warp_blend(color, velocity, iterations=1, alpha=0.5).tolist()  # taps at -2, 0, +2 px
    [[[[0.0, 0.0, 0.25, 0.0, 0.5, 0.0, 0.25, 0.0, 0.0]]]]
"""


@public(warp.WARP_BLEND_DOC, warp.WarpBlendOptions, example=WARP_BLEND_EXAMPLE)
def warp_blend(color: Float[Tensor, "b c h w"], velocity: Float[Tensor, "b 2 h w"], **options) -> Float[Tensor, "b c h w"]:
    return warp.warp_blend(TORCH, color, velocity, **options)
