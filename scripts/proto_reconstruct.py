"""Prototypes of seed 000's follow-ups in reconstruct, on torch tensor ops (measurement only):
a jittered NeighborMax lookup and a directional weight on the taps."""

from __future__ import annotations

import functools
import math

import torch

from diffblur import reference
from diffblur.ops import primitives, sampling
from diffblur.ops.reconstruct import ReconstructOptions
from diffblur.ops.taps import reconstruct_tap_time, shutter_factor
from torch_impl import neighbor_max, tile_max
from torch_impl._backend import TORCH

# The unchecked math of the ops (`diffblur.ops`), for PyTorch.
_cone, _cylinder, _safe_length, _soft_depth_compare = (functools.partial(f, TORCH) for f in (primitives.cone, primitives.cylinder, primitives.safe_length, primitives.soft_depth_compare))
pixel_grid, sample = functools.partial(sampling.pixel_grid, TORCH), functools.partial(sampling.sample, TORCH)


def reconstruct(color, velocity, depth, *, max_radius=20.0, samples=15, relative=0.3, lookup_jitter=0.0, directional=False, min_radius=0.5):
    o = ReconstructOptions(max_radius=max_radius, samples=samples, relative_z_extent=relative, shutter="box", min_radius=min_radius)
    batch, channels, height, width = color.shape
    tile = o.tile
    depth = torch.log(depth)
    neighbors = neighbor_max(tile_max(velocity, tile))  # (B, 2, TH, TW)
    noise = torch.tensor(reference.noise_jitter(height, width), dtype=color.dtype).reshape(1, 1, height, width)
    x, y = pixel_grid(height, width, color)
    x, y = x.unsqueeze(1), y.unsqueeze(1)
    if lookup_jitter:
        # a second, decorrelated noise for y: the same IGN read at the transposed pixel
        noise_t = torch.tensor(reference.noise_jitter(width, height), dtype=color.dtype).T.reshape(1, 1, height, width)
        jx = (x + lookup_jitter * tile * noise) / tile
        jy = (y + lookup_jitter * tile * noise_t) / tile
    else:
        jx, jy = x / tile, y / tile
    tx = torch.clamp(torch.floor(jx), 0, neighbors.shape[3] - 1).long()
    ty = torch.clamp(torch.floor(jy), 0, neighbors.shape[2] - 1).long()
    flat = neighbors.reshape(batch, 2, -1)
    idx = (ty * neighbors.shape[3] + tx).reshape(1, 1, -1).expand(batch, 2, -1)
    v_n = torch.gather(flat, 2, idx).reshape(batch, 2, height, width)
    speed_n = _safe_length(v_n)
    length_x = _safe_length(velocity)
    speed_x = torch.clamp(length_x, min=min_radius)
    buffers = torch.cat([color, velocity, depth], dim=1)
    center = 1.0
    weight = center / speed_x
    total = weight * color
    dir_n = v_n / torch.clamp(speed_n, min=1e-3)
    for k in range(samples):
        if k == (samples - 1) // 2:
            continue
        t = reconstruct_tap_time(k, noise, samples)
        tap_x, tap_y = x + v_n[:, :1] * t, y + v_n[:, 1:] * t
        read = sample(buffers, tap_x[:, 0], tap_y[:, 0], "bilinear")
        distance = torch.abs(t) * speed_n
        c_y, v_y, z_y = read[:, :channels], read[:, channels:channels + 2], read[:, channels + 2:]
        speed_y = torch.clamp(_safe_length(v_y), min=min_radius)
        front = _soft_depth_compare(depth, z_y, o.band) * _cone(distance, speed_y)
        if directional:  # seed 000 sec. 2.3: case 1 assumes V[Y] lies along v_N
            front = front * torch.abs((v_y * dir_n).sum(1, keepdim=True)) / speed_y.clamp(min=1e-3)
        alpha = front + _soft_depth_compare(z_y, depth, o.band) * _cone(distance, speed_x) + _cylinder(distance, speed_y) * _cylinder(distance, speed_x) * 2.0
        weight = weight + alpha
        total = total + alpha * c_y
    return total / weight
