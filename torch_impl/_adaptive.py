"""Tiled adaptive sampling (seed 001) for `gather_blur` and `reconstruct`: each class of tiles runs its
own tap count on the compacted pixels of its tiles; still tiles cost nothing (`diffblur._adaptive`).

The compacted filters below are the full-image filters written for a flat list of pixels: images
are read as (B * H * W, K) tables, a pixel is its flat index b * H * W + y * W + x. They repeat the
full-image filters' arithmetic, so a tile whose class is the full rate gets the same values (tests
compare them). Their backward keeps each tap's intermediates (no per-tap recompute): memory
O(moving pixels x taps), which the saving usually pays for.
"""

from __future__ import annotations

import torch
from torch import Tensor

from diffblur._adaptive import ADAPTIVE_TILE, STILL_SPEED, class_pixels, still_speed, tile_sample_counts
from diffblur.conventions import EARLY_OUT_SPEED
from diffblur.taps import gather_tap_times, reconstruct_tap_time, shutter_factor, stratum_weights
from torch_impl._primitives import _cone, _cylinder, _safe_length, _soft_depth_compare, neighbor_max, tile_max
from torch_impl._sampling import _clamp, position_dtype


def _table(image: Tensor) -> Tensor:
    """(B, K, H, W) -> (B * H * W, K), one row per pixel."""
    batch, channels, height, width = image.shape
    return image.permute(0, 2, 3, 1).reshape(batch * height * width, channels)


def _untable(table: Tensor, batch: int, height: int, width: int) -> Tensor:
    return table.reshape(batch, height, width, -1).permute(0, 3, 1, 2).contiguous()


def _sample_rows(table: Tensor, base: Tensor, x: Tensor, y: Tensor, height: int, width: int, mode: str) -> Tensor:
    """table (B * H * W, K) at positions x, y (P,) of the images starting at rows `base` (P,), as
    `torch_impl._sampling.sample` reads them (border clamp, a + f (b - a)), in x's dtype."""
    x = _clamp(x, width - 1.0)
    y = _clamp(y, height - 1.0)
    if mode == "nearest":
        column = torch.floor(x + 0.5).long().clamp(0, width - 1)
        row = torch.floor(y + 0.5).long().clamp(0, height - 1)
        return table[base + row * width + column].to(x.dtype)
    x0, y0 = torch.floor(x), torch.floor(y)
    fx, fy = (x - x0).unsqueeze(1), (y - y0).unsqueeze(1)
    column0, row0 = x0.long().clamp(0, width - 1), y0.long().clamp(0, height - 1)
    column1 = (column0 + 1).clamp(max=width - 1)
    row1 = (row0 + 1).clamp(max=height - 1)
    read = lambda row, column: table[base + row * width + column].to(x.dtype)  # noqa: E731
    top_left = read(row0, column0)
    bottom_left = read(row1, column0)
    top = top_left + fx * (read(row0, column1) - top_left)
    bottom = bottom_left + fx * (read(row1, column1) - bottom_left)
    return top + fy * (bottom - top)


