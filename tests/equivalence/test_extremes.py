"""The primitives at the extremes, the same assertions on both backends.

Velocity exactly 0, at and beyond the clamp, a huge exposure, equal depths, a soft extent near 0,
images whose size is not a multiple of the tile, batches that must not mix.
"""

from __future__ import annotations

import numpy as np
import pytest

from diffblur import reference
from diffblur.conventions import EPSILON


def vector_field(vx, vy, height=1, width=1, batch=1):
    field = np.zeros((batch, 2, height, width))
    field[:, 0], field[:, 1] = vx, vy
    return field


def test_zero_displacement_gives_zero_velocity_and_finite_gradients(backend):
    ops = backend.ops
    zero = backend.array(vector_field(0.0, 0.0))
    assert np.all(backend.numpy(ops.velocity_from_motion(zero)) == 0)
    d_disp, d_exposure = backend.grad(lambda d, e: ops.velocity_from_motion(d, exposure=e)[:, 0], zero, backend.array(1.0))
    # V = q * min_radius / EPSILON near q = 0, with q = displacement / 2: a large but finite slope.
    np.testing.assert_allclose(d_disp[0, :, 0, 0], [0.5 * 0.5 / EPSILON, 0.0])
    assert d_exposure == 0.0
    (d_vector,) = backend.grad(ops.safe_length, zero)
    assert np.all(d_vector == 0.0)


@pytest.mark.parametrize("speed", [0.0, 1e-8])
def test_classifiers_at_zero_speed_are_finite(backend, speed):
    ops = backend.ops
    distance = backend.array([0.0, 0.5, 2.0])
    speeds = backend.array([speed] * 3)
    np.testing.assert_array_equal(backend.numpy(ops.cone(distance, speeds)), [1.0, 0.0, 0.0])
    np.testing.assert_array_equal(backend.numpy(ops.cylinder(distance, speeds)), [1.0, 0.0, 0.0])
    for op in (ops.cone, ops.cylinder):
        for g in backend.grad(op, distance, speeds):
            assert np.all(np.isfinite(g))


@pytest.mark.parametrize("scale", [1.0, 10.0, 1e6])
def test_velocity_at_and_beyond_the_clamp(backend, scale):
    ops = backend.ops
    # |q| = |displacement| / 2 = 5 * scale against max_radius = 5: exactly at the clamp for scale 1.
    displacement = backend.array(vector_field(6.0 * scale, 8.0 * scale))
    velocity = backend.numpy(ops.velocity_from_motion(displacement, max_radius=5.0))
    np.testing.assert_allclose(velocity[0, :, 0, 0], [3.0, 4.0], rtol=1e-12)
    d_disp, d_exposure = backend.grad(lambda d, e: ops.velocity_from_motion(d, exposure=e, max_radius=5.0)[:, 0], displacement, backend.array(1.0))
    assert np.all(np.isfinite(d_disp)) and np.isfinite(d_exposure)
    if scale == 1.0:  # at the clamp the gradient is that of the inside: dVx/de = displacement_x / 2
        np.testing.assert_allclose(d_exposure, 3.0)
    else:  # beyond it the clamp hides the exposure, as seed 000 defines it (documented)
        assert abs(d_exposure) < 1e-12


def test_huge_exposure_is_finite(backend):
    ops = backend.ops
    displacement = backend.array(np.random.default_rng(0).normal(size=(1, 2, 3, 3)))
    for exposure in (1e4, 1e30):
        out = backend.numpy(ops.velocity_from_motion(displacement, exposure=exposure))
        assert np.all(np.isfinite(out))
        np.testing.assert_allclose(np.linalg.norm(out, axis=1), 20.0, rtol=1e-9)


def test_equal_depths_count_as_in_front_with_inside_gradient(backend):
    ops = backend.ops
    z = backend.array([1.0, 2.0, 3.0])
    extent = 0.25
    assert np.all(backend.numpy(ops.soft_depth_compare(z, z, extent)) == 1.0)
    d_a, d_b = backend.grad(lambda a, b: ops.soft_depth_compare(a, b, extent), z, z)
    np.testing.assert_allclose(d_a, 1.0 / extent)
    np.testing.assert_allclose(d_b, -1.0 / extent)


@pytest.mark.parametrize("dtype", ["float32", "float64"])
@pytest.mark.parametrize("extent", [1e-9, 1e-30])
def test_tiny_extent_is_a_finite_step(backend, dtype, extent):
    ops = backend.ops
    z_a = backend.array([1.0, 1.0, 1.0, 1.0, 1.0], dtype)
    z_b = backend.array([0.5, 1.0, 1.0 + 1e-3, 2.0, 1e4], dtype)
    out = backend.numpy(ops.soft_depth_compare(z_a, z_b, extent))
    np.testing.assert_array_equal(out, [1.0, 1.0, 0.0, 0.0, 0.0])
    extent_array = backend.array(extent, dtype)
    for g in backend.grad(lambda a, b, e: ops.soft_depth_compare(a, b, e), z_a, z_b, extent_array):
        assert np.all(np.isfinite(g))


