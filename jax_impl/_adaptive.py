"""Tiled adaptive sampling (seed 001) for `gather_blur` and `reconstruct`: each class of tiles runs its
own tap count on the compacted pixels of its tiles; still tiles cost nothing (`diffblur._adaptive`).

JAX needs static sizes. When the velocity is concrete (eager calls, also under jax.grad / jax.vjp,
whose primal values are concrete), the tile classes are read on the host and each class's filter
runs on its pixels, their count padded up to a power of two so that few sizes are compiled; the
whole compacted computation (tables, classes, scatter back) is one jit-compiled function once the
moving pixels number JIT_MIN_PIXELS or more (below that, op by op: compiling would cost more). Under jax.jit the velocity is traced and the classes cannot size arrays: every class runs
on every pixel and the result is selected per tile (the same values, no saving).

The compacted filters are the full-image filters written for a flat list of pixels: images are read
as (B * H * W, K) tables, a pixel is its flat index b * H * W + y * W + x.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from diffblur._adaptive import ADAPTIVE_TILE, STILL_SPEED, class_pixels, still_speed, tile_sample_counts
from diffblur.conventions import EARLY_OUT_SPEED
from diffblur.taps import gather_tap_times, reconstruct_tap_time, shutter_factor, stratum_weights
from jax_impl._primitives import _cone, _cylinder, _safe_length, _soft_depth_compare, neighbor_max, tile_max
from jax_impl._sampling import _clamp, position_dtype, widen_window


def _table(image: Array) -> Array:
    """(B, K, H, W) -> (B * H * W, K), one row per pixel."""
    batch, channels, height, width = image.shape
    return image.transpose(0, 2, 3, 1).reshape(batch * height * width, channels)


def _untable(table: Array, batch: int, height: int, width: int) -> Array:
    return table.reshape(batch, height, width, -1).transpose(0, 3, 1, 2)


def _sample_rows(table: Array, base: Array, x: Array, y: Array, height: int, width: int, mode: str) -> Array:
    """table (B * H * W, K) at positions x, y (P,) of the images starting at rows `base` (P,), as
    `jax_impl._sampling.sample` reads them (border clamp, a + f (b - a)), in x's dtype."""
    x = _clamp(x, width - 1.0)
    y = _clamp(y, height - 1.0)
    if mode == "nearest":
        column = jnp.minimum(jnp.floor(x + 0.5).astype(jnp.int32), width - 1)
        row = jnp.minimum(jnp.floor(y + 0.5).astype(jnp.int32), height - 1)
        return table[base + row * width + column].astype(x.dtype)
    x0 = jax.lax.stop_gradient(jnp.floor(x))
    y0 = jax.lax.stop_gradient(jnp.floor(y))
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    column0, row0 = jnp.minimum(x0.astype(jnp.int32), width - 1), jnp.minimum(y0.astype(jnp.int32), height - 1)
    column1 = jnp.minimum(column0 + 1, width - 1)
    row1 = jnp.minimum(row0 + 1, height - 1)
    read = lambda row, column: table[base + row * width + column].astype(x.dtype)  # noqa: E731
    top_left = read(row0, column0)
    bottom_left = read(row1, column0)
    top = top_left + fx * (read(row0, column1) - top_left)
    bottom = bottom_left + fx * (read(row1, column1) - bottom_left)
    return top + fy * (bottom - top)


