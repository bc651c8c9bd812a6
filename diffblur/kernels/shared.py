"""What the fused CPU kernels (numba) share: the numba set-up, the pair layouts, the row blocks, the
bilinear reads and their slopes, the scatter of a read's gradient, and the scratch arrays.

One file per op holds its kernels (`reconstruct`, `gather`, `scatter`); they take and return NumPy
arrays, so both backends share them (`torch_impl._fused*`, `jax_impl._fused*`).

The forward and backward kernels run a block of pixels of one row as SIMD vectors (see "The forward
runs a block" below): the per-pixel state lives in scratch arrays passed as separate arguments. A
kernel's scratch is a named tuple (`ReconstructForwardScratch`, ...) whose fields are the kernel's
trailing `*_s` parameters, in order, each typed by its kind (`Floats`, `Ints`, `ChannelFloats`,
`GradientFloats`);
`scratch_for` allocates one and `check_scratch` (run when each kernel module loads) checks the
fields against the kernel's parameters by name.
"""

from __future__ import annotations

import inspect
import math
import os
import sys
import threading
import time
from typing import Any, NewType, TypeVar, get_type_hints

import numpy as np

__all__ = [
    "THREADING_LAYER",
    "ChannelFloats",
    "Floats",
    "GradientFloats",
    "Ints",
    "available",
    "check_scratch",
    "read_only",
    "row_order",
    "scratch_for",
    "work_counter",
    "work_pieces",
]

try:  # numba is a dependency; the guard keeps the pure ops usable where it cannot load.
    import numba
    from llvmlite import ir as _ir
    from numba.core import types as _types
    from numba.extending import intrinsic as _intrinsic
    from numba.extending import overload as _overload
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

#: Row interleave of the parallel loops: each thread's static share of the rows is spread over the
#: whole image, so a scene whose motion sits in one band still keeps both cores busy.
_ROW_INTERLEAVE = 16


def available() -> bool:
    """Whether the fused kernels can run (numba imports)."""
    return numba is not None


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


def row_order(rows: int, interleave: int = _ROW_INTERLEAVE) -> np.ndarray:
    """Rows 0, 16, 32, ..., 1, 17, ... (for an interleave of 16): the order the parallel loops visit
    the B * H rows in."""
    return np.argsort(np.arange(rows) % interleave, kind="stable").astype(np.int64)


#: Seconds a kernel's compile runs before `_CompileNotice` says so: the small kernels (copies, sums)
#: compile in under a second and stay silent.
COMPILE_NOTICE_AFTER = 3.0


class _CompileNotice(numba.core.event.Listener if numba is not None else object):
    """A line on stderr while a fused kernel compiles for more than COMPILE_NOTICE_AFTER seconds,
    and one when it is done: a first call with new argument types (a dtype, a path) compiles for
    tens of seconds on a few cores (docs/fused.md), which without a word looks like a hang. numba
    reports a compile only on a cache miss (event "numba:compile"): calls that load the kernel from
    numba's on-disk cache say nothing."""

    def __init__(self) -> None:
        self.names: dict[int, str] = {}  # id of a `_jit` kernel's dispatcher -> its name
        self.pending: dict[tuple[int, int], dict] = {}  # (dispatcher, thread) -> the compile's state
        self.lock = threading.Lock()  # the timer's line and the end's, in order, never after the end

    def on_start(self, event) -> None:
        name = self.names.get(id(event.data["dispatcher"]))
        if name is None:  # an inlined helper, or someone else's numba function
            return
        floats = [arg for arg in event.data["args"] if isinstance(arg, _types.Array) and isinstance(arg.dtype, _types.Float)]
        images = [arg for arg in floats if arg.ndim == 4] or floats  # (B, C, H, W): the dtype a user chose
        state = {"name": name, "start": time.perf_counter(), "said": False, "done": False}

        def say() -> None:
            with self.lock:
                if not state["done"]:
                    dtypes = ", ".join(sorted({str(arg.dtype) for arg in images}))
                    print(f"diffblur: compiling the fused kernel {name} ({dtypes}) for numba's on-disk cache, once per dtype and path; later calls and processes load it", file=sys.stderr, flush=True)
                    state["said"] = True

        state["timer"] = threading.Timer(COMPILE_NOTICE_AFTER, say)
        state["timer"].daemon = True
        self.pending[(id(event.data["dispatcher"]), threading.get_ident())] = state
        state["timer"].start()

    def on_end(self, event) -> None:
        state = self.pending.pop((id(event.data["dispatcher"]), threading.get_ident()), None)
        if state is None:
            return
        state["timer"].cancel()
        with self.lock:
            state["done"] = True
            if state["said"]:
                print(f"diffblur: {state['name']} compiled in {time.perf_counter() - state['start']:.0f} s", file=sys.stderr, flush=True)


_COMPILE_NOTICE = _CompileNotice()
if numba is not None:
    numba.core.event.register("numba:compile", _COMPILE_NOTICE)


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
    dispatcher = numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy", fastmath=True)(function)
    _COMPILE_NOTICE.names[id(dispatcher)] = f"{function.__module__.rsplit('.', 1)[-1]}.{function.__name__.lstrip('_')}"
    return _Locked(dispatcher)


