"""The building blocks of seed 000 as batched, differentiable PyTorch ops.

Each mirrors a function of `diffblur.reference` (the oracle) and of `jax_impl._primitives`.
Clamps are written with `torch.where` so the gradient at a clamp boundary is that of the inside,
the same convention as the JAX backend.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from jaxtyping import Float
from torch import Tensor

from diffblur import checks
from diffblur.conventions import (
    CYLINDER_INNER,
    CYLINDER_OUTER,
    DEFAULT_MAX_RADIUS,
    DEFAULT_MIN_RADIUS,
    DEPTH_CHANNELS,
    EPSILON,
    IGN_A,
    IGN_B,
    IGN_C,
    VECTOR_CHANNELS,
)
from torch_impl import _checks

__all__ = [
    "cone",
    "cylinder",
    "interleaved_gradient_noise",
    "neighbor_max",
    "safe_length",
    "soft_depth_compare",
    "tile_max",
    "velocity_from_motion",
]


def _clamp01(x: Tensor) -> Tensor:
    return torch.where(x < 0, 0.0, torch.where(x > 1, 1.0, x))


def _floor_speed(speed: Tensor) -> Tensor:
    return torch.where(speed < EPSILON, EPSILON, speed)


def _floor_extent(extent: float | Tensor) -> float | Tensor:
    """Array extents below sqrt(smallest normal) of their dtype count as that value: below it the
    gradient (z_b - z_a) / extent**2 would overflow to inf and turn into NaN at the clamps.
    The output is a step there either way."""
    if isinstance(extent, float):
        return extent
    floor = torch.finfo(extent.dtype).tiny ** 0.5
    return torch.where(extent < floor, floor, extent)


def _soft_depth_compare(z_a: Tensor, z_b: Tensor, extent: float | Tensor) -> Tensor:
    # clamp(1 - (z_b - z_a) / extent, 0, 1), with the division only inside the soft band (double
    # where): outside it a tiny extent would give an infinite derivative times a zero cotangent.
    extent = _floor_extent(extent)
    behind = z_b - z_a
    in_band = (behind >= 0) & (behind <= extent)
    ramp = 1.0 - torch.where(in_band, behind, 0.0) / extent
    return torch.where(behind < 0, 1.0, torch.where(behind > extent, 0.0, ramp))


def _widen(x: Tensor) -> Tensor:
    """float32 for the half types. The classifiers' ratio distance / speed reaches 1e7 (1e4 px over
    the 1e-3 px floor), past float16's 65504: the clamp hides it forward, but the backward's
    0 * inf would be NaN."""
    return x.float() if x.dtype in (torch.float16, torch.bfloat16) else x


def _cone(distance: Tensor, speed: Tensor) -> Tensor:
    dtype = distance.dtype
    distance, speed = _widen(distance), _widen(speed)
    return _clamp01(1.0 - distance / _floor_speed(speed)).to(dtype)


def _cylinder(distance: Tensor, speed: Tensor) -> Tensor:
    dtype = distance.dtype
    distance, speed = _widen(distance), _floor_speed(_widen(speed))
    t = _clamp01((distance - CYLINDER_INNER * speed) / ((CYLINDER_OUTER - CYLINDER_INNER) * speed))
    return (1.0 - t * t * (3.0 - 2.0 * t)).to(dtype)


def _squared_length(vector: Tensor, axis: int) -> Tensor:
    """Sum of squares along `axis` (kept), in float32 for the half types: in float16 a vector
    longer than 256 px would square to infinity."""
    if vector.dtype in (torch.float16, torch.bfloat16):
        vector = vector.float()
    return torch.sum(vector * vector, dim=axis, keepdim=True)


def _safe_length(vector: Tensor, axis: int = 1) -> Tensor:
    squared = _squared_length(vector, axis)
    # Double where: sqrt never sees 0, so its infinite derivative never meets the zero cotangent.
    positive = squared > 0
    return torch.where(positive, torch.sqrt(torch.where(positive, squared, 1.0)), 0.0).to(vector.dtype)


def soft_depth_compare(z_a: Float[Tensor, "*shape"], z_b: Float[Tensor, "*shape"], extent: float | Tensor) -> Float[Tensor, "*shape"]:
    """Seed 000's softDepthCompare for positive depth: ~1 where z_b is in front of z_a.

    Args:
        z_a, z_b: depths of the same shape (any), positive, larger = farther.
        extent: the soft band, in depth units, > 0: a number, a 0-d tensor or a tensor of z's shape.
            A tensor extent below sqrt(finfo(dtype).tiny) (1.1e-19 in float32) counts as that value.

    Returns:
        clamp(1 - (z_b - z_a) / extent, 0, 1): 1 where z_b <= z_a, 0 where z_b >= z_a + extent.

    >>> import torch
    >>> soft_depth_compare(torch.tensor([2.0, 2.0, 2.0]), torch.tensor([1.0, 2.5, 4.0]), 1.0)
    tensor([1.0000, 0.5000, 0.0000])
    """
    _checks.floating_tensor("z_a", z_a)
    _checks.same_shape("z_b", _checks.floating_tensor("z_b", z_b), "z_a", z_a)
    extent = _checks.positive_scalar("extent", extent, z_a)
    return _soft_depth_compare(z_a, z_b, extent)


def cone(distance: Float[Tensor, "*shape"], speed: Float[Tensor, "*shape"]) -> Float[Tensor, "*shape"]:
    """Seed 000's cone: is a point `distance` px away inside the blur of a point moving at `speed` px?

    Args:
        distance: distances in pixels, >= 0, any shape.
        speed: lengths of the half-spread velocity in pixels, the shape of `distance`; speeds below
            `diffblur.conventions.EPSILON` count as EPSILON.

    Returns:
        clamp(1 - distance / speed, 0, 1).

    >>> import torch
    >>> cone(torch.tensor([0.0, 1.0, 3.0]), torch.tensor([2.0, 2.0, 2.0]))
    tensor([1.0000, 0.5000, 0.0000])
    """
    _checks.floating_tensor("distance", distance)
    _checks.same_shape("speed", _checks.floating_tensor("speed", speed), "distance", distance)
    return _cone(distance, speed)


def cylinder(distance: Float[Tensor, "*shape"], speed: Float[Tensor, "*shape"]) -> Float[Tensor, "*shape"]:
    """Seed 000's cylinder: 1 - smoothstep(0.95 speed, 1.05 speed, distance).

    Args:
        distance: distances in pixels, any shape.
        speed: speeds in pixels, the shape of `distance`; below EPSILON they count as EPSILON.

    >>> import torch
    >>> cylinder(torch.tensor([0.0, 2.0, 3.0]), torch.tensor([2.0, 2.0, 2.0]))
    tensor([1.0000, 0.5000, 0.0000])
    """
    _checks.floating_tensor("distance", distance)
    _checks.same_shape("speed", _checks.floating_tensor("speed", speed), "distance", distance)
    return _cylinder(distance, speed)


def safe_length(vector: Float[Tensor, "b c h w"], *, axis: int = 1) -> Float[Tensor, "b 1 h w"]:
    """Euclidean length along `axis` (kept, size 1) whose gradient at the zero vector is 0, not NaN.

    >>> import torch
    >>> v = torch.zeros(1, 2, 1, 1, requires_grad=True)
    >>> safe_length(v).sum().backward()
    >>> v.grad.flatten().tolist()
    [0.0, 0.0]
    """
    _checks.floating_tensor("vector", vector)
    if not -vector.ndim <= axis < vector.ndim:
        raise ValueError(f"axis must be in [{-vector.ndim}, {vector.ndim}) for a {vector.ndim}-d vector, got {axis}")
    return _safe_length(vector, axis)


def velocity_from_motion(
    displacement: Float[Tensor, "b 2 h w"],
    *,
    exposure: float | Tensor = 1.0,
    max_radius: float = DEFAULT_MAX_RADIUS,
    min_radius: float = DEFAULT_MIN_RADIUS,
) -> Float[Tensor, "b 2 h w"]:
    """Seed 000 sec. 2.2: the half-spread velocity from the per-frame displacement X - X'.

    Args:
        displacement: (B, 2, H, W) pixels moved over one frame, channel 0 = x, 1 = y.
        exposure: exposure time x frame rate (1 = shutter open all frame): a number, a 0-d tensor or
            a (B,) tensor; differentiable.
        max_radius: the clamp k in pixels, > 0 (math.inf for none).
        min_radius: the smallest blur radius in pixels, >= 0 and <= max_radius (seed 000: 0.5).

    Returns:
        (B, 2, H, W) q / |q| * clamp(|q|, min_radius, max_radius) with q = displacement * exposure / 2.
        Exact for |q| in [min_radius, max_radius]; at q = 0 it is 0 with a finite gradient.

    >>> import torch
    >>> d = torch.tensor([3.0, 4.0, 0.2, 0.0, 60.0, 80.0]).reshape(3, 2, 1, 1).permute(1, 0, 2, 3).reshape(1, 2, 1, 3)
    >>> velocity_from_motion(d, exposure=1.0, max_radius=20.0).squeeze().T
    tensor([[ 1.5000,  2.0000],
            [ 0.5000,  0.0000],
            [12.0000, 16.0000]])
    """
    _checks.image("displacement", displacement, channels=VECTOR_CHANNELS)
    _checks.finite_values("displacement", displacement)
    max_radius = checks.require_positive_number("max_radius", max_radius)
    min_radius = checks.require_nonnegative_number("min_radius", min_radius)
    if min_radius > max_radius:
        raise ValueError(f"min_radius must be <= max_radius ({max_radius}), got {min_radius}")
    exposure = _checks.per_batch_scalar("exposure", exposure, displacement)
    q = 0.5 * displacement * exposure
    length = _safe_length(q)
    radius = torch.where(length < min_radius, min_radius, torch.where(length > max_radius, max_radius, length))
    return q * (radius / _floor_speed(length))


def _vmax_gather(candidates: Tensor, squared: Tensor, dim: int) -> Tensor:
    """Pick, along `dim` of `candidates` (B, 2, ..., N, ...), the vector whose `squared` length
    (B, ..., N, ...) is largest; argmax returns the first maximum, which is the tie rule."""
    index = torch.argmax(squared, dim=dim - 1, keepdim=True).unsqueeze(1)
    index = index.expand(*candidates.shape[:dim], 1, *candidates.shape[dim + 1 :])
    return torch.gather(candidates, dim, index).squeeze(dim)


def tile_max(velocity: Float[Tensor, "b 2 h w"], tile: int) -> Float[Tensor, "b 2 th tw"]:
    """Seed 000 eq. 1: the largest-magnitude velocity of each tile x tile block.

    Args:
        velocity: (B, 2, H, W) in pixels; H and W need not be multiples of `tile`.
        tile: tile size in pixels (seed 000 uses the max radius k), an integer >= 1.

    Returns:
        (B, 2, ceil(H / tile), ceil(W / tile)). Ties go to the first pixel in row-major order; the
        gradient flows to the chosen pixel.
    """
    _checks.image("velocity", velocity, channels=VECTOR_CHANNELS)
    tile = checks.require_positive_int("tile", tile)
    batch, _, height, width = velocity.shape
    tiles_y, tiles_x = -(-height // tile), -(-width // tile)
    pad_y, pad_x = tiles_y * tile - height, tiles_x * tile - width
    squared = _squared_length(velocity, 1)[:, 0]
    # Padding gets squared length -1 so it never wins, not even against a zero vector.
    squared = F.pad(squared, (0, pad_x, 0, pad_y), value=-1.0)
    padded = F.pad(velocity, (0, pad_x, 0, pad_y))
    squared = squared.reshape(batch, tiles_y, tile, tiles_x, tile).permute(0, 1, 3, 2, 4)
    padded = padded.reshape(batch, 2, tiles_y, tile, tiles_x, tile).permute(0, 1, 2, 4, 3, 5)
    squared = squared.reshape(batch, tiles_y, tiles_x, tile * tile)
    padded = padded.reshape(batch, 2, tiles_y, tiles_x, tile * tile)
    return _vmax_gather(padded, squared, dim=4)


def neighbor_max(tile_velocity: Float[Tensor, "b 2 th tw"]) -> Float[Tensor, "b 2 th tw"]:
    """Seed 000 eq. 2: the largest-magnitude vector of each tile's 3 x 3 tile neighbourhood.

    Args:
        tile_velocity: (B, 2, TH, TW), usually `tile_max`'s output.

    Returns:
        (B, 2, TH, TW). Tiles beyond the border take no part; ties go to the first in row-major
        order of the neighbourhood (top-left first).
    """
    _checks.image("tile_velocity", tile_velocity, channels=VECTOR_CHANNELS)
    _, _, tiles_y, tiles_x = tile_velocity.shape
    squared = F.pad(_squared_length(tile_velocity, 1)[:, 0], (1, 1, 1, 1), value=-1.0)
    padded = F.pad(tile_velocity, (1, 1, 1, 1))
    offsets = [(dy, dx) for dy in range(3) for dx in range(3)]
    candidates = torch.stack([padded[:, :, dy : dy + tiles_y, dx : dx + tiles_x] for dy, dx in offsets], dim=2)
    candidate_squared = torch.stack([squared[:, dy : dy + tiles_y, dx : dx + tiles_x] for dy, dx in offsets], dim=1)
    return _vmax_gather(candidates, candidate_squared, dim=2)


def interleaved_gradient_noise(
    height: int, width: int, *, dtype: torch.dtype | None = None, device: torch.device | str | None = None
) -> Float[Tensor, "h w"]:
    """Interleaved gradient noise at integer pixel coordinates, in [0, 1), shape (height, width).

    Computed in float64 (bit-identical to `diffblur.reference.interleaved_gradient_noise` and to
    the JAX backend), then cast to `dtype` (default: torch's default dtype) on `device`.
    """
    height = checks.require_positive_int("height", height)
    width = checks.require_positive_int("width", width)
    y = torch.arange(height, dtype=torch.float64).reshape(-1, 1)
    x = torch.arange(width, dtype=torch.float64).reshape(1, -1)
    inner = IGN_A * x + IGN_B * y
    inner = inner - torch.floor(inner)
    outer = IGN_C * inner
    noise = outer - torch.floor(outer)
    return noise.to(device=device, dtype=dtype or torch.get_default_dtype())
