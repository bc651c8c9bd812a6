"""`reconstruct` in PyTorch (defined in `diffblur.ops.reconstruct`)."""

from __future__ import annotations

from jaxtyping import Float
from torch import Tensor

from diffblur.ops import reconstruct as op
from diffblur.ops._options import public
from torch_impl._backend import TORCH


@public(op.DOC, op.ReconstructOptions)
def reconstruct(color: Float[Tensor, "b c h w"], velocity: Float[Tensor, "b 2 h w"], depth: Float[Tensor, "b 1 h w"], **options) -> Float[Tensor, "b c h w"]:
    return op.reconstruct(TORCH, color, velocity, depth, **options)