def _inline(function):
    """A helper whose numba IR is copied into every caller before typing (numba's inline="always"),
    so that LLVM optimises the helper and the caller's loop as one function: the backward's loops
    need it (compiled on its own first, `_tap_gradients` made the per-pixel backward about a tenth
    slower). Each copy adds to the kernel's compile time: call such a helper once in a loop over
    what varies (reconstruct's backward scatters every input channel through one copy) rather than
    once per case."""
    if numba is None:  # pragma: no cover
        return function
    return numba.njit(inline="always", cache=True, error_model="numpy", fastmath=True)(function)


def _llvm_inline(function):
    """A helper compiled once on its own and inlined by LLVM where it is called (numba's
    forceinline): none of `_inline`'s compile time per call site, for the helpers whose callers
    ran no slower so (the forward's tap weights and reads)."""
    if numba is None:  # pragma: no cover
        return function
    return numba.njit(forceinline=True, cache=True, error_model="numpy", fastmath=True)(function)


def _real(value, like):  # pragma: no cover - numba compiles the overload below
    raise NotImplementedError


if numba is not None:

    @_overload(_real, inline="always")
    def _real_overload(value, like):
        """`value` in the floating type of `like` (a scalar or an array): float32 stays float32,
        anything else is float64. A literal such as 1.0 is float64 to numba and would turn float32
        arithmetic into float64; the kernels write their constants as _real(1.0, x) instead."""
        kind = like.dtype if isinstance(like, _types.Array) else like
        if kind == _types.float32:
            return lambda value, like: np.float32(value)
        return lambda value, like: np.float64(value)


@_inline
def _length(a, b):
    squared = a * a + b * b
    return math.sqrt(squared) if squared > 0.0 else _real(0.0, squared)


@_inline
def _soft_depth_compare(z_a, z_b, extent, inverse_extent):
    behind = z_b - z_a
    ramp = behind * inverse_extent
    if behind < 0.0:
        return _real(1.0, ramp)
    if behind > extent:
        return _real(0.0, ramp)
    return _real(1.0, ramp) - ramp


@_jit
def _deinterleave_sum(grads, out, first):
    """Sum channels [first, first + K) of the (chunks, B, H, W, stored) per-chunk gradient buffers
    into out (B, K, H, W)."""
    chunks, batch, height, width, _ = grads.shape
    channels = out.shape[1]
    for row in numba.prange(batch * height):
        b = row // height
        y = row % height
        for x in range(width):
            for c in range(channels):
                total = 0.0
                for chunk in range(chunks):
                    total += grads[chunk, b, y, x, first + c]
                out[b, c, y, x] = total


# The forward runs a block of pixels of one row as vectors: for each tap index k, one loop over the
# block's pixels with no branches, whose bilinear reads LLVM turns into SIMD gathers (2x faster than a
# pixel-at-a-time loop here). Three things make that loop vectorize: the per-pixel state lives in
# scratch arrays that are separate arguments of the parallel loop (numba marks non-aliasing arguments
# `noalias`; a view or a bool flag copied inside the loop counts as an alias and turns that off), the
# image is read as (left, right) pairs (`_pairs`: one 64-bit read per bilinear row for float32), and
# a block is a run of tiles with one tap count (`_block_end`), so every lane takes the same taps and
# adaptive sampling saves per tile, not per block.
# 256 pixels: at 1280x720 (S=15, no jitter, 2 cores) the reconstruct kernels took 40 / 103 ms
# (forward / backward, best of 15) against 43 / 118 ms with blocks of 128 and 42 / 110 with 512.
_BLOCK = 256


