"""The fused CPU reconstruct (diffblur.kernels.reconstruct) against the pure tensor ops, both frameworks.

The pure ops are the reference: the fused path must give the same image and the same gradients
w.r.t. color, velocity and depth (float64: to rounding; float32: to float32 tolerance), for every
option it accepts, eagerly, under jax.jit and under jax.vmap; it must refuse what it does not
cover when asked for (impl="fused") and quietly use the pure ops otherwise (impl="auto").
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

torch = pytest.importorskip("torch")
jax = pytest.importorskip("jax")
numba = pytest.importorskip("numba")
import jax.numpy as jnp  # noqa: E402

import jax_impl  # noqa: E402
from diffblur.kernels import reconstruct as reconstruct_kernel  # noqa: E402
from diffblur.kernels.shared import _BLOCK  # noqa: E402
import torch_impl  # noqa: E402
from torch_impl._backend import TORCH  # noqa: E402
from tests.tolerances import tolerance  # noqa: E402

FUSED_FLOAT64, FUSED_FLOAT32 = (tolerance(dtype, "fused", "reconstruct") for dtype in ("float64", "float32"))

BATCH, CHANNELS, HEIGHT, WIDTH = 2, 3, 11, 14

#: Options the fused kernel covers (small radius: several tiles on a 11 x 14 image).
CASES = {
    "default": dict(max_radius=4.0, samples=7),
    "own directions": dict(max_radius=4.0, samples=7, directions="neighbor_and_own"),
    "early out": dict(max_radius=4.0, samples=7, early_out=True),
    # Without jitter (or with one constant per tile) the kernels read every tap as a shifted row.
    "no jitter": dict(max_radius=3.0, samples=5, jitter="none"),
    "no jitter, adaptive, early out": dict(max_radius=4.0, samples=15, adaptive=(3, 7), early_out=True, jitter="none"),
    "no jitter, min radius, soft z": dict(max_radius=5.0, samples=9, min_radius=1.5, soft_z_extent=0.02, jitter="none"),
    "adaptive": dict(max_radius=4.0, samples=15, adaptive=True),
    "adaptive, early out": dict(max_radius=4.0, samples=15, adaptive=(3, 7), early_out=True),
    # Tap 7, the middle of 15 (skipped), is a real tap of the 9-tap class beside it.
    "adaptive, classes past a middle": dict(max_radius=4.0, samples=15, adaptive=(5, 9)),
    "min radius, soft z": dict(max_radius=5.0, samples=9, min_radius=1.5, soft_z_extent=0.02),
}


def _scene(dtype=np.float64, seed=0, width=WIDTH):
    """Two depth layers, a fast block over a slowly drifting background, one still corner tile; a
    wider image gets a second fast block across the kernels' first block boundary (_BLOCK)."""
    rng = np.random.default_rng(seed)
    color = rng.random((BATCH, CHANNELS, HEIGHT, width))
    velocity = np.zeros((BATCH, 2, HEIGHT, width))
    velocity[:, 0] = 0.7
    velocity[:, :, 3:8, 4:10] = rng.uniform(-6, 6, size=(BATCH, 2, 1, 1))
    if width > _BLOCK:
        velocity[:, :, 1:9, _BLOCK - 7 : _BLOCK + 5] = rng.uniform(-6, 6, size=(BATCH, 2, 1, 1))
    velocity[:, :, :, :] += rng.normal(0, 0.3, size=velocity.shape)
    velocity[:, :, 8:, 10:14] = 0.0  # a still region
    depth = np.where(velocity[:, :1] ** 2 > 4.0, 1.0, 2.0) + rng.uniform(0, 0.05, size=(BATCH, 1, HEIGHT, width))
    cotangent = rng.standard_normal((BATCH, CHANNELS, HEIGHT, width))
    return [a.astype(dtype) for a in (color, velocity, depth, cotangent)]


def _torch_run(arrays, options, impl):
    color, velocity, depth = (torch.tensor(a, requires_grad=True) for a in arrays[:3])
    out = torch_impl.reconstruct(color, velocity, depth, impl=impl, **options)
    grads = torch.autograd.grad(out, (color, velocity, depth), torch.tensor(arrays[3]))
    return out.detach().numpy(), [g.numpy() for g in grads]


