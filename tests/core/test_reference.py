"""The NumPy oracle against values worked out by hand on tiny inputs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from diffblur import checks, reference


def test_soft_depth_compare_by_hand():
    z_a = np.array([2.0, 2.0, 2.0, 2.0, 2.0])
    z_b = np.array([1.0, 2.0, 2.25, 2.5, 3.0])  # in front, tied, a quarter and half the band behind, beyond
    np.testing.assert_allclose(reference.soft_depth_compare(z_a, z_b, 0.5), [1.0, 1.0, 0.5, 0.0, 0.0])


def test_cone_and_cylinder_by_hand():
    speed = np.full(5, 4.0)
    distance = np.array([0.0, 2.0, 3.8, 4.0, 4.2])
    np.testing.assert_allclose(reference.cone(distance, speed), [1.0, 0.5, 0.05, 0.0, 0.0], atol=1e-15)
    # smoothstep from 0.95 * 4 = 3.8 to 1.05 * 4 = 4.2: 0 at 3.8, 1/2 at 4.0, 1 at 4.2
    np.testing.assert_allclose(reference.cylinder(distance, speed), [1.0, 1.0, 1.0, 0.5, 0.0], atol=1e-12)


def test_velocity_from_motion_by_hand():
    displacement = np.zeros((1, 2, 1, 4))
    displacement[0, :, 0, 0] = [6.0, 8.0]  # q = (3, 4), |q| = 5: inside, kept
    displacement[0, :, 0, 1] = [0.6, 0.0]  # |q| = 0.3 < 0.5: stretched to 0.5
    displacement[0, :, 0, 2] = [0.0, -100.0]  # |q| = 50 > 20: clamped to 20
    velocity = reference.velocity_from_motion(displacement, exposure=1.0, max_radius=20.0, min_radius=0.5)
    np.testing.assert_allclose(velocity[0, :, 0].T, [[3.0, 4.0], [0.5, 0.0], [0.0, -20.0], [0.0, 0.0]])
    half_exposure = reference.velocity_from_motion(displacement, exposure=0.5)
    np.testing.assert_allclose(half_exposure[0, :, 0, 0], [1.5, 2.0])


def test_tile_and_neighbor_max_by_hand():
    velocity = np.zeros((1, 2, 3, 5))
    velocity[0, :, 0, 1] = [1.0, 1.0]
    velocity[0, :, 1, 0] = [0.0, -2.0]  # longest of tile (0, 0)
    velocity[0, :, 2, 4] = [3.0, 0.0]  # alone in the partial tile (1, 2)
    tiles = reference.tile_max(velocity, 2)
    assert tiles.shape == (1, 2, 2, 3)
    np.testing.assert_array_equal(tiles[0, :, 0, 0], [0.0, -2.0])
    np.testing.assert_array_equal(tiles[0, :, 1, 2], [3.0, 0.0])
    np.testing.assert_array_equal(tiles[0, :, 0, 2], [0.0, 0.0])
    neighbors = reference.neighbor_max(tiles)
    # (3, 0) reaches tiles (0, 1), (0, 2), (1, 1), (1, 2); the rest see (0, -2)
    np.testing.assert_array_equal(neighbors[0, 0], [[0.0, 3.0, 3.0], [0.0, 3.0, 3.0]])
    np.testing.assert_array_equal(neighbors[0, 1], [[-2.0, 0.0, 0.0], [-2.0, 0.0, 0.0]])


def test_interleaved_gradient_noise_by_hand():
    noise = reference.interleaved_gradient_noise(2, 3)
    frac = lambda v: v - math.floor(v)  # noqa: E731
    for i in range(2):
        for j in range(3):
            assert noise[i, j] == frac(52.9829189 * frac(0.06711056 * j + 0.00583715 * i))
    assert noise[0, 0] == 0.0


@pytest.mark.parametrize(
    "call,exception,pattern",
    [
        (lambda: checks.require_odd_int("samples", 4), ValueError, r"samples must be an odd integer >= 1, got 4"),
        (lambda: checks.require_odd_int("samples", 3.0), TypeError, r"samples must be an odd integer >= 1, got 3.0"),
        (lambda: checks.require_choice("sampling", "linear", ("nearest", "bilinear")), ValueError, r"sampling must be one of 'nearest', 'bilinear'; got 'linear'"),
        (lambda: checks.require_image("color", (3, 4, 4)), ValueError, r"color must be a 4-d \(B, C, H, W\) array, got shape \(3, 4, 4\)"),
        (lambda: checks.require_same_batch_and_size("color", (2, 3, 4, 4), [("depth", (2, 1, 4, 5))]), ValueError, r"depth must match color in batch and size \(B=2, H=4, W=4\), got shape \(2, 1, 4, 5\)"),
        (lambda: checks.require_positive_number("max_radius", float("inf")) and checks.require_positive_number("x", -1), ValueError, r"x must be > 0, got -1"),
        (lambda: reference.tile_max(np.zeros((1, 2, 2, 2)), 0), ValueError, r"tile must be an integer >= 1, got 0"),
    ],
)
def test_shared_checks_name_the_argument(call, exception, pattern):
    with pytest.raises(exception, match=pattern):
        call()
