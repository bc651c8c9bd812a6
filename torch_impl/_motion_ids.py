"""Vector motion IDs (seed 001) in PyTorch: an ID map and a palette of motions to a velocity field.

The formulas are in `diffblur.motion_ids`, the NumPy reference."""

from __future__ import annotations

import torch
from jaxtyping import Float, Int
from torch import Tensor

from diffblur import motion_ids
from torch_impl import _checks


def velocity_from_motion_ids(
    ids: Int[Tensor, "b 1 h w"],
    palette: Float[Tensor, "b k d"],
    *,
    depth: Float[Tensor, "b 1 h w"] | None = None,
    focal: float | None = None,
    principal_point: tuple[float, float] | None = None,
) -> Float[Tensor, "b 2 h w"]:
    """The (B, 2, H, W) image velocity of a per-pixel motion ID map, differentiable w.r.t. the palette.

    Args:
        ids: (B, 1, H, W) integer IDs, each in [0, K).
        palette: (B, K, 2) image velocities (pixels, half-spread, channel 0 = x), or (B, K, 3)
            world velocities (Vx, Vy, Vz), the half-spread in camera space in depth's units.
        depth: (B, 1, H, W) positive depth; needed for (and only for) a (B, K, 3) palette, with
            |Vz| < depth everywhere.
        focal: the pinhole's focal length in pixels (a (B, K, 3) palette only).
        principal_point: (cx, cy) in pixels; default the image centre ((W - 1) / 2, (H - 1) / 2).

    Returns:
        (B, 2, H, W) velocity in pixels; a world velocity V at depth Z is projected exactly as the
        half-spread (proj(P + V) - proj(P - V)) / 2 (see `diffblur.motion_ids`).

    >>> ids = torch.tensor([[[[0, 1], [1, 0]]]])
    >>> palette = torch.tensor([[[0.0, 0.0], [3.0, -1.0]]], requires_grad=True)
    >>> velocity_from_motion_ids(ids, palette)[0, 0]
    tensor([[0., 3.],
            [3., 0.]], grad_fn=<SelectBackward0>)
    """
    ids = _checks.tensor("ids", ids)
    palette = _checks.floating_tensor("palette", palette)
    if depth is not None:
        depth = _checks.floating_tensor("depth", depth)
    focal, center = motion_ids.check_motion_id_arguments(
        ids.shape,
        not ids.dtype.is_floating_point and not ids.dtype.is_complex and ids.dtype != torch.bool,
        ids.dtype,
        palette.shape,
        None if depth is None else depth.shape,
        focal,
        principal_point,
    )
    batch, _, height, width = ids.shape
    palette_size, dims = palette.shape[1], palette.shape[2]
    if ids.device != palette.device:
        raise ValueError(f"ids must be on the device of palette ({palette.device}), got {ids.device}")
    _checks.require(lambda: ((ids >= 0) & (ids < palette_size)).all(), motion_ids.id_range_message(palette_size))
    index = ids.reshape(batch, height * width, 1).long().expand(batch, height * width, dims)
    entry = torch.gather(palette, 1, index).permute(0, 2, 1).reshape(batch, dims, height, width)
    if dims == 2:
        return entry
    _checks.same_dtype_and_device("depth", depth, "palette", palette)
    _checks.positive_values("depth", depth)
    vx, vy, vz = entry[:, 0:1], entry[:, 1:2], entry[:, 2:3]
    _checks.require(lambda: (vz.abs() < depth).all(), motion_ids.world_velocity_message())
    x = torch.arange(width, dtype=palette.dtype, device=palette.device).reshape(1, 1, 1, width)
    y = torch.arange(height, dtype=palette.dtype, device=palette.device).reshape(1, 1, height, 1)
    denominator = depth * depth - vz * vz
    u = depth * (focal * vx - (x - center[0]) * vz) / denominator
    v = depth * (focal * vy - (y - center[1]) * vz) / denominator
    return torch.cat([u, v], dim=1)
