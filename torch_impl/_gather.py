"""`gather_blur` in PyTorch (defined in `diffblur.ops.gather`)."""

from __future__ import annotations

from jaxtyping import Float
from torch import Tensor

from diffblur.ops import gather
from diffblur.ops._options import public
from torch_impl._backend import TORCH

EXAMPLE = """
    >>> import torch
    >>> color = torch.tensor([0.0, 0.0, 1.0, 0.0, 0.0]).reshape(1, 1, 1, 5)
    >>> velocity = torch.zeros(1, 2, 1, 5); velocity[:, 0] = 1.0
    >>> gather_blur(color, velocity, samples=3)
    tensor([[[[0.0000, 0.2222, 0.5556, 0.2222, 0.0000]]]])
"""


@public(gather.DOC, gather.GatherOptions, example=EXAMPLE)
def gather_blur(color: Float[Tensor, "b c h w"], velocity: Float[Tensor, "b 2 h w"], **options) -> Float[Tensor, "b c h w"]:
    return gather.gather_blur(TORCH, color, velocity, **options)