def _coordinates(index: Tensor, height: int, width: int, dtype) -> tuple[Tensor, Tensor, Tensor]:
    """Row base b * H * W, and x, y (P,) in `position_dtype(dtype)`, of flat pixel indices."""
    plane = height * width
    within = index % plane
    dtype = position_dtype(dtype)
    return index - within, (within % width).to(dtype), (within // width).to(dtype)


def _tile_index(index: Tensor, height: int, width: int, tile: int, tiles_y: int, tiles_x: int) -> Tensor:
    """The flat index b * TH * TW + ty * TW + tx of each flat pixel index's tile, in integers."""
    plane = height * width
    within = index % plane
    return (index // plane) * (tiles_y * tiles_x) + (within // width // tile) * tiles_x + (within % width) // tile


def _pixel_counts(counts: Tensor, tile: int, height: int, width: int) -> Tensor:
    """(B, TH, TW) tile counts -> (B, 1, H, W) per pixel."""
    return counts.repeat_interleave(tile, dim=1).repeat_interleave(tile, dim=2)[:, None, :height, :width]


def _select(color: Tensor, by_count: dict[int, Tensor], pixel_counts: Tensor) -> Tensor:
    out = color
    for count, filtered in by_count.items():
        out = torch.where(pixel_counts == count, filtered, out)
    return out


def _compacted(color: Tensor, counts: Tensor, classes: tuple[int, ...], tile: int, run) -> Tensor:
    """Run `run(index, count)` -> (P, C) on the pixels of each class's tiles; still pixels keep color."""
    batch, _, height, width = color.shape
    counts = counts.cpu().numpy()
    out = _table(color)
    for count in classes:
        pixels = class_pixels(counts, count, tile, height, width)
        if pixels.size:
            index = torch.from_numpy(pixels).to(color.device)
            out = out.index_copy(0, index, run(index, count))
    return _untable(out, batch, height, width)


def adaptive_gather(color: Tensor, velocity: Tensor, classes: tuple[int, ...], window, sampling: str) -> Tensor:
    """gather_blur with tiled adaptive sampling (tiles of ADAPTIVE_TILE px, speed = max |V|)."""
    from torch_impl._gather import gather_blur

    batch, _, height, width = color.shape
    tile = ADAPTIVE_TILE
    speed = _safe_length(tile_max(velocity.detach(), tile))[:, 0]
    counts = tile_sample_counts(speed, classes, STILL_SPEED, torch)
    if torch.compiler.is_compiling():
        # fused=False: this is the tensor-op path (the fused kernel sizes the classes itself).
        full = {c: gather_blur(color, velocity, samples=c, shutter=window, sampling=sampling, fused=False) for c in classes}
        return _select(color, full, _pixel_counts(counts, tile, height, width))
    color_table, velocity_table = _table(color), _table(velocity)

    def run(index: Tensor, count: int) -> Tensor:
        times = gather_tap_times(count)
        base, x, y = _coordinates(index, height, width, color.dtype)  # float32 for a half image
        masses = stratum_weights(window, torch.as_tensor(times, dtype=x.dtype, device=color.device), 1.0 / count, torch)
        masses = masses / masses.sum()
        v = velocity_table[index].to(x.dtype)
        out = 0.0
        for k, tau in enumerate(times):
            out = out + masses[k] * _sample_rows(color_table, base, x - tau * v[:, 0], y - tau * v[:, 1], height, width, sampling)
        return out.to(color.dtype)

    return _compacted(color, counts, classes, tile, run)


def adaptive_reconstruct(color, velocity, depth, jitter, o) -> Tensor:
    """reconstruct with tiled adaptive sampling: its tiles (ceil(max_radius)), speed = |NeighborMax|."""
    from torch_impl._reconstruct import _at_least, _reconstruct

    batch, channels, height, width = color.shape
    tile = o.tile
    neighbors = neighbor_max(tile_max(velocity, tile))
    counts = tile_sample_counts(_safe_length(neighbors.detach())[:, 0], o.classes, still_speed(o.early_out), torch)
    if torch.compiler.is_compiling():
        full = {
            c: _reconstruct(color, velocity, depth, tile, c, o.soft_z_extent, jitter, o.sampling, o.window, o.early_out, o.directions, o.min_radius)
            for c in o.classes
        }
        return _select(color, full, _pixel_counts(counts, tile, height, width))
    buffers = _table(torch.cat([color, velocity, depth], dim=1))
    neighbor_table = _table(neighbors)
    jitter_table = _table(jitter)
    tiles_y, tiles_x = neighbors.shape[2:]

    def run(index: Tensor, count: int) -> Tensor:
        # Positions, tap offsets, weights and sums in float32 for a half image (as _reconstruct).
        base, x, y = _coordinates(index, height, width, color.dtype)
        wide = x.dtype
        v_n = neighbor_table[_tile_index(index, height, width, tile, tiles_y, tiles_x)].to(wide)
        speed_n = _safe_length(v_n)
        own = buffers[index]
        c_x, v_x, z_x = own[:, :channels], own[:, channels : channels + 2].to(wide), own[:, channels + 2 :]
        length_x = _safe_length(v_x)
        speed_x = _at_least(length_x, o.min_radius)
        j = jitter_table[index if jitter.shape[0] == batch else index % (height * width)].to(wide)
        x, y = x[:, None], y[:, None]
        weight = shutter_factor(o.window, torch.zeros((), dtype=wide, device=color.device), count, torch) / speed_x
        total = weight * c_x
        for k in range(count):
            if k == (count - 1) // 2:
                continue
            t = reconstruct_tap_time(k, j, count)
            use_own = o.directions == "neighbor_and_own" and k % 2 == 1
            direction, speed = (v_x, length_x) if use_own else (v_n, speed_n)
            tap_x = x + direction[:, :1] * t
            tap_y = y + direction[:, 1:] * t
            read = _sample_rows(buffers, base, tap_x[:, 0], tap_y[:, 0], height, width, o.sampling)
            if o.sampling == "nearest":
                distance = torch.hypot(torch.floor(tap_x + 0.5) - x, torch.floor(tap_y + 0.5) - y)
            else:
                distance = torch.abs(t) * speed
            c_y, v_y, z_y = read[:, :channels], read[:, channels : channels + 2], read[:, channels + 2 :]
            speed_y = _at_least(_safe_length(v_y), o.min_radius)
            alpha = (
                _soft_depth_compare(z_x, z_y, o.soft_z_extent) * _cone(distance, speed_y)
                + _soft_depth_compare(z_y, z_x, o.soft_z_extent) * _cone(distance, speed_x)
                + _cylinder(distance, speed_y) * _cylinder(distance, speed_x) * 2.0
            ) * shutter_factor(o.window, -t, count, torch)
            weight = weight + alpha
            total = total + alpha * c_y
        out = total / weight
        if o.early_out:
            out = torch.where(speed_n <= EARLY_OUT_SPEED, c_x.to(wide), out)
        return out.to(color.dtype)

    return _compacted(color, counts, o.classes, tile, run)