def _jax_run(arrays, options, impl, transform=lambda f: f):
    cotangent = jnp.asarray(arrays[3])

    def loss(color, velocity, depth):
        return jnp.sum(jax_impl.reconstruct(color, velocity, depth, impl=impl, **options) * cotangent)

    out = transform(lambda c, v, d: jax_impl.reconstruct(c, v, d, impl=impl, **options))(*arrays[:3])
    grads = transform(jax.grad(loss, argnums=(0, 1, 2)))(*arrays[:3])
    return np.asarray(out), [np.asarray(g) for g in grads]


def _assert_close(fused, pure, tolerance):
    out_f, grads_f = fused
    out_p, grads_p = pure
    np.testing.assert_allclose(out_f, out_p, rtol=0, atol=tolerance)
    for name, gf, gp in zip(("color", "velocity", "depth"), grads_f, grads_p):
        scale = max(1.0, float(np.abs(gp).max()))
        np.testing.assert_allclose(gf, gp, rtol=0, atol=tolerance * scale, err_msg=f"gradient w.r.t. {name}")


@pytest.mark.parametrize("case", list(CASES))
def test_torch_fused_matches_pure_float64(case):
    arrays = _scene()
    _assert_close(_torch_run(arrays, CASES[case], "fused"), _torch_run(arrays, CASES[case], "tensor"), FUSED_FLOAT64)


@pytest.mark.parametrize("case", list(CASES))
def test_jax_fused_matches_pure_float64_under_jit(case):
    arrays = _scene()
    _assert_close(_jax_run(arrays, CASES[case], "fused", jax.jit), _jax_run(arrays, CASES[case], "tensor"), FUSED_FLOAT64)


@pytest.mark.parametrize("case", ["default", "own directions", "adaptive, early out", "adaptive, classes past a middle", "no jitter", "no jitter, adaptive, early out"])
def test_rows_wider_than_one_block(case):
    """The kernels run each row in blocks of at most _BLOCK pixels that end where the tiles'
    tap count changes: several blocks, a partial last one, adaptive classes side by side."""
    arrays = _scene(width=_BLOCK + 23)
    _assert_close(_torch_run(arrays, CASES[case], "fused"), _torch_run(arrays, CASES[case], "tensor"), FUSED_FLOAT64)


@pytest.mark.parametrize("jitter", ["none", "per pair of tiles"])
def test_shifted_rows_across_tiles_of_one_motion(jitter, monkeypatch):
    """A pan: neighbouring tiles share NeighborMax, so the shifted rows read runs of several tiles at
    once (cut where the jitter or the motion changes, at the block's end and at the border). The
    backward's blocks (`_ROW_BLOCK`, 640 px) shortened to 110 px here: a row of three, the last
    partial, and a block's end inside a tile."""
    monkeypatch.setattr(reconstruct_kernel, "_ROW_BLOCK", 110)
    width, tile = _BLOCK + 23, 4
    color, velocity, depth, cotangent = _scene(width=width)
    velocity[...] = np.array([3.3, 0.6]).reshape(1, 2, 1, 1)
    # Two more motions mid-row, each differing from the pan in one component of NeighborMax.
    velocity[:, :, 4:, 40:60] = np.array([3.3, -1.7]).reshape(1, 2, 1, 1)
    velocity[:, :, :7, 120:150] = np.array([-4.5, 0.6]).reshape(1, 2, 1, 1)
    options = dict(max_radius=float(tile), samples=7, jitter="none")
    if jitter != "none":  # constant over pairs of tiles: runs of two tiles
        options["jitter"] = _per_tile_jitter(2 * tile, width=width)
        assert reconstruct_kernel.shifted_rows(options["jitter"], tile, own_odd=False)
    arrays = [color, velocity, depth, cotangent]
    torch_options = dict(options, jitter=torch.tensor(options["jitter"])) if jitter != "none" else options
    _assert_close(_torch_run(arrays, torch_options, "fused"), _torch_run(arrays, torch_options, "tensor"), FUSED_FLOAT64)
    jax_options = dict(options, jitter=jnp.asarray(options["jitter"])) if jitter != "none" else options
    _assert_close(_jax_run(arrays, jax_options, "fused", jax.jit), _jax_run(arrays, jax_options, "tensor"), FUSED_FLOAT64)