def _coordinates(index: Array, height: int, width: int, dtype) -> tuple[Array, Array, Array]:
    """Row base b * H * W, and x, y (P,) in `position_dtype(dtype)`, of flat pixel indices."""
    plane = height * width
    within = index % plane
    dtype = position_dtype(dtype)
    return index - within, (within % width).astype(dtype), (within // width).astype(dtype)


def _tile_index(index: Array, height: int, width: int, tile: int, tiles_y: int, tiles_x: int) -> Array:
    """The flat index b * TH * TW + ty * TW + tx of each flat pixel index's tile, in integers."""
    plane = height * width
    within = index % plane
    return (index // plane) * (tiles_y * tiles_x) + (within // width // tile) * tiles_x + (within % width) // tile


def _pixel_counts(counts: Array, tile: int, height: int, width: int) -> Array:
    return jnp.repeat(jnp.repeat(counts, tile, axis=1), tile, axis=2)[:, None, :height, :width]


def _select(color: Array, by_count: dict[int, Array], pixel_counts: Array) -> Array:
    out = color
    for count, filtered in by_count.items():
        out = jnp.where(pixel_counts == count, filtered, out)
    return out


def _concrete(x: Array) -> np.ndarray | None:
    """x's values when they are known now (not under jax.jit), else None."""
    try:
        return np.asarray(jax.lax.stop_gradient(x))
    except jax.errors.TracerArrayConversionError:
        return None


def _padded(pixels: np.ndarray, total: int) -> tuple[Array, Array]:
    """Indices padded up to one of 8 sizes per octave (at most 1/8 more work, few sizes to compile):
    (to read, valid ones then pixel 0) and (to write, the padding pointing past the end, which a
    scatter with mode="drop" ignores)."""
    step = 1 << max(int(pixels.size).bit_length() - 4, 0)
    size = -(-pixels.size // step) * step
    read = np.zeros(size, dtype=np.int32)
    write = np.full(size, total, dtype=np.int32)
    read[: pixels.size] = pixels
    write[: pixels.size] = pixels
    return jnp.asarray(read), jnp.asarray(write)


#: Images with fewer moving pixels than this run op by op: compiling costs more than it saves.
JIT_MIN_PIXELS = 4096


def _hashable(static: dict) -> bool:
    try:
        hash(tuple(static.values()))
    except TypeError:  # e.g. a shutter window whose parameters are arrays being fitted
        return False
    return True


def _class_indices(counts: np.ndarray, classes: tuple[int, ...], tile: int, height: int, width: int, total: int):
    """For each class with tiles: (count, read indices, write indices), padded (see _padded)."""
    found = []
    for count in classes:
        pixels = class_pixels(counts, count, tile, height, width)
        if pixels.size:
            found.append((count, *_padded(pixels, total), pixels.size))
    return found


def _gather_rows(color_table, velocity_table, index, masses, *, times, height, width, sampling):
    base, x, y = _coordinates(index, height, width, color_table.dtype)  # float32 for a half image
    v = velocity_table[index].astype(x.dtype)
    out = jnp.zeros((index.shape[0], color_table.shape[1]), dtype=x.dtype)
    for k, tau in enumerate(times):
        out = out + masses[k] * _sample_rows(color_table, base, x - tau * v[:, 0], y - tau * v[:, 1], height, width, sampling)
    return out


def _gather_compacted(color, velocity, masses, reads, writes, *, counts, sampling):
    """Each class's gather on its pixels, written into the image (one function, jit-compiled whole)."""
    batch, _, height, width = color.shape
    color_table, velocity_table = _table(color), _table(velocity)
    out = color_table
    for count, mass, read, write in zip(counts, masses, reads, writes):
        values = _gather_rows(color_table, velocity_table, read, mass, times=gather_tap_times(count), height=height, width=width, sampling=sampling)
        out = out.at[write].set(values.astype(out.dtype), mode="drop")
    return _untable(out, batch, height, width)


_gather_compacted_jit = jax.jit(_gather_compacted, static_argnames=("counts", "sampling"))


def adaptive_gather(color: Array, velocity: Array, classes: tuple[int, ...], window, sampling: str) -> Array:
    """gather_blur with tiled adaptive sampling (tiles of ADAPTIVE_TILE px, speed = max |V|)."""
    from jax_impl._gather import gather_blur

    batch, _, height, width = color.shape
    tile = ADAPTIVE_TILE
    speed = _safe_length(tile_max(jax.lax.stop_gradient(velocity), tile))[:, 0]
    concrete = _concrete(speed)
    if concrete is None:
        counts = tile_sample_counts(speed, classes, STILL_SPEED, jnp)
        # fused=False: this is the tensor-op path (the fused kernel sizes the classes itself).
        full = {c: gather_blur(color, velocity, samples=c, shutter=window, sampling=sampling, fused=False) for c in classes}
        return _select(color, full, _pixel_counts(counts, tile, height, width))
    found = _class_indices(tile_sample_counts(concrete, classes, STILL_SPEED, np), classes, tile, height, width, batch * height * width)
    if not found:
        return color
    masses = []
    wide = position_dtype(color.dtype)
    for count, *_ in found:
        mass = stratum_weights(widen_window(window, wide), jnp.asarray(gather_tap_times(count), dtype=wide), 1.0 / count, jnp)
        masses.append((mass / mass.sum()).astype(wide))
    counts = tuple(f[0] for f in found)
    run = _gather_compacted_jit if sum(f[3] for f in found) >= JIT_MIN_PIXELS else _gather_compacted
    return run(color, velocity, tuple(masses), tuple(f[1] for f in found), tuple(f[2] for f in found), counts=counts, sampling=sampling)


def _reconstruct_rows(
    buffers, neighbor_table, jitter_table, index, *, count, channels, height, width, tiles, tile, jitter_per_image, soft_z_extent, sampling, window, early_out, directions, min_radius
):
    from jax_impl._reconstruct import _at_least

    # Positions, tap offsets, weights and sums in float32 for a half image (as _reconstruct).
    dtype = buffers.dtype
    wide = position_dtype(dtype)
    window = widen_window(window, wide)
    tiles_y, tiles_x = tiles
    base, x, y = _coordinates(index, height, width, dtype)
    v_n = neighbor_table[_tile_index(index, height, width, tile, tiles_y, tiles_x)].astype(wide)
    speed_n = _safe_length(v_n)
    own = buffers[index].astype(wide)
    c_x, v_x, z_x = own[:, :channels], own[:, channels : channels + 2], own[:, channels + 2 :]
    length_x = _safe_length(v_x)
    speed_x = _at_least(length_x, min_radius)
    j = jitter_table[index if jitter_per_image else index % (height * width)].astype(wide)
    x, y = x[:, None], y[:, None]
    weight = (shutter_factor(window, jnp.zeros((), dtype=wide), count, jnp) / speed_x).astype(wide)
    total = weight * c_x
    for k in range(count):
        if k == (count - 1) // 2:
            continue
        t = reconstruct_tap_time(k, j, count).astype(wide)
        use_own = directions == "neighbor_and_own" and k % 2 == 1
        direction, speed = (v_x, length_x) if use_own else (v_n, speed_n)
        tap_x = x + direction[:, :1] * t
        tap_y = y + direction[:, 1:] * t
        read = _sample_rows(buffers, base, tap_x[:, 0], tap_y[:, 0], height, width, sampling)
        if sampling == "nearest":
            distance = jnp.hypot(jnp.floor(tap_x + 0.5) - x, jnp.floor(tap_y + 0.5) - y)
        else:
            distance = jnp.abs(t) * speed
        c_y, v_y, z_y = read[:, :channels], read[:, channels : channels + 2], read[:, channels + 2 :]
        speed_y = _at_least(_safe_length(v_y), min_radius)
        alpha = (
            _soft_depth_compare(z_x, z_y, soft_z_extent) * _cone(distance, speed_y)
            + _soft_depth_compare(z_y, z_x, soft_z_extent) * _cone(distance, speed_x)
            + _cylinder(distance, speed_y) * _cylinder(distance, speed_x) * 2.0
        ) * shutter_factor(window, -t, count, jnp)
        weight = weight + alpha.astype(wide)
        total = total + (alpha * c_y).astype(wide)
    out = total / weight
    if early_out:
        out = jnp.where(speed_n <= EARLY_OUT_SPEED, c_x, out)
    return out.astype(dtype)


def _reconstruct_compacted(color, velocity, depth, jitter, reads, writes, *, counts, tile, soft_z_extent, sampling, window, early_out, directions, min_radius):
    """Each class's filter on its pixels, written into the image (one function, jit-compiled whole)."""
    batch, channels, height, width = color.shape
    neighbors = neighbor_max(tile_max(velocity, tile))
    buffers = _table(jnp.concatenate([color, velocity, depth], axis=1))
    neighbor_table, jitter_table = _table(neighbors), _table(jitter)
    out = _table(color)
    for count, read, write in zip(counts, reads, writes):
        values = _reconstruct_rows(
            buffers,
            neighbor_table,
            jitter_table,
            read,
            count=count,
            channels=channels,
            height=height,
            width=width,
            tiles=tuple(neighbors.shape[2:]),
            tile=tile,
            jitter_per_image=jitter.shape[0] == batch,
            soft_z_extent=soft_z_extent,
            sampling=sampling,
            window=window,
            early_out=early_out,
            directions=directions,
            min_radius=min_radius,
        )
        out = out.at[write].set(values, mode="drop")
    return _untable(out, batch, height, width)


_RECONSTRUCT_STATIC = ("counts", "tile", "soft_z_extent", "sampling", "window", "early_out", "directions", "min_radius")
_reconstruct_compacted_jit = jax.jit(_reconstruct_compacted, static_argnames=_RECONSTRUCT_STATIC)


def adaptive_reconstruct(color, velocity, depth, jitter, o) -> Array:
    """reconstruct with tiled adaptive sampling: its tiles (ceil(max_radius)), speed = |NeighborMax|."""
    from jax_impl._reconstruct import _reconstruct

    batch, _, height, width = color.shape
    tile = o.tile
    speed = _safe_length(neighbor_max(tile_max(jax.lax.stop_gradient(velocity), tile)))[:, 0]
    still = still_speed(o.early_out)
    concrete = _concrete(speed)
    if concrete is None:
        counts = tile_sample_counts(speed, o.classes, still, jnp)
        full = {
            c: _reconstruct(color, velocity, depth, tile, c, o.soft_z_extent, jitter, o.sampling, o.window, o.early_out, o.directions, o.min_radius)
            for c in o.classes
        }
        return _select(color, full, _pixel_counts(counts, tile, height, width))
    found = _class_indices(tile_sample_counts(concrete, o.classes, still, np), o.classes, tile, height, width, batch * height * width)
    if not found:
        return color
    static = dict(
        counts=tuple(f[0] for f in found),
        tile=tile,
        soft_z_extent=o.soft_z_extent,
        sampling=o.sampling,
        window=o.window,
        early_out=o.early_out,
        directions=o.directions,
        min_radius=o.min_radius,
    )
    jit = _hashable(static) and sum(f[3] for f in found) >= JIT_MIN_PIXELS
    run = _reconstruct_compacted_jit if jit else _reconstruct_compacted
    return run(color, velocity, depth, jitter, tuple(f[1] for f in found), tuple(f[2] for f in found), **static)
