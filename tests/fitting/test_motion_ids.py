"""velocity_from_motion_ids (seed 001's vector motion IDs): values by hand, the pinhole projection
against projecting the two end points, palette gradients, and bad input in both backends."""

from __future__ import annotations

import numpy as np
import pytest

from diffblur import reference


def _ids(backend, values):
    return backend.array(np.asarray(values), "int64")


def test_image_palette_values_by_hand(backend):
    ids = _ids(backend, [[[[0, 2], [1, 2]]]])
    palette = backend.array([[[0.5, 0.0], [-1.0, 2.0], [3.0, 4.0]]])
    out = backend.numpy(backend.ops.velocity_from_motion_ids(ids, palette))
    np.testing.assert_array_equal(out[0, 0], [[0.5, 3.0], [-1.0, 3.0]])
    np.testing.assert_array_equal(out[0, 1], [[0.0, 4.0], [2.0, 4.0]])


def test_world_palette_is_the_half_spread_of_the_projected_end_points(backend):
    """Unproject each pixel at its depth, move it by -V and +V, project both with the pinhole:
    half their difference is the velocity (computed here without the closed form)."""
    rng = np.random.default_rng(11)
    height, width, focal, center = 5, 7, 9.0, (3.2, 1.7)
    ids = rng.integers(0, 3, size=(1, 1, height, width))
    palette = rng.normal(size=(1, 3, 3)) * [1.0, 1.0, 0.5]
    depth = rng.uniform(2.0, 3.0, size=(1, 1, height, width))
    out = backend.numpy(
        backend.ops.velocity_from_motion_ids(_ids(backend, ids), backend.array(palette), depth=backend.array(depth), focal=focal, principal_point=center)
    )
    for i in range(height):
        for j in range(width):
            z = depth[0, 0, i, j]
            point = np.array([(j - center[0]) * z / focal, (i - center[1]) * z / focal, z])
            v = palette[0, ids[0, 0, i, j]]
            ends = [point + s * v for s in (-1.0, 1.0)]
            pixels = [np.array([center[0] + focal * p[0] / p[2], center[1] + focal * p[1] / p[2]]) for p in ends]
            np.testing.assert_allclose(out[0, :, i, j], 0.5 * (pixels[1] - pixels[0]), rtol=1e-12, atol=1e-12)


def test_palette_gradient_sums_the_pixels_of_each_id(backend):
    """d(sum of channel x)/d palette[k, 0] is the number of pixels with ID k; an unused ID gets 0."""
    ids = np.array([[[[0, 0, 1], [1, 0, 3]]]])
    (grad,) = backend.grad(lambda p: backend.ops.velocity_from_motion_ids(_ids(backend, ids), p)[:, 0], backend.array(np.ones((1, 4, 2))))
    np.testing.assert_array_equal(grad[0, :, 0], [3, 2, 0, 1])
    np.testing.assert_array_equal(grad[0, :, 1], [0, 0, 0, 0])


def test_bad_input(backend):
    op = backend.ops.velocity_from_motion_ids
    ids = _ids(backend, [[[[0, 1]]]])
    palette = backend.array(np.zeros((1, 2, 2)))
    with pytest.raises(TypeError, match="ids must have an integer dtype"):
        op(backend.array([[[[0.0, 1.0]]]]), palette)
    with pytest.raises(ValueError, match=r"ids must index the palette: every value in \[0, 1\]"):
        op(_ids(backend, [[[[0, 2]]]]), palette)
    with pytest.raises(ValueError, match=r"palette must be \(B, K, 2\)"):
        op(ids, backend.array(np.zeros((1, 2, 4))))
    with pytest.raises(ValueError, match="palette must have the batch size of ids"):
        op(ids, backend.array(np.zeros((2, 2, 2))))
    world = backend.array(np.array([[[0.0, 0.0, 0.5], [0.0, 0.0, 2.5]]]))
    depth = backend.array(np.full((1, 1, 1, 2), 2.0))
    with pytest.raises(ValueError, match="needs focal"):
        op(ids, world, depth=depth)
    with pytest.raises(ValueError, match="needs depth"):
        op(ids, world, focal=5.0)
    with pytest.raises(ValueError, match=r"\|Vz\| < depth"):
        op(ids, world, depth=depth, focal=5.0)
    with pytest.raises(ValueError, match="apply to a .* palette of world velocities"):
        op(ids, palette, focal=5.0)


def test_reference_matches_hand_values():
    out = reference.velocity_from_motion_ids(np.array([[[[1, 0]]]]), np.array([[[1.0, 2.0], [-3.0, 0.25]]]))
    np.testing.assert_array_equal(out[0, :, 0], [[-3.0, 1.0], [0.25, 2.0]])


def test_jax_range_check_under_jit():
    import jax
    import jax.numpy as jnp

    import jax_impl

    fn = jax.jit(jax_impl.velocity_from_motion_ids)
    # Raised when the computation runs, the library's message first.
    with pytest.raises(jax.errors.JaxRuntimeError, match="^INVALID_ARGUMENT: ids must index the palette"):
        fn(jnp.array([[[[0, 5]]]]), jnp.zeros((1, 2, 2))).block_until_ready()