@pytest.mark.parametrize(("batch", "height", "tiles_y", "threads", "largest_y"), [(1, 720, 36, 2, 0.0), (2, 37, 10, 2, 9.2), (3, 11, 3, 8, 2.5), (1, 5, 1, 2, 40.0)])
def test_shifted_row_bands_cover_every_row_once_and_the_taps_reach(batch, height, tiles_y, threads, largest_y):
    """The shifted-row backward's bands: whole tile rows of one image each, together every row once
    in order, and margins deep enough for the farthest row a tap reads (|NeighborMax_y| + 1)."""
    tile = -(-height // tiles_y)
    neighbors = np.zeros((batch, 2, tiles_y, 3))
    neighbors[-1, 1, -1, 0] = -largest_y
    bands, reach = reconstruct_kernel._bands(neighbors, height, tile, threads)
    assert bands[0] == 0 and bands[-1] == batch * height and np.all(np.diff(bands) > 0)
    for start, end in zip(bands[:-1], bands[1:]):
        assert start // height == (end - 1) // height  # within one image
        assert start % height % tile == 0 and (end % height == 0 or end % height % tile == 0)
    assert min(height, largest_y + 1) <= reach <= height
    # as many bands as keep them 4 reach high, but at least 4 per thread (or one per tile row)
    per_image = (len(bands) - 1) // batch
    assert per_image >= min(tiles_y, -(-4 * threads // batch))
    if per_image > min(tiles_y, -(-4 * threads // batch)):
        assert min(np.diff(bands)[: per_image - 1]) >= 4 * reach  # the last band of an image may be cut short


def test_workers_take_every_piece_once():
    """`_take_next`, the count the kernels' threads take their pieces of work from: over many
    pieces and more workers than cores, each piece is taken by exactly one worker, and each worker
    stops at the first number past the last piece."""
    numba = pytest.importorskip("numba")
    from diffblur.kernels.shared import _take_next, work_counter, work_pieces

    @numba.njit(parallel=True)
    def take_all(workers, pieces, taken, takers):
        for _ in numba.prange(workers):
            while True:
                piece = _take_next(taken)
                if piece >= pieces:
                    break
                takers[piece] += 1

    assert work_pieces(720, 2) == 32 and work_pieces(5, 2) == 5
    for workers, pieces in ((2, 32), (8, 100_000), (3, 1)):
        taken, takers = work_counter(), np.zeros(pieces, dtype=np.int64)
        take_all(workers, pieces, taken, takers)
        assert np.all(takers == 1) and taken[0] == pieces + workers


@pytest.mark.parametrize(("largest_y", "expected"), [(0.0, 36), (7.5, 18), (15.0, 9), (40.0, 8)])
def test_shifted_row_bands_at_720p(largest_y, expected):
    """720p, tiles of 20, 2 threads: a horizontal pan (reach 2) gets a band per tile row; longer
    vertical motion fewer, taller bands, 4 reach high each, and never fewer than 8."""
    neighbors = np.zeros((1, 2, 36, 64))
    neighbors[0, 1, 3, 5] = largest_y
    bands, reach = reconstruct_kernel._bands(neighbors, 720, 20, 2)
    assert len(bands) - 1 == expected and reach == math.ceil(largest_y) + 2


@pytest.mark.parametrize(
    ("batch", "tiles_y", "threads", "moving_rows"),
    [(1, 36, 2, slice(None)), (1, 36, 2, slice(0, 18)), (1, 36, 2, slice(30, 36)), (3, 7, 4, slice(2, 5)), (1, 1, 2, slice(None)), (2, 9, 8, slice(None))],
)
def test_band_turns_share_the_work_evenly(batch, tiles_y, threads, moving_rows):
    """`_band_turns`: every band once, the most work first, so that workers of one speed, each
    taking the next band when free, end within one band's work of the mean (720p in 2 threads: 18
    tile rows each, where every other band gave one thread 16 and the other 20); also when the
    motion sits in one part of the image and the other tiles early-out."""
    tile, tiles_x = 20, 64
    height = tiles_y * tile
    counts = np.zeros((batch, tiles_y, tiles_x), dtype=np.int32)
    counts[:, moving_rows] = 15
    neighbors = np.zeros((batch, 2, tiles_y, tiles_x))
    neighbors[:, 1] = 40.0  # long vertical motion: the fewest bands, 4 per thread, of unequal heights
    bands, _ = reconstruct_kernel._bands(neighbors, height, tile, threads)
    turns = reconstruct_kernel._band_turns(bands, counts, height, tile)
    assert sorted(turns.tolist()) == list(range(len(bands) - 1))  # every band once
    # each band's work recomputed here row by row from the tiles that the row crosses
    tile_costs = np.where(counts > 0, counts + reconstruct_kernel._TILE_COST_BESIDE_TAPS, reconstruct_kernel._EARLY_OUT_TILE_COST)
    costs = np.array([sum(tile_costs[row // height, row % height // tile].sum() for row in range(start, end)) for start, end in zip(bands[:-1], bands[1:])])
    np.testing.assert_allclose(reconstruct_kernel._band_costs(bands, counts, height, tile), costs)
    assert np.all(np.diff(costs[turns]) <= 0)  # the most work first
    loads, tile_rows = np.zeros(threads), np.zeros(threads, dtype=int)
    for band in turns:  # the next band to the worker that is free first
        worker = int(np.argmin(loads))
        loads[worker] += costs[band]
        tile_rows[worker] += -(-(bands[band + 1] - bands[band]) // tile)
    assert loads.max() <= loads.sum() / threads + costs.max() + 1e-9
    if (batch, tiles_y, threads, moving_rows) == (1, 36, 2, slice(None)):
        assert np.diff(bands).tolist() == [80, 100] * 4 and tile_rows.tolist() == [18, 18]


def test_shifted_rows_with_motion_across_several_bands():
    """Vertical motion longer than a band is tall: a tap's gradient lands in bands above and below
    its own (each band's margins, added after the kernel), on a batch of images."""
    tile = 9  # max_radius: the tiles' size and the longest motion
    rng = np.random.default_rng(7)
    height, width = 37, 29
    color, depth = rng.random((BATCH, CHANNELS, height, width)), 1.0 + rng.random((BATCH, 1, height, width))
    velocity = np.zeros((BATCH, 2, height, width))
    velocity[:, 1] = 3.1
    velocity[0, :, 5:20, 3:15] = np.array([1.3, -8.0]).reshape(2, 1, 1)  # up, beyond the next band
    velocity[1, :, 18:30, 10:25] = np.array([-2.2, 7.5]).reshape(2, 1, 1)
    velocity += rng.normal(0, 0.2, size=velocity.shape)
    cotangent = rng.standard_normal((BATCH, CHANNELS, height, width))
    options = dict(max_radius=float(tile), samples=7, jitter="none")
    bands, reach = reconstruct_kernel._bands(np.full((BATCH, 2, 5, 4), 8.0), height, tile, 2)
    assert reach > np.diff(bands).min()  # the margins span more than one band
    arrays = [color, velocity, depth, cotangent]
    _assert_close(_torch_run(arrays, options, "fused"), _torch_run(arrays, options, "tensor"), FUSED_FLOAT64)
    _assert_close(_jax_run(arrays, options, "fused", jax.jit), _jax_run(arrays, options, "tensor"), FUSED_FLOAT64)


@pytest.mark.parametrize("channels", [1, 3, 4])
@pytest.mark.parametrize("motion", ["horizontal", "diagonal"])
@pytest.mark.parametrize("jitter", ["none", "noise"])
def test_any_channel_count_and_taps_on_a_row(channels, motion, jitter):
    """The backward reads three colours in one loop and the others one channel at a time; a
    horizontal motion puts every tap on a row (fraction fy = 0: the shifted rows' gradients go to
    the top row only). Both against the pure ops, shifted rows (jitter "none") and per pixel."""
    rng = np.random.default_rng(11)
    height, width = 13, 30
    color = rng.random((BATCH, channels, height, width))
    velocity = np.zeros((BATCH, 2, height, width))
    velocity[:, 0] = 2.6
    velocity[:, 0, 3:9, 8:20] = -4.5
    if motion == "diagonal":
        velocity[:, 1] = 1.3
        velocity[:, :, 3:9, 8:20] += rng.normal(0, 0.3, size=(BATCH, 2, 6, 12))
    depth = np.where(velocity[:, :1] < 0, 1.0, 2.0) + rng.uniform(0, 0.05, size=(BATCH, 1, height, width))
    cotangent = rng.standard_normal((BATCH, channels, height, width))
    options = dict(max_radius=4.0, samples=7, jitter=jitter)
    arrays = [color, velocity, depth, cotangent]
    _assert_close(_torch_run(arrays, options, "fused"), _torch_run(arrays, options, "tensor"), FUSED_FLOAT64)
    _assert_close(_jax_run(arrays, options, "fused", jax.jit), _jax_run(arrays, options, "tensor"), FUSED_FLOAT64)


def test_float32_both_frameworks_agree():
    arrays = _scene(np.float32, seed=1)
    options = CASES["default"]
    torch_fused = _torch_run(arrays, options, "fused")
    _assert_close(torch_fused, _torch_run(arrays, options, "tensor"), FUSED_FLOAT32)
    _assert_close(_jax_run(arrays, options, "fused"), torch_fused, FUSED_FLOAT32)


def test_default_takes_the_fused_path_and_it_is_the_pure_result():
    """impl="auto" on float32 CPU inputs runs the kernel (its autograd node), with the pure result."""
    color, velocity, depth, _ = (torch.tensor(a, requires_grad=True) for a in _scene(np.float32))
    out = torch_impl.reconstruct(color, velocity, depth, max_radius=4.0)
    assert "diffblur_reconstruct_forward" in type(out.grad_fn).__name__  # the custom operator's autograd node
    pure = torch_impl.reconstruct(color, velocity, depth, max_radius=4.0, impl="tensor")
    assert "diffblur" not in type(pure.grad_fn).__name__
    torch.testing.assert_close(out, pure, rtol=0, atol=2e-5)


def test_jitter_tensor_per_batch_item():
    arrays = _scene()
    jitter = np.random.default_rng(3).uniform(-0.5, 0.5, size=(BATCH, 1, HEIGHT, WIDTH))
    options = dict(max_radius=4.0, samples=7)
    torch_jitter = dict(options, jitter=torch.tensor(jitter))
    _assert_close(_torch_run(arrays, torch_jitter, "fused"), _torch_run(arrays, torch_jitter, "tensor"), FUSED_FLOAT64)


def _per_tile_jitter(tile, width=WIDTH, seed=4):
    """A jitter constant over each tile's part of a row (it differs between rows and tiles)."""
    values = np.random.default_rng(seed).uniform(-0.5, 0.5, size=(BATCH, 1, HEIGHT, -(-width // tile)))
    return np.repeat(values, tile, axis=3)[..., :width]


def test_which_jitters_read_shifted_rows():
    """The kernels take the shifted rows exactly when every tile's taps share their offsets."""
    tile = 4
    assert reconstruct_kernel.shifted_rows(np.zeros((1, 1, HEIGHT, WIDTH)), tile, own_odd=False)
    assert reconstruct_kernel.shifted_rows(_per_tile_jitter(tile), tile, own_odd=False)
    assert not reconstruct_kernel.shifted_rows(_per_tile_jitter(tile), tile + 1, own_odd=False)
    assert not reconstruct_kernel.shifted_rows(np.zeros((1, 1, HEIGHT, WIDTH)), tile, own_odd=True)
    noise = TORCH.noise_jitter(HEIGHT, WIDTH, torch.zeros(1, dtype=torch.float64)).numpy()
    assert not reconstruct_kernel.shifted_rows(noise, tile, own_odd=False)


@pytest.mark.parametrize("width", [WIDTH, _BLOCK + 23])
def test_a_jitter_constant_per_tile_matches_pure(width):
    """A jitter array constant per tile (fractional tap times, different per row and tile) on the
    shifted rows, both frameworks, float64."""
    options = dict(max_radius=4.0, samples=7)
    arrays = _scene(width=width)
    jitter = _per_tile_jitter(4, width)
    assert reconstruct_kernel.shifted_rows(jitter, 4, own_odd=False)
    torch_options = dict(options, jitter=torch.tensor(jitter))
    _assert_close(_torch_run(arrays, torch_options, "fused"), _torch_run(arrays, torch_options, "tensor"), FUSED_FLOAT64)
    jax_options = dict(options, jitter=jnp.asarray(jitter))
    _assert_close(_jax_run(arrays, jax_options, "fused", jax.jit), _jax_run(arrays, jax_options, "tensor"), FUSED_FLOAT64)


def test_jax_vmap_over_a_leading_axis():
    arrays = _scene()
    stacked = [np.stack([a, a[::-1]]) for a in arrays]
    options = CASES["default"]
    out = jax.vmap(lambda c, v, d: jax_impl.reconstruct(c, v, d, impl="fused", **options))(*stacked[:3])
    for i in range(2):
        reference = jax_impl.reconstruct(*(s[i] for s in stacked[:3]), impl="tensor", **options)
        np.testing.assert_allclose(np.asarray(out[i]), np.asarray(reference), rtol=0, atol=1e-11)


@pytest.mark.parametrize(
    "options, words",
    [
        (dict(sampling="nearest"), "sampling='nearest'"),
        (dict(shutter="gaussian"), "shutter 'gaussian'"),
        (dict(sampling="pyramid"), "sampling='pyramid'"),
    ],
)
def test_fused_true_refuses_what_it_does_not_cover_and_none_falls_back(options, words):
    color, velocity, depth, _ = (torch.tensor(a) for a in _scene(np.float32))
    with pytest.raises(ValueError, match=words.replace("(", r"\(")):
        torch_impl.reconstruct(color, velocity, depth, max_radius=4.0, impl="fused", **options)
    with pytest.raises(ValueError, match=words.replace("(", r"\(")):
        jax_impl.reconstruct(*(jnp.asarray(a.numpy()) for a in (color, velocity, depth)), max_radius=4.0, impl="fused", **options)
    fallback = torch_impl.reconstruct(color, velocity, depth, max_radius=4.0, **options)
    pure = torch_impl.reconstruct(color, velocity, depth, max_radius=4.0, impl="tensor", **options)
    torch.testing.assert_close(fallback, pure, rtol=0, atol=0)


def test_half_precision_falls_back_to_the_tensor_ops():
    color, velocity, depth, _ = (torch.tensor(a).to(torch.float16) for a in _scene(np.float32))
    with pytest.raises(ValueError, match="float16"):
        torch_impl.reconstruct(color, velocity, depth, max_radius=4.0, impl="fused")
    assert torch_impl.reconstruct(color, velocity, depth, max_radius=4.0).dtype == torch.float16


def test_torch_double_backward_is_refused_clearly():
    color, velocity, depth, _ = (torch.tensor(a, requires_grad=True) for a in _scene())
    (grad,) = torch.autograd.grad(torch_impl.reconstruct(color, velocity, depth, max_radius=4.0).sum(), velocity, create_graph=True)
    with pytest.raises(RuntimeError, match="double backward"):
        grad.sum().backward()


def test_jax_forward_mode_needs_fused_false():
    color, velocity, depth, _ = (jnp.asarray(a) for a in _scene())
    f = lambda v: jax_impl.reconstruct(color, v, depth, max_radius=4.0, impl="fused")  # noqa: E731
    with pytest.raises(TypeError, match="custom_vjp"):
        jax.jvp(f, (velocity,), (jnp.ones_like(velocity),))
    pure = lambda v: jax_impl.reconstruct(color, v, depth, max_radius=4.0, impl="tensor")  # noqa: E731
    _, tangent = jax.jvp(pure, (velocity,), (jnp.ones_like(velocity),))
    assert np.isfinite(np.asarray(tangent)).all()


def test_batch_items_do_not_mix():
    arrays = _scene(np.float32)
    color, velocity, depth = (torch.tensor(a) for a in arrays[:3])
    whole = torch_impl.reconstruct(color, velocity, depth, max_radius=4.0, impl="fused")
    single = torch_impl.reconstruct(color[1:], velocity[1:], depth[1:], max_radius=4.0, impl="fused")
    torch.testing.assert_close(whole[1:], single, rtol=0, atol=0)


def test_both_frameworks_run_one_compiled_kernel_per_dtype():
    """numba compiles a kernel once per argument type, read-only arrays (JAX's) apart from writable
    ones (PyTorch's): both frameworks must reach the kernels with one type, or every kernel is
    compiled twice in a process that runs both."""
    arrays = _scene()
    for case in ("default", "no jitter"):
        _torch_run(arrays, CASES[case], impl="fused")
        _jax_run(arrays, CASES[case], impl="fused")
    for kernel in (reconstruct_kernel._reconstruct_forward, reconstruct_kernel._reconstruct_backward):
        float64_types = {signature for signature in kernel.signatures if str(signature[4].dtype) == "float64"}  # 4: color
        # Each path is a signature of its own (pairs None on shifted rows): one each.
        paths = [str(signature[0]) == "none" for signature in float64_types]
        assert sorted(paths) == [False, True], float64_types


@pytest.mark.parametrize("wanted", [("velocity",), ("color",), ("depth",), ("color", "depth")])
def test_torch_backward_computes_only_the_gradients_asked_for(wanted):
    """The kernel skips the scatter of inputs that need no gradient (most of the backward's time);
    the gradients asked for still match the tensor ops'."""
    arrays = _scene()
    results = []
    for impl in ("fused", "tensor"):
        tensors = {name: torch.tensor(a, requires_grad=name in wanted) for name, a in zip(("color", "velocity", "depth"), arrays[:3])}
        out = torch_impl.reconstruct(tensors["color"], tensors["velocity"], tensors["depth"], impl=impl, **CASES["default"])
        grads = torch.autograd.grad(out, [tensors[name] for name in wanted], torch.tensor(arrays[3]))
        results.append([g.numpy() for g in grads])
    for name, fused_grad, pure_grad in zip(wanted, *results):
        assert np.abs(pure_grad).max() > 0, name
        np.testing.assert_allclose(fused_grad, pure_grad, rtol=1e-10, atol=1e-10, err_msg=name)


@pytest.mark.parametrize("wanted", [("velocity",), ("color",), ("depth",), ("color", "depth")])
def test_jax_backward_computes_only_the_gradients_asked_for(wanted, monkeypatch):
    """JAX's rule asks the kernel for the differentiated inputs' gradients only (symbolic zeros),
    under jit too; they match the tensor ops'."""
    arrays = _scene()
    asked = []
    backward = reconstruct_kernel.reconstruct_backward
    monkeypatch.setattr(reconstruct_kernel, "reconstruct_backward", lambda *a, needs, **k: asked.append(needs) or backward(*a, needs=needs, **k))
    names = ("color", "velocity", "depth")
    argnums = tuple(names.index(name) for name in wanted)
    results = []
    for impl in ("fused", "tensor"):
        cotangent = jnp.asarray(arrays[3])
        loss = lambda c, v, d: jnp.sum(jax_impl.reconstruct(c, v, d, impl=impl, **CASES["default"]) * cotangent)  # noqa: E731
        results.append(jax.jit(jax.grad(loss, argnums=argnums))(*(jnp.asarray(a) for a in arrays[:3])))
    assert asked == [tuple(name in wanted for name in names)]
    for name, fused_grad, pure_grad in zip(wanted, *results):
        assert np.abs(pure_grad).max() > 0, name
        np.testing.assert_allclose(fused_grad, pure_grad, rtol=1e-10, atol=1e-10, err_msg=name)


def _add_one(values):  # compiled by test_a_long_compile_says_so_and_a_cached_kernel_does_not
    for i in numba.prange(values.shape[0]):
        values[i] += 1.0


def test_a_long_compile_says_so_and_a_cached_kernel_does_not(tmp_path, monkeypatch, capsys):
    """A kernel's first call with new argument types compiles (tens of seconds for reconstruct's):
    stderr says so while it runs and when it is done; a second call, and a kernel loaded from
    numba's cache by a new dispatcher (a new process), say nothing."""
    from diffblur.kernels import shared

    monkeypatch.setattr(shared, "COMPILE_NOTICE_AFTER", 0.0)  # this one compiles in well under the real 3 s
    # A cold cache of its own. numba rereads its settings from the environment when it compiles, so
    # the directory is set there, and the settings reread after the test.
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    numba.core.config.reload_config()
    try:
        values = np.zeros(4)
        shared._jit(_add_one)(values)
        err = capsys.readouterr().err
        assert re.fullmatch(
            r"diffblur: compiling the fused kernel test_fused\.add_one \(float64\) for numba's on-disk cache, once per dtype and path; later calls and processes load it\n"
            r"diffblur: test_fused\.add_one compiled in \d+ s\n",
            err,
        ), err
        shared._jit(_add_one)(values)  # a new dispatcher: loaded from the cache
        kernel = shared._jit(_add_one)
        kernel(values)
        kernel(values)
        assert capsys.readouterr().err == ""
        assert list(tmp_path.rglob("*_add_one*.nbi")), "not cached in the test's directory"
        np.testing.assert_array_equal(values, 4.0)
    finally:
        monkeypatch.undo()
        numba.core.config.reload_config()
