"""Fused CPU kernels (numba) behind the PyTorch and JAX ops' custom gradient rules.

A tensor framework runs `reconstruct` as ~200 full-resolution elementwise ops per tap; on a 2-core
CPU that cannot reach the 100 ms target at 1280x720 (BENCHMARKS.md), and JAX's backward is
dominated by the scatter-add that transposes the bilinear reads. These kernels do the whole filter
in one parallel loop over pixels, and its hand-written backward in a second one. `reconstruct`'s and
`gather_blur`'s run a block of one row at a time as SIMD vectors (see "The forward runs a block"
below). They take and return NumPy arrays, so both backends share them: `torch_impl._fused` wraps them in an
`autograd.Function`, `jax_impl._fused` in a `custom_vjp` over `pure_callback`.

The pure tensor ops stay the reference: tests compare outputs and gradients of both paths. The
kernels repeat the pure ops' arithmetic (the same clamps, floors and `where` branches, so the same
one-sided derivatives at kinks) in float64, reading and writing the arrays' dtype.

Scope, checked by `reconstruct_unfused_reason`: bilinear sampling, the box shutter, float32 or
float64, no pyramid. The tap count is per tile (`counts`), which is how adaptive sampling and the
early-out run here: a tile with count 0 returns the image and costs one copy.

The backward scatters each tap's gradient to the 4 pixels it read, which may be anywhere in the
image: each thread accumulates into its own full-size buffer, summed at the end, so the backward's
memory is O(pixels x threads) (2 threads here), never O(pixels x taps).
"""

from __future__ import annotations

import math
import os
import threading
from typing import Any

import numpy as np

from diffblur.conventions import CYLINDER_INNER, CYLINDER_OUTER, EPSILON

try:  # numba is a dependency; the guard keeps the pure ops usable where it cannot load.
    import numba
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None

#: The numba threading layer the kernels ask for, unless the user set NUMBA_THREADING_LAYER:
#: "forksafe" is TBB where it is installed, else numba's own "workqueue". The default on Linux is
#: GNU OpenMP, which is not fork-safe: a DataLoader worker forked after the parent ran a kernel died
#: ("Terminating: fork() called from a process already using GNU OpenMP"). It takes effect when this
#: module is imported before the process's first parallel numba launch: every op imports it before
#: its first kernel, so only numba code of the user's own, run earlier, can have chosen the layer.
THREADING_LAYER = "forksafe"


def _pin_threading_layer() -> None:
    if numba is None or "NUMBA_THREADING_LAYER" in os.environ:
        return
    # Both: numba re-reads its config from NUMBA_* variables whenever they change, which would put
    # the default back if only the config attribute were set.
    os.environ["NUMBA_THREADING_LAYER"] = THREADING_LAYER
    numba.config.THREADING_LAYER = THREADING_LAYER


_pin_threading_layer()

#: Held while a kernel runs. The workqueue layer is not thread-safe: two threads launching kernels
#: at once (JAX runs callbacks on its own threads; a user's thread pool) abort the process. Each
#: kernel already uses every core, so running them one at a time costs nothing measurable.
_KERNEL_LOCK = threading.RLock()


def _fresh_lock_in_child() -> None:
    # A fork while another thread held the lock would leave it held for ever in the child.
    global _KERNEL_LOCK
    _KERNEL_LOCK = threading.RLock()


os.register_at_fork(after_in_child=_fresh_lock_in_child)

__all__ = [
    "available",
    "gather_backward",
    "gather_forward",
    "gather_mass_table",
    "gather_unfused_reason",
    "reconstruct_backward",
    "reconstruct_forward",
    "reconstruct_unfused_reason",
    "tile_counts",
    "use_fused",
]

_INVERSE_CYLINDER_SPAN = 1.0 / (CYLINDER_OUTER - CYLINDER_INNER)
#: Row interleave of the parallel loops: each thread's static share of the rows is spread over the
#: whole image, so a scene whose motion sits in one band still keeps both cores busy.
_ROW_INTERLEAVE = 16


def available() -> bool:
    """Whether the fused kernels can run (numba imports)."""
    return numba is not None


def use_fused(op: str, fused: bool | None, reason: str | None) -> bool:
    """Whether `op` runs on its fused kernel, given the user's `fused` and why the kernel cannot run
    these inputs (`reason`, None when it can): None takes the kernel where it can, True insists
    (ValueError naming the reason), False never takes it."""
    if fused is False:
        return False
    if reason is not None and fused:
        raise ValueError(f"{op}(fused=True) cannot run: {reason}")
    return reason is None


def reconstruct_unfused_reason(o: Any, dtype_name: str) -> str | None:
    """Why `reconstruct` with options `o` (`diffblur.taps.ReconstructOptions`) cannot take the
    fused path, or None when it can. dtype_name: the image's dtype, as a string."""
    from diffblur.shutters import Box

    if numba is None:
        return "numba is not installed"
    if o.sampling != "bilinear":
        return f"sampling={o.sampling!r} (the fused kernel is bilinear)"
    if type(o.window) is not Box:
        return f"shutter {o.window.name!r} (the fused kernel takes the box shutter)"
    if o.pyramid:
        return "pyramid=True"
    if dtype_name not in ("float32", "float64"):
        return f"dtype {dtype_name} (the fused kernel takes float32 and float64)"
    return None


def tile_counts(speed: Any, o: Any, xp: Any) -> Any:
    """The kernel's taps per tile from the tiles' |NeighborMax| (any shape, numpy/torch/jax.numpy):
    the adaptive classes, else the full rate, 0 where the early-out returns the image."""
    from diffblur._adaptive import still_speed, tile_sample_counts

    if o.classes is not None:
        return tile_sample_counts(speed, o.classes, still_speed(o.early_out), xp)
    # Without the early-out no tile is skipped: the full-rate filter runs on still tiles too.
    return tile_sample_counts(speed, (o.samples,), still_speed(True) if o.early_out else -1.0, xp)


def read_only(*arrays: np.ndarray) -> list[np.ndarray]:
    """Read-only views of a kernel's input arrays. numba compiles a kernel once per argument type,
    and a read-only array is a type of its own: JAX's callbacks hand over read-only arrays and
    PyTorch writable ones, so without these views a process that runs both compiled every kernel
    twice (~100 s more on a cold cache, measured)."""
    views = []
    for array in arrays:
        view = array.view()
        view.flags.writeable = False
        views.append(view)
    return views


def row_order(rows: int) -> np.ndarray:
    """Rows 0, 16, 32, ..., 1, 17, ...: the order the parallel loops visit the B * H rows in."""
    return np.argsort(np.arange(rows) % _ROW_INTERLEAVE, kind="stable").astype(np.int64)


class _Locked:
    """A parallel kernel called from Python under `_KERNEL_LOCK`; its other attributes are the
    numba dispatcher's (`signatures`, ...)."""

    def __init__(self, dispatcher):
        self._dispatcher = dispatcher

    def __call__(self, *args):
        with _KERNEL_LOCK:
            return self._dispatcher(*args)

    def __getattr__(self, name):
        return getattr(self._dispatcher, name)


