"""`velocity_from_motion_ids` in PyTorch (defined in `diffblur.ops.motion_ids`)."""

from __future__ import annotations

from jaxtyping import Float, Int
from torch import Tensor

from diffblur.ops import motion_ids
from diffblur.ops._options import public
from torch_impl._backend import TORCH

EXAMPLE = """
    >>> import torch
    >>> ids = torch.tensor([[[[0, 1], [1, 0]]]])
    >>> palette = torch.tensor([[[0.0, 0.0], [3.0, -1.0]]], requires_grad=True)
    >>> velocity_from_motion_ids(ids, palette)[0, 0].tolist()
    [[0.0, 3.0], [3.0, 0.0]]
"""


@public(motion_ids.DOC, example=EXAMPLE)
def velocity_from_motion_ids(
    ids: Int[Tensor, "b 1 h w"], palette: Float[Tensor, "b k d"], *, depth: Float[Tensor, "b 1 h w"] | None = None, focal: float | None = None, principal_point: tuple[float, float] | None = None
) -> Float[Tensor, "b 2 h w"]:
    return motion_ids.velocity_from_motion_ids(TORCH, ids, palette, depth=depth, focal=focal, principal_point=principal_point)