if numba is not None:

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
def _block_end(counts, b, tile_y, start, width, tile, block):
    """Where the block that starts at column `start` ends: the run of tiles with the count of
    `start`'s tile, at most `block` pixels (_BLOCK; the shifted-row backward's are longer)."""
    count = counts[b, tile_y, start // tile]
    end = min((start // tile + 1) * tile, width)
    while end < width and end - start < block and counts[b, tile_y, end // tile] == count:
        end = min(end + tile, width)
    return min(end, start + block)


@_inline
def _tap_corner(px, py, last_x, last_y):
    """A tap at (px, py) clamped to the image as `diffblur.ops.sampling.sample` does: its top-left pixel (a
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
    `diffblur.ops.sampling.sample` computes it (a + f (b - a), the columns first)."""
    top_left, top_right = _pair(pairs, index)
    bottom_left, bottom_right = _pair(pairs, index + below)
    top = top_left + fx * (top_right - top_left)
    bottom = bottom_left + fx * (bottom_right - bottom_left)
    return top + fy * (bottom - top)


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
    each with its weight; indexed rather than sliced (a slice is an alias). The weights are in the
    fractions' precision (a float64 1.0 turns each float32 add into two conversions) and the
    indices unsigned (a signed one carries numba's negative-index wraparound)."""
    one = _real(1.0, fx)
    right = grad * fx
    left = grad * (one - fx)
    part = np.uint64(chunk)
    image = np.uint64(b)
    k = np.uint64(channel)
    top = np.uint64(row0)
    bottom = np.uint64(row1)
    first = np.uint64(column0)
    second = np.uint64(column1)
    grads[part, image, top, first, k] += left * (one - fy)
    grads[part, image, top, second, k] += right * (one - fy)
    grads[part, image, bottom, first, k] += left * fy
    grads[part, image, bottom, second, k] += right * fy


# Each scratch row is followed by 1024 elements (4 KiB of float32) that no thread touches. Side by
# side, one thread's row next to another's, the float64 backward on 2 threads took 365 ms at 720p
# instead of 250 with a 1 KiB gap (256 B: 355 ms); likely the prefetcher running ahead of one
# thread's row into the other's. With float32 scratch 128 elements were 512 B: the per-pixel
# backward 246.7 against 236.8 ms with 1024 (720p, median of 7, interleaved).
_SCRATCH_GAP = 1024



#: The kinds of a kernel's *_s scratch arrays, as the annotations of its scratch named tuple: one
#: block row per chunk of rows, float64 (chunks, row) or int64 (chunks, row), float64 per colour
#: channel (chunks, C, row), or float64 per input channel with a gradient (chunks, C + 3, row: the
#: colours, V's two, Z), with row = _BLOCK + _SCRATCH_GAP.
Floats = NewType("Floats", np.ndarray)
Ints = NewType("Ints", np.ndarray)
ChannelFloats = NewType("ChannelFloats", np.ndarray)
GradientFloats = NewType("GradientFloats", np.ndarray)

Scratch = TypeVar("Scratch")


def _scratch_shapes(chunks: int, channels: int, floats: Any, block: int = _BLOCK) -> dict:
    """Each scratch kind's array shape and dtype, for blocks of at most `block` pixels."""
    row = block + _SCRATCH_GAP
    return {
        Floats: ((chunks, row), floats),
        Ints: ((chunks, row), np.int64),
        ChannelFloats: ((chunks, channels, row), floats),
        GradientFloats: ((chunks, channels + 3, row), floats),
    }


def scratch_for(layout: type[Scratch], chunks: int, channels: int, floats: Any = np.float64, block: int = _BLOCK) -> Scratch:
    """A fresh `layout` (a kernel's scratch named tuple), each field an uninitialised array of its
    annotated kind (`_scratch_shapes`), the floating ones of dtype `floats`, for blocks of at most
    `block` pixels. The kernel takes it as `*scratch`."""
    shapes = _scratch_shapes(chunks, channels, floats, block)
    kinds = get_type_hints(layout)
    return layout(*(np.empty(*shapes[kinds[name]]) for name in layout._fields))


def check_scratch(kernel: Any, layout: type) -> None:
    """Raise unless `kernel`'s last parameters are `layout`'s fields, each with the suffix _s, in
    order: the named tuple is passed by position, so its order is the kernel's."""
    parameters = list(inspect.signature(getattr(kernel, "py_func", kernel)).parameters)
    expected = [f"{name}_s" for name in layout._fields]
    if parameters[-len(expected) :] != expected:
        raise TypeError(f"{layout.__name__} does not match {parameters[-len(expected):]} of its kernel")
    kinds = get_type_hints(layout)
    unknown = sorted(set(kinds.values()) - set(_scratch_shapes(1, 1, np.float64)), key=str)
    if unknown:
        raise TypeError(f"{layout.__name__}: unknown scratch kinds {unknown}")


def _threads() -> int:
    return max(1, numba.get_num_threads())


#: Pieces of work per thread that a kernel's workers take one at a time (`_take_next`): the last
#: piece taken, which the others may wait for, is a sixteenth of a thread's share.
_PIECES_PER_THREAD = 16


def work_pieces(rows: int, threads: int) -> int:
    """How many pieces a parallel loop over `rows` rows is cut into for `threads` workers."""
    return max(1, min(rows, _PIECES_PER_THREAD * threads))


def work_counter() -> np.ndarray:
    """The count of pieces taken (`_take_next`), zero: one per kernel call."""
    return np.zeros(1, dtype=np.int64)


if numba is not None:

    @_intrinsic
    def _take_next(typingctx, taken):
        """taken[0] += 1 as one atomic step; returns the value before. A parallel loop runs one
        iteration per thread, each taking pieces of the work by this count until it passes their
        number, so that a thread slowed by other work on its core takes fewer pieces, where a fixed
        split of the range would wait for it (PyTorch's OpenMP workers spin for milliseconds after
        each op, XLA's pool too). taken: a 1-element int64 array (`work_counter`)."""
        if not (isinstance(taken, _types.Array) and taken.dtype == _types.int64):
            return None

        def codegen(context, builder, signature, args):
            array = context.make_array(signature.args[0])(context, builder, args[0])
            return builder.atomic_rmw("add", array.data, _ir.Constant(_ir.IntType(64), 1), "monotonic")

        return _types.int64(taken), codegen

else:  # pragma: no cover - without numba no kernel runs

    def _take_next(taken):
        taken[0] += 1
        return taken[0] - 1