def _jit(function):
    if numba is None:  # pragma: no cover
        return function
    return _Locked(numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy", fastmath=True)(function))


def _inline(function):
    if numba is None:  # pragma: no cover
        return function
    return numba.njit(inline="always", cache=True, error_model="numpy", fastmath=True)(function)


@_inline
def _length(a, b):
    squared = a * a + b * b
    return math.sqrt(squared) if squared > 0.0 else 0.0


@_inline
def _soft_depth_compare(z_a, z_b, extent, inverse_extent):
    behind = z_b - z_a
    if behind < 0.0:
        return 1.0
    if behind > extent:
        return 0.0
    return 1.0 - behind * inverse_extent


@_inline
def _floored_inverse(speed):
    """1 / max(speed, EPSILON): the classifiers divide by the floored speed; one division per speed."""
    return 1.0 / (speed if speed >= EPSILON else EPSILON)


@_inline
def _cone(distance, inverse):
    u = 1.0 - distance * inverse
    return 0.0 if u < 0.0 else (1.0 if u > 1.0 else u)


@_inline
def _cone_grad(distance, speed, inverse, grad):
    """d cone / d distance and d cone / d speed, times grad (the pure op's one-sided rules). One
    return of selects: a tuple merged from two returns is an alias to numba's parallel loops."""
    u = 1.0 - distance * inverse
    grad = grad if (u >= 0.0) & (u <= 1.0) else 0.0
    d_speed = grad * distance * inverse * inverse if speed >= EPSILON else 0.0
    return -grad * inverse, d_speed


@_inline
def _cylinder(distance, inverse):
    q = (distance * inverse - CYLINDER_INNER) * _INVERSE_CYLINDER_SPAN
    q = 0.0 if q < 0.0 else (1.0 if q > 1.0 else q)
    return 1.0 - q * q * (3.0 - 2.0 * q)


@_inline
def _cylinder_grad(distance, speed, inverse, grad):
    """As `_cone_grad`, for the cylinder."""
    q = (distance * inverse - CYLINDER_INNER) * _INVERSE_CYLINDER_SPAN
    d_q = grad * (-6.0 * q * (1.0 - q)) * _INVERSE_CYLINDER_SPAN if (q >= 0.0) & (q <= 1.0) else 0.0
    d_speed = -d_q * distance * inverse * inverse if speed >= EPSILON else 0.0
    return d_q * inverse, d_speed


@_jit
def _deinterleave_sum(grads, out):
    """Sum the (chunks, B, H, W, K) per-chunk gradient buffers into out (B, K, H, W)."""
    chunks, batch, height, width, channels = grads.shape
    for row in numba.prange(batch * height):
        b = row // height
        y = row % height
        for x in range(width):
            for c in range(channels):
                total = 0.0
                for chunk in range(chunks):
                    total += grads[chunk, b, y, x, c]
                out[b, c, y, x] = total


# The forward runs a block of pixels of one row as vectors: for each tap index k, one loop over the
# block's pixels with no branches, whose bilinear reads LLVM turns into SIMD gathers (2x faster than a
# pixel-at-a-time loop here). Three things make that loop vectorize: the per-pixel state lives in
# scratch arrays that are separate arguments of the parallel loop (numba marks non-aliasing arguments
# `noalias`; a view or a bool flag copied inside the loop counts as an alias and turns that off), the
# image is read as (left, right) pairs (`_pairs`: one 64-bit read per bilinear row for float32), and
# a block is a run of tiles with one tap count (`_block_end`), so every lane takes the same taps and
# adaptive sampling saves per tile, not per block.
_BLOCK = 128


if numba is not None:
    from llvmlite import ir as _ir
    from numba.core import types as _types
    from numba.extending import intrinsic as _intrinsic
    from numba.extending import overload as _overload

    @_intrinsic
    def _split_float32_pair(typingctx, bits):
        """A uint64 that holds two float32 (little-endian: the first in the low word) -> both."""
        if bits != _types.uint64:
            return None

        def codegen(context, builder, signature, args):
            low = builder.trunc(args[0], _ir.IntType(32))
            high = builder.trunc(builder.lshr(args[0], _ir.Constant(_ir.IntType(64), 32)), _ir.IntType(32))
            halves = (builder.bitcast(low, _ir.FloatType()), builder.bitcast(high, _ir.FloatType()))
            return context.make_tuple(builder, signature.return_type, halves)

        return _types.UniTuple(_types.float32, 2)(bits), codegen


def _pair(pairs, index):  # pragma: no cover - numba compiles the overload below
    raise NotImplementedError


if numba is not None:

    @_overload(_pair, inline="always", fastmath=True)
    def _pair_overload(pairs, index):
        """Pair `index` of `_pairs`' flat array as float64 (left, right): float32 pairs are one
        uint64 read, float64 pairs two reads."""
        if pairs.dtype == _types.uint64:

            def read_uint64(pairs, index):
                left, right = _split_float32_pair(pairs[index])
                return np.float64(left), np.float64(right)

            return read_uint64

        def read_float64(pairs, index):
            return pairs[2 * index], pairs[2 * index + 1]

        return read_float64


@_jit
def _fill_pairs(color, velocity, depth, pairs):
    """pairs (B, H, W, C + 3, 2): each pixel's C, V, Z beside those of its right neighbour (the last
    column beside itself), so a bilinear row is one read."""
    batch, channels, height, width = color.shape
    for row in numba.prange(batch * height):
        b = row // height
        y = row % height
        for x in range(width):
            right = min(x + 1, width - 1)
            for c in range(channels):
                pairs[b, y, x, c, 0] = color[b, c, y, x]
                pairs[b, y, x, c, 1] = color[b, c, y, right]
            for c in range(2):
                pairs[b, y, x, channels + c, 0] = velocity[b, c, y, x]
                pairs[b, y, x, channels + c, 1] = velocity[b, c, y, right]
            pairs[b, y, x, channels + 2, 0] = depth[b, 0, y, x]
            pairs[b, y, x, channels + 2, 1] = depth[b, 0, y, right]


def _pairs(color: np.ndarray, velocity: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """`_fill_pairs`' buffer, flat: uint64 (one per pair) for float32, float64 (two per pair) else."""
    batch, channels, height, width = color.shape
    pairs = np.empty((batch, height, width, channels + 3, 2), dtype=color.dtype)
    _fill_pairs(color, velocity, depth, pairs)
    return _flat_pairs(pairs)


@_jit
def _fill_color_pairs(color, pairs):
    """`_fill_pairs` for the colour alone: pairs (B, H, W, C, 2)."""
    batch, channels, height, width = color.shape
    for row in numba.prange(batch * height):
        b = row // height
        y = row % height
        for x in range(width):
            right = min(x + 1, width - 1)
            for c in range(channels):
                pairs[b, y, x, c, 0] = color[b, c, y, x]
                pairs[b, y, x, c, 1] = color[b, c, y, right]


def _flat_pairs(pairs: np.ndarray) -> np.ndarray:
    """A pairs buffer, flat: uint64 (one per pair) for float32, float64 (two per pair) else."""
    return pairs.reshape(-1).view(np.uint64) if pairs.dtype == np.float32 else pairs.reshape(-1)


def _color_pairs(color: np.ndarray) -> np.ndarray:
    batch, channels, height, width = color.shape
    pairs = np.empty((batch, height, width, channels, 2), dtype=color.dtype)
    _fill_color_pairs(color, pairs)
    return _flat_pairs(pairs)


@_inline
def _block_end(counts, b, tile_y, start, width, tile):
    """Where the block that starts at column `start` ends: the run of tiles with the count of
    `start`'s tile, at most _BLOCK pixels."""
    count = counts[b, tile_y, start // tile]
    end = min((start // tile + 1) * tile, width)
    while end < width and end - start < _BLOCK and counts[b, tile_y, end // tile] == count:
        end = min(end + tile, width)
    return min(end, start + _BLOCK)


@_inline
def _pixel_state(velocity, depth, neighbors, jitter, b, jb, y, x, tile, min_radius, chunk, p, jitter_s, nx_s, ny_s, speed_n_s, vx_s, vy_s, length_x_s, inverse_x_s, z_x_s):
    """Pixel X's scratch entries p of chunk `chunk`: its jitter, NeighborMax v_N and |v_N|, V[X],
    |V[X]|, the classifiers' floored inverse speed and Z[X]. Returns the classifiers' speed."""
    jitter_s[chunk, p] = jitter[jb, 0, y, x]
    nx = np.float64(neighbors[b, 0, y // tile, x // tile])
    ny = np.float64(neighbors[b, 1, y // tile, x // tile])
    nx_s[chunk, p] = nx
    ny_s[chunk, p] = ny
    speed_n_s[chunk, p] = _length(nx, ny)
    vx = np.float64(velocity[b, 0, y, x])
    vy = np.float64(velocity[b, 1, y, x])
    vx_s[chunk, p] = vx
    vy_s[chunk, p] = vy
    length_x = _length(vx, vy)
    length_x_s[chunk, p] = length_x
    speed_x = length_x if length_x >= min_radius else min_radius
    inverse_x_s[chunk, p] = _floored_inverse(speed_x)
    z_x_s[chunk, p] = depth[b, 0, y, x]
    return speed_x


@_inline
def _tap_corner(px, py, last_x, last_y):
    """A tap at (px, py) clamped to the image as `_sampling.sample` does: its top-left pixel (a
    clamped position is >= 0, so int() floors it), the fractions, and whether the clamp left each
    coordinate alone (1.0) or cut its gradient (0.0)."""
    cx = min(max(px, 0.0), last_x)
    cy = min(max(py, 0.0), last_y)
    column = np.int64(cx)
    row0 = np.int64(cy)
    inside_x = 1.0 if (px >= 0.0) & (px <= last_x) else 0.0
    inside_y = 1.0 if (py >= 0.0) & (py <= last_y) else 0.0
    return column, row0, cx - column, cy - row0, inside_x, inside_y


@_inline
def _pair_read(pairs, index, below, fx, fy):
    """Bilinear read of pair `index` (top row) and `index + below` (bottom row), in float64, as
    `_sampling.sample` computes it (a + f (b - a), the columns first)."""
    top_left, top_right = _pair(pairs, index)
    bottom_left, bottom_right = _pair(pairs, index + below)
    top = top_left + fx * (top_right - top_left)
    bottom = bottom_left + fx * (bottom_right - bottom_left)
    return top + fy * (bottom - top)


@_jit
def _reconstruct_forward(
    pairs, color, velocity, depth, neighbors, counts, jitter, tile, extent, min_radius, own_odd, order, chunks, out, weight,
    jitter_s, nx_s, ny_s, speed_n_s, vx_s, vy_s, length_x_s, inverse_x_s, z_x_s, weight_s, total_s, index_s, below_s, fx_s, fy_s, alpha_s,
):
    """The *_s scratch arrays hold one block per chunk: (chunks, >= _BLOCK), total_s (chunks, C, >= _BLOCK).
    own_odd is an int (0 or 1): see the note above on aliases."""
    batch, channels, height, width = color.shape
    stored = channels + 3
    jitter_batch = jitter.shape[0]
    inverse_extent = 1.0 / extent
    rows = batch * height
    last_x = width - 1.0
    last_y = height - 1.0
    for chunk in numba.prange(chunks):
        for i in range(chunk * rows // chunks, (chunk + 1) * rows // chunks):
            row = order[i]
            b = row // height
            y = row % height
            jb = b if jitter_batch > 1 else 0
            image_start = b * height * width * stored
            start = 0
            while start < width:
                end = _block_end(counts, b, y // tile, start, width, tile)
                size = end - start
                count = counts[b, y // tile, start // tile]
                if count == 0:  # the early-out: the image
                    for x in range(start, end):
                        for c in range(channels):
                            out[b, c, y, x] = color[b, c, y, x]
                        weight[b, y, x] = 0.0
                    start = end
                    continue
                for p in range(size):  # each pixel's state: NeighborMax, V[X], |V[X]|, Z[X], j
                    x = start + p
                    speed_x = _pixel_state(velocity, depth, neighbors, jitter, b, jb, y, x, tile, min_radius, chunk, p, jitter_s, nx_s, ny_s, speed_n_s, vx_s, vy_s, length_x_s, inverse_x_s, z_x_s)
                    w = 1.0 / speed_x
                    weight_s[chunk, p] = w
                    for c in range(channels):
                        total_s[chunk, c, p] = w * color[b, c, y, x]
                middle = (count - 1) // 2
                step = 2.0 / (count + 1.0)
                for k in range(count):
                    if k == middle:
                        continue
                    own = own_odd * (k % 2)
                    for p in range(size):  # vectorized: no branches, gathers
                        t = -1.0 + (k + jitter_s[chunk, p] + 1.0) * step
                        dx = vx_s[chunk, p] if own != 0 else nx_s[chunk, p]
                        dy = vy_s[chunk, p] if own != 0 else ny_s[chunk, p]
                        speed = length_x_s[chunk, p] if own != 0 else speed_n_s[chunk, p]
                        column, row0, fx, fy, _, _ = _tap_corner((start + p) + dx * t, y + dy * t, last_x, last_y)
                        index = image_start + (row0 * width + column) * stored
                        below = width * stored if row0 < height - 1 else 0
                        index_s[chunk, p] = index
                        below_s[chunk, p] = below
                        fx_s[chunk, p] = fx
                        fy_s[chunk, p] = fy
                        v_yx = _pair_read(pairs, index + channels, below, fx, fy)
                        v_yy = _pair_read(pairs, index + channels + 1, below, fx, fy)
                        z_y = _pair_read(pairs, index + channels + 2, below, fx, fy)
                        length_y = math.sqrt(v_yx * v_yx + v_yy * v_yy)
                        inverse_y = _floored_inverse(length_y if length_y >= min_radius else min_radius)
                        inverse_x = inverse_x_s[chunk, p]
                        z_x = z_x_s[chunk, p]
                        distance = abs(t) * speed
                        alpha = (
                            _soft_depth_compare(z_x, z_y, extent, inverse_extent) * _cone(distance, inverse_y)
                            + _soft_depth_compare(z_y, z_x, extent, inverse_extent) * _cone(distance, inverse_x)
                            + _cylinder(distance, inverse_y) * _cylinder(distance, inverse_x) * 2.0
                        )
                        alpha_s[chunk, p] = alpha
                        weight_s[chunk, p] += alpha
                    for c in range(channels):
                        for p in range(size):  # vectorized
                            read = _pair_read(pairs, index_s[chunk, p] + c, below_s[chunk, p], fx_s[chunk, p], fy_s[chunk, p])
                            total_s[chunk, c, p] += alpha_s[chunk, p] * read
                for p in range(size):
                    x = start + p
                    w = weight_s[chunk, p]
                    for c in range(channels):
                        out[b, c, y, x] = total_s[chunk, c, p] / w
                    weight[b, y, x] = w
                start = end


@_inline
def _pair_read_slopes(pairs, index, below, fx, fy):
    """d read / d fx, d read / d fy and the read of `_pair_read`."""
    top_left, top_right = _pair(pairs, index)
    bottom_left, bottom_right = _pair(pairs, index + below)
    top = top_left + fx * (top_right - top_left)
    bottom = bottom_left + fx * (bottom_right - bottom_left)
    return (1.0 - fy) * (top_right - top_left) + fy * (bottom_right - bottom_left), bottom - top, top + fy * (bottom - top)


@_inline
def _scatter_chunk(grads, chunk, b, channel, row0, row1, column0, column1, fx, fy, grad):
    """Add `grad` to chunk `chunk` of grads (chunks, B, H, W, K) at the 4 corners of a bilinear read,
    each with its weight; indexed rather than sliced (a slice is an alias)."""
    grads[chunk, b, row0, column0, channel] += grad * (1.0 - fx) * (1.0 - fy)
    grads[chunk, b, row0, column1, channel] += grad * fx * (1.0 - fy)
    grads[chunk, b, row1, column0, channel] += grad * (1.0 - fx) * fy
    grads[chunk, b, row1, column1, channel] += grad * fx * fy


@_jit
def _reconstruct_backward(
    pairs, color, velocity, depth, neighbors, counts, jitter, tile, extent, min_radius, own_odd, order, scatter_color, scatter_velocity, scatter_depth,
    out, weight, grad_out, grads, grad_neighbors,
    jitter_s, nx_s, ny_s, speed_n_s, vx_s, vy_s, length_x_s, speed_x_s, inverse_x_s, z_x_s, g_total_s, out_s,
    column_s, row_s, t_s, fx_s, fy_s, inside_x_s, inside_y_s, g_alpha_s, slope_x_s, slope_y_s, alpha_s, g_v_yx_s, g_v_yy_s, g_z_y_s,
    g_speed_x_s, g_z_x_s, g_vx_s, g_vy_s, g_length_x_s, g_nx_s, g_ny_s, g_speed_n_s,
):
    """The forward's layout (pairs, blocks of one row as vectors, scratch arguments) for the hand-written
    backward. Per tap index k: one vector loop places the taps, one per channel reads the colours, one
    runs the classifiers' derivatives; then a scalar loop scatters the gradients of the 4 pixels each
    tap read (lanes may collide, so it cannot be a vector scatter), for the inputs whose scatter_* flag
    is 1 (ints: see the note above on aliases); the other inputs' gradients come out incomplete.
    grads: (chunks, B, H, W, C + 3) zeros, one buffer per chunk of rows (C, V, Z gradients
    interleaved); grad_neighbors: (chunks, B, 2, TH, TW) zeros; *_s scratch: (chunks, >= _BLOCK), g_total_s
    and out_s (chunks, C, >= _BLOCK)."""
    batch, channels, height, width = color.shape
    stored = channels + 3
    jitter_batch = jitter.shape[0]
    inverse_extent = 1.0 / extent
    chunks = grads.shape[0]
    rows = batch * height
    last_x = width - 1.0
    last_y = height - 1.0
    for chunk in numba.prange(chunks):
        for i in range(chunk * rows // chunks, (chunk + 1) * rows // chunks):
            row = order[i]
            b = row // height
            y = row % height
            jb = b if jitter_batch > 1 else 0
            image_start = b * height * width * stored
            start = 0
            while start < width:
                end = _block_end(counts, b, y // tile, start, width, tile)
                size = end - start
                count = counts[b, y // tile, start // tile]
                if count == 0:  # the early-out: out = C[X]
                    for x in range(start, end):
                        for c in range(channels):
                            grads[chunk, b, y, x, c] += grad_out[b, c, y, x]
                    start = end
                    continue
                for p in range(size):
                    x = start + p
                    speed_x = _pixel_state(velocity, depth, neighbors, jitter, b, jb, y, x, tile, min_radius, chunk, p, jitter_s, nx_s, ny_s, speed_n_s, vx_s, vy_s, length_x_s, inverse_x_s, z_x_s)
                    speed_x_s[chunk, p] = speed_x
                    # out = total / w: d total = g / w, d w = -sum(g out) / w; per tap alpha and
                    # alpha C[Y] both enter, so d alpha = sum(g (C[Y] - out)) / w.
                    w = np.float64(weight[b, y, x])
                    g_center = 0.0
                    for c in range(channels):
                        g_total = grad_out[b, c, y, x] / w
                        g_total_s[chunk, c, p] = g_total
                        out_s[chunk, c, p] = out[b, c, y, x]
                        g_center += g_total * (color[b, c, y, x] - out[b, c, y, x])
                        grads[chunk, b, y, x, c] += g_total / speed_x
                    g_speed_x_s[chunk, p] = -g_center / (speed_x * speed_x)
                    g_z_x_s[chunk, p] = 0.0
                    g_vx_s[chunk, p] = 0.0
                    g_vy_s[chunk, p] = 0.0
                    g_length_x_s[chunk, p] = 0.0
                    g_nx_s[chunk, p] = 0.0
                    g_ny_s[chunk, p] = 0.0
                    g_speed_n_s[chunk, p] = 0.0
                middle = (count - 1) // 2
                step = 2.0 / (count + 1.0)
                for k in range(count):
                    if k == middle:
                        continue
                    own = own_odd * (k % 2)
                    for p in range(size):  # vectorized: the taps' positions
                        t = -1.0 + (k + jitter_s[chunk, p] + 1.0) * step
                        px = (start + p) + (vx_s[chunk, p] if own != 0 else nx_s[chunk, p]) * t
                        py = y + (vy_s[chunk, p] if own != 0 else ny_s[chunk, p]) * t
                        column, row0, fx, fy, inside_x, inside_y = _tap_corner(px, py, last_x, last_y)
                        column_s[chunk, p] = column
                        row_s[chunk, p] = row0
                        t_s[chunk, p] = t
                        fx_s[chunk, p] = fx
                        fy_s[chunk, p] = fy
                        inside_x_s[chunk, p] = inside_x
                        inside_y_s[chunk, p] = inside_y
                        g_alpha_s[chunk, p] = 0.0
                        slope_x_s[chunk, p] = 0.0
                        slope_y_s[chunk, p] = 0.0
                    for c in range(channels):
                        for p in range(size):  # vectorized: the colours read
                            row0 = row_s[chunk, p]
                            index = image_start + (row0 * width + column_s[chunk, p]) * stored + c
                            below = width * stored if row0 < height - 1 else 0
                            slope_x, slope_y, c_y = _pair_read_slopes(pairs, index, below, fx_s[chunk, p], fy_s[chunk, p])
                            g_total = g_total_s[chunk, c, p]
                            g_alpha_s[chunk, p] += g_total * (c_y - out_s[chunk, c, p])
                            slope_x_s[chunk, p] += g_total * slope_x  # times alpha below
                            slope_y_s[chunk, p] += g_total * slope_y
                    for p in range(size):  # vectorized: the classifiers and their derivatives
                        row0 = row_s[chunk, p]
                        index = image_start + (row0 * width + column_s[chunk, p]) * stored + channels
                        below = width * stored if row0 < height - 1 else 0
                        fx = fx_s[chunk, p]
                        fy = fy_s[chunk, p]
                        t = t_s[chunk, p]
                        slope_vxx, slope_vxy, v_yx = _pair_read_slopes(pairs, index, below, fx, fy)
                        slope_vyx, slope_vyy, v_yy = _pair_read_slopes(pairs, index + 1, below, fx, fy)
                        slope_zx, slope_zy, z_y = _pair_read_slopes(pairs, index + 2, below, fx, fy)
                        length_y = math.sqrt(v_yx * v_yx + v_yy * v_yy)
                        speed_y = length_y if length_y >= min_radius else min_radius
                        inverse_y = _floored_inverse(speed_y)
                        speed_x = speed_x_s[chunk, p]
                        inverse_x = inverse_x_s[chunk, p]
                        z_x = z_x_s[chunk, p]
                        distance = abs(t) * (length_x_s[chunk, p] if own != 0 else speed_n_s[chunk, p])
                        front = _soft_depth_compare(z_x, z_y, extent, inverse_extent)
                        behind = _soft_depth_compare(z_y, z_x, extent, inverse_extent)
                        cone_y = _cone(distance, inverse_y)
                        cone_x = _cone(distance, inverse_x)
                        cylinder_y = _cylinder(distance, inverse_y)
                        cylinder_x = _cylinder(distance, inverse_x)
                        alpha = front * cone_y + behind * cone_x + cylinder_y * cylinder_x * 2.0
                        g_alpha = g_alpha_s[chunk, p]
                        # The classifiers.
                        g_front = g_alpha * cone_y
                        g_behind = g_alpha * cone_x
                        front_slope = g_front * inverse_extent if (z_y - z_x >= 0.0) & (z_y - z_x <= extent) else 0.0
                        behind_slope = g_behind * inverse_extent if (z_x - z_y >= 0.0) & (z_x - z_y <= extent) else 0.0
                        g_z_y = behind_slope - front_slope
                        g_distance, g_speed_y = _cone_grad(distance, speed_y, inverse_y, g_alpha * front)
                        d_distance, g_speed_x = _cone_grad(distance, speed_x, inverse_x, g_alpha * behind)
                        g_distance += d_distance
                        d_distance, d_speed = _cylinder_grad(distance, speed_y, inverse_y, g_alpha * 2.0 * cylinder_x)
                        g_distance += d_distance
                        g_speed_y += d_speed
                        d_distance, d_speed = _cylinder_grad(distance, speed_x, inverse_x, g_alpha * 2.0 * cylinder_y)
                        g_distance += d_distance
                        g_speed_x += d_speed
                        # V[Y] through speed_y = max(|V[Y]|, min_radius).
                        moving = (length_y >= min_radius) & (length_y > 0.0)
                        g_v_yx = g_speed_y * v_yx / length_y if moving else 0.0
                        g_v_yy = g_speed_y * v_yy / length_y if moving else 0.0
                        g_fx = alpha * slope_x_s[chunk, p] + g_v_yx * slope_vxx + g_v_yy * slope_vyx + g_z_y * slope_zx
                        g_fy = alpha * slope_y_s[chunk, p] + g_v_yx * slope_vxy + g_v_yy * slope_vyy + g_z_y * slope_zy
                        # The tap position X + direction t (no gradient where clamped) and the
                        # distance |t| speed; own (0 or 1) picks V[X] or NeighborMax.
                        g_dx = g_fx * t * inside_x_s[chunk, p]
                        g_dy = g_fy * t * inside_y_s[chunk, p]
                        g_along = g_distance * abs(t)
                        alpha_s[chunk, p] = alpha
                        g_v_yx_s[chunk, p] = g_v_yx
                        g_v_yy_s[chunk, p] = g_v_yy
                        g_z_y_s[chunk, p] = g_z_y
                        g_speed_x_s[chunk, p] += g_speed_x
                        g_z_x_s[chunk, p] += front_slope - behind_slope
                        g_vx_s[chunk, p] += g_dx * own
                        g_vy_s[chunk, p] += g_dy * own
                        g_length_x_s[chunk, p] += g_along * own
                        g_nx_s[chunk, p] += g_dx * (1 - own)
                        g_ny_s[chunk, p] += g_dy * (1 - own)
                        g_speed_n_s[chunk, p] += g_along * (1 - own)
                    for p in range(size):  # scalar: the 4 pixels each tap read
                        row0 = row_s[chunk, p]
                        column = column_s[chunk, p]
                        row1 = min(row0 + 1, height - 1)
                        column1 = min(column + 1, width - 1)
                        fx = fx_s[chunk, p]
                        fy = fy_s[chunk, p]
                        alpha = alpha_s[chunk, p]
                        if scatter_color != 0:
                            for c in range(channels):
                                _scatter_chunk(grads, chunk, b, c, row0, row1, column, column1, fx, fy, alpha * g_total_s[chunk, c, p])
                        if scatter_velocity != 0:
                            _scatter_chunk(grads, chunk, b, channels, row0, row1, column, column1, fx, fy, g_v_yx_s[chunk, p])
                            _scatter_chunk(grads, chunk, b, channels + 1, row0, row1, column, column1, fx, fy, g_v_yy_s[chunk, p])
                        if scatter_depth != 0:
                            _scatter_chunk(grads, chunk, b, channels + 2, row0, row1, column, column1, fx, fy, g_z_y_s[chunk, p])
                for p in range(size):  # each pixel's own V[X], Z[X] and NeighborMax
                    x = start + p
                    length_x = length_x_s[chunk, p]
                    g_length_x = g_length_x_s[chunk, p]
                    if length_x >= min_radius:
                        g_length_x += g_speed_x_s[chunk, p]
                    g_vx = g_vx_s[chunk, p]
                    g_vy = g_vy_s[chunk, p]
                    if length_x > 0.0:
                        g_vx += g_length_x * vx_s[chunk, p] / length_x
                        g_vy += g_length_x * vy_s[chunk, p] / length_x
                    g_nx = g_nx_s[chunk, p]
                    g_ny = g_ny_s[chunk, p]
                    speed_n = speed_n_s[chunk, p]
                    if speed_n > 0.0:
                        g_nx += g_speed_n_s[chunk, p] * nx_s[chunk, p] / speed_n
                        g_ny += g_speed_n_s[chunk, p] * ny_s[chunk, p] / speed_n
                    grads[chunk, b, y, x, channels] += g_vx
                    grads[chunk, b, y, x, channels + 1] += g_vy
                    grads[chunk, b, y, x, channels + 2] += g_z_x_s[chunk, p]
                    grad_neighbors[chunk, b, 0, y // tile, x // tile] += g_nx
                    grad_neighbors[chunk, b, 1, y // tile, x // tile] += g_ny
                start = end


#: The kinds of the kernels' *_s scratch arguments, in order: i an int64 (chunks, row) array, f a
#: float64 one, c float64 (chunks, C, row), with row = _BLOCK + _SCRATCH_GAP.
_FORWARD_SCRATCH = "f" * 10 + "c" + "ii" + "fff"
_BACKWARD_SCRATCH = "f" * 10 + "cc" + "ii" + "f" * 20
_GATHER_SCRATCH = "ff" + "ii" + "ff" + "c"
_GATHER_BACKWARD_SCRATCH = "ff" + "ii" + "f" * 9 + "c"


# Each scratch row is followed by 1 KiB that no thread touches. Side by side, one thread's row next to
# another's, the backward on 2 threads took 365 ms at 720p instead of 250 (a gap of 256 B: 355 ms);
# likely the prefetcher running ahead of one thread's row into the other's.
_SCRATCH_GAP = 128


def _scratch(kinds: str, chunks: int, channels: int) -> list[np.ndarray]:
    row = _BLOCK + _SCRATCH_GAP
    shapes = {"i": (chunks, row), "f": (chunks, row), "c": (chunks, channels, row)}
    return [np.empty(shapes[kind], dtype=np.int64 if kind == "i" else np.float64) for kind in kinds]


def _threads() -> int:
    return max(1, numba.get_num_threads())


def reconstruct_forward(
    color: np.ndarray,
    velocity: np.ndarray,
    depth: np.ndarray,
    neighbors: np.ndarray,
    counts: np.ndarray,
    jitter: np.ndarray,
    *,
    tile: int,
    soft_z_extent: float,
    min_radius: float,
    own_odd: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """The reconstruction filter, fused. color (B, C, H, W), velocity (B, 2, H, W), depth (B, 1, H,
    W), neighbors (B, 2, TH, TW) NeighborMax, counts (B, TH, TW) taps per tile (0: the image),
    jitter (B or 1, 1, H, W), all C-contiguous in one float dtype (counts int32). Returns the
    image and the per-pixel weight sum (B, H, W) that the backward needs."""
    color, velocity, depth, neighbors, counts, jitter = read_only(color, velocity, depth, neighbors, counts, jitter)
    batch, channels, height, width = color.shape
    out = np.empty_like(color)
    weight = np.empty((batch, height, width), dtype=color.dtype)
    chunks = min(batch * height, _threads())
    settings = (int(tile), float(soft_z_extent), float(min_radius), int(own_odd), row_order(batch * height), chunks)
    scratch = _scratch(_FORWARD_SCRATCH, chunks, channels)
    _reconstruct_forward(_pairs(color, velocity, depth), color, velocity, depth, neighbors, counts, jitter, *settings, out, weight, *scratch)
    return out, weight


def reconstruct_backward(
    color: np.ndarray,
    velocity: np.ndarray,
    depth: np.ndarray,
    neighbors: np.ndarray,
    counts: np.ndarray,
    jitter: np.ndarray,
    out: np.ndarray,
    weight: np.ndarray,
    grad_out: np.ndarray,
    *,
    tile: int,
    soft_z_extent: float,
    min_radius: float,
    own_odd: bool,
    needs: tuple[bool, bool, bool] = (True, True, True),
) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """Gradients of `reconstruct_forward`'s image w.r.t. color, velocity, depth and neighbors,
    given the forward's out and weight and the output's gradient grad_out. needs: whether color,
    velocity and depth want theirs; None for the others, whose scatter to the taps' pixels (most of
    the backward's time) is skipped. neighbors' comes with velocity's."""
    total, grad_neighbors = reconstruct_backward_stacked(
        color, velocity, depth, neighbors, counts, jitter, out, weight, grad_out, tile=tile, soft_z_extent=soft_z_extent, min_radius=min_radius, own_odd=own_odd, needs=needs
    )
    channels = color.shape[1]
    need_color, need_velocity, need_depth = (bool(need) for need in needs)
    return (
        total[:, :channels] if need_color else None,
        total[:, channels : channels + 2] if need_velocity else None,
        total[:, channels + 2 :] if need_depth else None,
        grad_neighbors,
    )


def reconstruct_backward_stacked(
    color: np.ndarray,
    velocity: np.ndarray,
    depth: np.ndarray,
    neighbors: np.ndarray,
    counts: np.ndarray,
    jitter: np.ndarray,
    out: np.ndarray,
    weight: np.ndarray,
    grad_out: np.ndarray,
    *,
    tile: int,
    soft_z_extent: float,
    min_radius: float,
    own_odd: bool,
    needs: tuple[bool, bool, bool] = (True, True, True),
) -> tuple[np.ndarray, np.ndarray | None]:
    """`reconstruct_backward` with the gradients w.r.t. color, velocity and depth in one array
    (B, C + 3, H, W), stacked along the channels as the kernel writes them (the channels of one not
    asked for are left unwritten), and neighbors' gradient (None unless velocity's is asked for).
    The PyTorch operator returns this array whole and slices it, as an operator's outputs may not
    be views of one another."""
    color, velocity, depth, neighbors, counts, jitter, out, weight, grad_out = read_only(color, velocity, depth, neighbors, counts, jitter, out, weight, grad_out)
    batch, channels, height, width = color.shape
    chunks = min(_threads(), batch * height)
    grads = np.zeros((chunks, batch, height, width, channels + 3), dtype=color.dtype)
    grad_neighbors = np.zeros((chunks, *neighbors.shape), dtype=color.dtype)
    need_color, need_velocity, need_depth = (bool(need) for need in needs)
    settings = (int(tile), float(soft_z_extent), float(min_radius), int(own_odd), row_order(batch * height), int(need_color), int(need_velocity), int(need_depth))
    scratch = _scratch(_BACKWARD_SCRATCH, chunks, channels)
    arrays = (_pairs(color, velocity, depth), color, velocity, depth, neighbors, counts, jitter)
    _reconstruct_backward(*arrays, *settings, out, weight, grad_out, grads, grad_neighbors, *scratch)
    total = np.empty((batch, channels + 3, height, width), dtype=color.dtype)
    _deinterleave_sum(grads, total)
    return total, grad_neighbors.sum(axis=0) if need_velocity else None


# -- gather_blur ------------------------------------------------------------------------------------
# out[X] = sum_k m[n, k] C[X - t_k V[X]] with n the pixel's tile count and t_k = (2k + 1) / n - 1
# (`diffblur.taps.gather_tap_times`); the mass table m (S + 1, S) holds row n for each count n in use,
# so adaptive classes and the shutter (any window: its masses are an input with a gradient) come in
# as data. Only colour is read at the taps; the velocity is read at X.


def gather_unfused_reason(sampling: str, pyramid: bool, dtype_name: str) -> str | None:
    """Why `gather_blur` with these options cannot take the fused path, or None when it can."""
    if numba is None:
        return "numba is not installed"
    if sampling != "bilinear":
        return f"sampling={sampling!r} (the fused kernel is bilinear)"
    if pyramid:
        return "pyramid=True"
    if dtype_name not in ("float32", "float64"):
        return f"dtype {dtype_name} (the fused kernel takes float32 and float64)"
    return None


def gather_mass_table(window: Any, samples: int, classes: tuple[int, ...], xp: Any, dtype: Any) -> Any:
    """The kernel's mass table (S + 1, S) as an `xp` array of `dtype`: row n holds the renormalised
    masses of n taps for each count n in `classes`, zeros elsewhere. A window with constant
    parameters gets it from NumPy in float64; one with a parameter being fitted from `xp` ops, which
    carry its gradient."""
    from diffblur._scatter_options import has_constant_parameters
    from diffblur.taps import gather_tap_times, stratum_weights

    if has_constant_parameters(window):
        table = np.zeros((samples + 1, samples))
        for count in classes:
            masses = stratum_weights(window, np.asarray(gather_tap_times(count)), 1.0 / count, np)
            table[count, :count] = masses / masses.sum()
        return xp.asarray(table, dtype=dtype)
    rows = []
    for count in range(samples + 1):
        if count in classes:
            masses = stratum_weights(window, xp.asarray(gather_tap_times(count), dtype=dtype), 1.0 / count, xp)
            rows.append(xp.concatenate([masses / masses.sum(), xp.zeros(samples - count, dtype=dtype)]))
        else:
            rows.append(xp.zeros(samples, dtype=dtype))
    return xp.stack(rows)


@_jit
def _gather_forward(pairs, velocity, counts, masses, tile, order, out, vx_s, vy_s, index_s, below_s, fx_s, fy_s, total_s):
    """`_reconstruct_forward`'s layout for the gather: pairs of the colour (`_color_pairs`), blocks
    of one row as vectors (per tap index, one loop places the taps, one per channel reads them), the
    *_s scratch one block per chunk: (chunks, >= _BLOCK), total_s (chunks, C, >= _BLOCK)."""
    batch, channels, height, width = out.shape
    chunks = vx_s.shape[0]
    rows = batch * height
    last_x = width - 1.0
    last_y = height - 1.0
    for chunk in numba.prange(chunks):
        for i in range(chunk * rows // chunks, (chunk + 1) * rows // chunks):
            row = order[i]
            b = row // height
            y = row % height
            image_start = b * height * width * channels
            start = 0
            while start < width:
                end = _block_end(counts, b, y // tile, start, width, tile)
                size = end - start
                count = counts[b, y // tile, start // tile]
                if count == 0:  # the image
                    for x in range(start, end):
                        for c in range(channels):
                            out[b, c, y, x] = _pair(pairs, image_start + (y * width + x) * channels + c)[0]
                    start = end
                    continue
                for p in range(size):
                    vx_s[chunk, p] = velocity[b, 0, y, start + p]
                    vy_s[chunk, p] = velocity[b, 1, y, start + p]
                    for c in range(channels):
                        total_s[chunk, c, p] = 0.0
                for k in range(count):
                    t = (2.0 * k + 1.0) / count - 1.0
                    mass = np.float64(masses[count, k])
                    for p in range(size):  # vectorized: the taps
                        column, row0, fx, fy, _, _ = _tap_corner((start + p) - t * vx_s[chunk, p], y - t * vy_s[chunk, p], last_x, last_y)
                        index_s[chunk, p] = image_start + (row0 * width + column) * channels
                        below_s[chunk, p] = width * channels if row0 < height - 1 else 0
                        fx_s[chunk, p] = fx
                        fy_s[chunk, p] = fy
                    for c in range(channels):
                        for p in range(size):  # vectorized: gathers
                            read = _pair_read(pairs, index_s[chunk, p] + c, below_s[chunk, p], fx_s[chunk, p], fy_s[chunk, p])
                            total_s[chunk, c, p] += mass * read
                for p in range(size):
                    for c in range(channels):
                        out[b, c, y, start + p] = total_s[chunk, c, p]
                start = end


@_jit
def _gather_backward(
    pairs, velocity, counts, masses, tile, order, scatter_color, grad_out, grads, grad_velocity, grad_masses,
    vx_s, vy_s, column_s, row_s, fx_s, fy_s, inside_x_s, inside_y_s, g_fx_s, g_fy_s, g_mass_s, g_vx_s, g_vy_s, g_s,
):
    """`_gather_forward`'s layout for its backward: per tap index, one vector loop places the taps,
    one per channel reads them with their slopes, then a scalar loop scatters the colour's gradient
    to the 4 pixels each tap read (lanes may collide), if scatter_color is 1 (an int: see the note
    on aliases above; with 0 grads stays incomplete). grads: (chunks, B, H, W, C) zeros, one per
    chunk of rows; grad_velocity (B, 2, H, W) (each pixel writes its own); grad_masses: (chunks,
    S + 1, S) zeros; *_s scratch (chunks, >= _BLOCK), g_s (chunks, C, >= _BLOCK)."""
    batch, _, height, width = velocity.shape
    chunks, channels = grads.shape[0], grads.shape[4]
    rows = batch * height
    last_x = width - 1.0
    last_y = height - 1.0
    for chunk in numba.prange(chunks):
        # Accumulated in the thread's own memory: written per tap, grad_masses' rows lie side by side.
        g_masses = np.zeros(grad_masses.shape[1:])
        for i in range(chunk * rows // chunks, (chunk + 1) * rows // chunks):
            row = order[i]
            b = row // height
            y = row % height
            image_start = b * height * width * channels
            start = 0
            while start < width:
                end = _block_end(counts, b, y // tile, start, width, tile)
                size = end - start
                count = counts[b, y // tile, start // tile]
                if count == 0:  # out = C[X]
                    for x in range(start, end):
                        if scatter_color != 0:
                            for c in range(channels):
                                grads[chunk, b, y, x, c] += grad_out[b, c, y, x]
                        grad_velocity[b, 0, y, x] = 0.0
                        grad_velocity[b, 1, y, x] = 0.0
                    start = end
                    continue
                for p in range(size):
                    vx_s[chunk, p] = velocity[b, 0, y, start + p]
                    vy_s[chunk, p] = velocity[b, 1, y, start + p]
                    g_vx_s[chunk, p] = 0.0
                    g_vy_s[chunk, p] = 0.0
                    for c in range(channels):
                        g_s[chunk, c, p] = grad_out[b, c, y, start + p]
                for k in range(count):
                    t = (2.0 * k + 1.0) / count - 1.0
                    mass = np.float64(masses[count, k])
                    for p in range(size):  # vectorized: the taps
                        # The clamp at the border passes no gradient to the tap position X - t V.
                        column, row0, fx, fy, inside_x, inside_y = _tap_corner((start + p) - t * vx_s[chunk, p], y - t * vy_s[chunk, p], last_x, last_y)
                        column_s[chunk, p] = column
                        row_s[chunk, p] = row0
                        fx_s[chunk, p] = fx
                        fy_s[chunk, p] = fy
                        inside_x_s[chunk, p] = inside_x
                        inside_y_s[chunk, p] = inside_y
                        g_fx_s[chunk, p] = 0.0
                        g_fy_s[chunk, p] = 0.0
                        g_mass_s[chunk, p] = 0.0
                    for c in range(channels):
                        for p in range(size):  # vectorized: the colours read and their slopes
                            row0 = row_s[chunk, p]
                            index = image_start + (row0 * width + column_s[chunk, p]) * channels + c
                            below = width * channels if row0 < height - 1 else 0
                            slope_x, slope_y, c_y = _pair_read_slopes(pairs, index, below, fx_s[chunk, p], fy_s[chunk, p])
                            g = g_s[chunk, c, p]
                            g_mass_s[chunk, p] += g * c_y
                            g_fx_s[chunk, p] += g * slope_x
                            g_fy_s[chunk, p] += g * slope_y
                    g_mass = 0.0
                    for p in range(size):
                        g_mass += g_mass_s[chunk, p]
                        g_vx_s[chunk, p] -= mass * g_fx_s[chunk, p] * t * inside_x_s[chunk, p]
                        g_vy_s[chunk, p] -= mass * g_fy_s[chunk, p] * t * inside_y_s[chunk, p]
                    g_masses[count, k] += g_mass
                    if scatter_color != 0:
                        for p in range(size):  # scalar: the 4 pixels each tap read
                            row0 = row_s[chunk, p]
                            column = column_s[chunk, p]
                            row1 = min(row0 + 1, height - 1)
                            column1 = min(column + 1, width - 1)
                            for c in range(channels):
                                _scatter_chunk(grads, chunk, b, c, row0, row1, column, column1, fx_s[chunk, p], fy_s[chunk, p], g_s[chunk, c, p] * mass)
                for p in range(size):
                    grad_velocity[b, 0, y, start + p] = g_vx_s[chunk, p]
                    grad_velocity[b, 1, y, start + p] = g_vy_s[chunk, p]
                start = end
        grad_masses[chunk] = g_masses


@_jit
def _gather_tile_counts(velocity, classes, still, tile, counts):
    """counts (B, TH, TW): the taps of each tile's class from its largest |V|, as
    `diffblur._adaptive.tile_sample_counts` (0 at most `still`, else the smallest class c with
    2 |V| <= c, else the last)."""
    batch, _, height, width = velocity.shape
    _, tiles_y, tiles_x = counts.shape
    for index in numba.prange(batch * tiles_y):
        b = index // tiles_y
        tile_y = index % tiles_y
        for tile_x in range(tiles_x):
            largest = 0.0
            for y in range(tile_y * tile, min((tile_y + 1) * tile, height)):
                for x in range(tile_x * tile, min((tile_x + 1) * tile, width)):
                    vx = np.float64(velocity[b, 0, y, x])
                    vy = np.float64(velocity[b, 1, y, x])
                    largest = max(largest, vx * vx + vy * vy)
            speed = math.sqrt(largest)
            count = 0
            if speed > still:
                count = classes[-1]
                for c in classes[::-1]:
                    if 2.0 * speed <= c:
                        count = c
            counts[b, tile_y, tile_x] = count


def _gather_counts(velocity: np.ndarray, samples: int, classes: tuple[int, ...] | None, still: float, tile: int) -> np.ndarray:
    batch, _, height, width = velocity.shape
    if classes is None:  # the full rate everywhere, one tile
        return np.full((batch, 1, 1), samples, dtype=np.int32)
    counts = np.empty((batch, -(-height // tile), -(-width // tile)), dtype=np.int32)
    _gather_tile_counts(velocity, np.asarray(classes, dtype=np.int64), float(still), int(tile), counts)
    return counts


def gather_forward(
    color: np.ndarray, velocity: np.ndarray, masses: np.ndarray, *, samples: int, classes: tuple[int, ...] | None, still: float, tile: int
) -> np.ndarray:
    """gather_blur, fused. color (B, C, H, W), velocity (B, 2, H, W), masses (S + 1, S) with row n
    the masses of n taps, all C-contiguous, one float dtype. classes: the adaptive sample counts
    (each tile of `tile` px takes its class's taps, 0 where its |V| <= still: the image), or None
    for `samples` taps everywhere."""
    color, velocity, masses = read_only(color, velocity, masses)
    batch, _, height, width = color.shape
    out = np.empty_like(color)
    counts = _gather_counts(velocity, samples, classes, still, tile)
    tile = max(height, width) if classes is None else int(tile)
    scratch = _scratch(_GATHER_SCRATCH, min(batch * height, _threads()), color.shape[1])
    _gather_forward(_color_pairs(color), velocity, counts, masses, tile, row_order(batch * height), out, *scratch)
    return out


def gather_backward(
    color: np.ndarray,
    velocity: np.ndarray,
    masses: np.ndarray,
    grad_out: np.ndarray,
    *,
    samples: int,
    classes: tuple[int, ...] | None,
    still: float,
    tile: int,
    needs: tuple[bool, bool, bool] = (True, True, True),
) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """Gradients of `gather_forward`'s image w.r.t. color, velocity and masses. needs: whether each
    wants its gradient; None for the others. Without the colour's, the scatter to the taps' pixels
    (most of the backward's time) is skipped."""
    color, velocity, masses, grad_out = read_only(color, velocity, masses, grad_out)
    batch, channels, height, width = color.shape
    chunks = min(_threads(), batch * height)
    need_color, need_velocity, need_masses = (bool(need) for need in needs)
    grads = np.zeros((chunks, batch, height, width, channels) if need_color else (chunks, batch, 1, 1, channels), dtype=color.dtype)
    grad_velocity = np.empty_like(velocity)
    grad_masses = np.zeros((chunks, *masses.shape), dtype=masses.dtype)
    counts = _gather_counts(velocity, samples, classes, still, tile)
    tile = max(height, width) if classes is None else int(tile)
    scratch = _scratch(_GATHER_BACKWARD_SCRATCH, chunks, channels)
    arrays = (_color_pairs(color), velocity, counts, masses, tile, row_order(batch * height), int(need_color))
    _gather_backward(*arrays, grad_out, grads, grad_velocity, grad_masses, *scratch)
    grad_color = None
    if need_color:
        grad_color = np.empty_like(color)
        _deinterleave_sum(grads, grad_color)
    return grad_color, grad_velocity if need_velocity else None, grad_masses.sum(axis=0) if need_masses else None