@pytest.mark.parametrize("height,width,tile", [(1, 1, 20), (5, 3, 20), (1, 17, 4), (9, 8, 4), (20, 20, 20), (21, 19, 20)])
def test_tile_and_neighbor_max_on_sizes_not_multiple_of_tile(backend, height, width, tile):
    ops = backend.ops
    rng = np.random.default_rng(height * 100 + width)
    velocity = rng.normal(size=(2, 2, height, width)) * 5
    tiles = ops.tile_max(backend.array(velocity), tile)
    assert tuple(tiles.shape) == (2, 2, -(-height // tile), -(-width // tile))
    np.testing.assert_array_equal(backend.numpy(tiles), reference.tile_max(velocity, tile))
    np.testing.assert_array_equal(backend.numpy(ops.neighbor_max(tiles)), reference.neighbor_max(reference.tile_max(velocity, tile)))


@pytest.mark.parametrize("height,width,tile", [(9, 8, 4), (21, 19, 20), (7, 30, 3)])
def test_neighbor_max_of_the_velocity_in_one_gather_is_neighbor_max_of_tile_max(backend, height, width, tile):
    """The fused reconstruct's NeighborMax (one gather from the velocity) against the two steps:
    the same vectors and the same gradient, ties included (whole rows of equal speeds)."""
    from diffblur.ops import primitives

    be = backend.ops._backend.TORCH if backend.name == "torch" else backend.ops._backend.JAX
    rng = np.random.default_rng(height * 100 + width + tile)
    velocity = np.round(rng.normal(size=(2, 2, height, width)) * 3)
    velocity[:, 0, ::3], velocity[:, 1, ::3] = 2.0, -2.0  # rows of equal vectors: ties in tiles and between them
    weights = backend.array(rng.normal(size=(2, 2, -(-height // tile), -(-width // tile))))
    one_gather = lambda v: primitives.neighbor_max_of_velocity(be, v, tile) * weights  # noqa: E731
    two_steps = lambda v: primitives.neighbor_max(be, primitives.tile_max(be, v, tile)) * weights  # noqa: E731
    array = backend.array(velocity)
    np.testing.assert_array_equal(backend.numpy(one_gather(array)), backend.numpy(two_steps(array)))
    np.testing.assert_array_equal(backend.numpy(primitives.neighbor_max_of_velocity(be, array, tile)), reference.neighbor_max(reference.tile_max(velocity, tile)))
    np.testing.assert_array_equal(backend.grad(one_gather, array)[0], backend.grad(two_steps, array)[0])


def test_tile_max_picks_largest_magnitude_not_componentwise_max(backend):
    ops = backend.ops
    velocity = np.zeros((1, 2, 2, 2))
    velocity[0, :, 0, 0] = [3.0, 0.0]
    velocity[0, :, 0, 1] = [0.0, 2.0]
    velocity[0, :, 1, 1] = [-4.0, 0.0]  # the longest, though its x is the smallest
    out = backend.numpy(ops.tile_max(backend.array(velocity), 2))
    np.testing.assert_array_equal(out[0, :, 0, 0], [-4.0, 0.0])
    # Gradient flows to the chosen pixel only.
    (g,) = backend.grad(lambda v: ops.tile_max(v, 2)[:, 0], backend.array(velocity))
    expected = np.zeros_like(velocity)
    expected[0, 0, 1, 1] = 1.0
    np.testing.assert_array_equal(g, expected)


def test_ties_go_to_the_first_pixel_and_never_to_padding(backend):
    ops = backend.ops
    zero = backend.array(np.zeros((1, 2, 3, 3)))
    (g,) = backend.grad(lambda v: ops.tile_max(v, 2)[:, 0], zero)
    # Four tiles (2 x 2, partial on the right and bottom); each routes its gradient to its top-left pixel.
    expected = np.zeros((1, 2, 3, 3))
    expected[0, 0, ::2, ::2] = 1.0
    np.testing.assert_array_equal(g, expected)


def test_batch_items_do_not_mix(backend):
    ops = backend.ops
    rng = np.random.default_rng(5)
    velocity = rng.normal(size=(3, 2, 9, 10)) * 3
    whole = backend.numpy(ops.neighbor_max(ops.tile_max(backend.array(velocity), 4)))
    for b in range(3):
        single = backend.numpy(ops.neighbor_max(ops.tile_max(backend.array(velocity[b : b + 1]), 4)))
        np.testing.assert_array_equal(whole[b : b + 1], single)
