"""Bad input raises ValueError or TypeError naming the argument, the same way in both backends."""

from __future__ import annotations

import numpy as np
import pytest


def field(shape, dtype="float64", backend=None):
    return backend.array(np.ones(shape), dtype)


BAD_CALLS = [
    # (id, call(ops, backend), exception, message pattern)
    ("velocity rank 3", lambda o, b: o.tile_max(field((2, 7, 11), backend=b), 4), ValueError, r"velocity must be a 4-d \(B, 2, H, W\) array, got shape \(2, 7, 11\)"),
    ("velocity 3 channels", lambda o, b: o.tile_max(field((1, 3, 7, 11), backend=b), 4), ValueError, r"velocity must have 2 channel\(s\).*got shape \(1, 3, 7, 11\)"),
    ("velocity empty", lambda o, b: o.tile_max(field((1, 2, 0, 11), backend=b), 4), ValueError, r"velocity must not be empty"),
    ("tile 0", lambda o, b: o.tile_max(field((1, 2, 4, 4), backend=b), 0), ValueError, r"tile must be an integer >= 1, got 0"),
    ("tile float", lambda o, b: o.tile_max(field((1, 2, 4, 4), backend=b), 2.5), TypeError, r"tile must be an integer >= 1, got 2.5"),
    ("tile bool", lambda o, b: o.tile_max(field((1, 2, 4, 4), backend=b), True), TypeError, r"tile must be an integer"),
    ("integer velocity", lambda o, b: o.tile_max(b.array(np.ones((1, 2, 4, 4)), "int32"), 2), TypeError, r"velocity must have a floating dtype.*int32"),
    ("tile_velocity 1 channel", lambda o, b: o.neighbor_max(field((1, 1, 4, 4), backend=b)), ValueError, r"tile_velocity must have 2 channel"),
    ("z shapes differ", lambda o, b: o.soft_depth_compare(field((1, 1, 4, 4), backend=b), field((1, 1, 4, 5), backend=b), 0.1), ValueError, r"z_b must have the shape of z_a \(1, 1, 4, 4\), got \(1, 1, 4, 5\)"),
    ("z dtypes differ", lambda o, b: o.soft_depth_compare(field((3,), "float32", b), field((3,), "float64", b), 0.1), TypeError, r"z_b must have the dtype of z_a"),
    ("extent 0", lambda o, b: o.soft_depth_compare(field((3,), backend=b), field((3,), backend=b), 0.0), ValueError, r"extent must be > 0, got 0.0"),
    ("extent negative", lambda o, b: o.soft_depth_compare(field((3,), backend=b), field((3,), backend=b), -1), ValueError, r"extent must be > 0, got -1"),
    ("extent NaN", lambda o, b: o.soft_depth_compare(field((3,), backend=b), field((3,), backend=b), float("nan")), ValueError, r"extent must be > 0, got nan"),
    ("extent string", lambda o, b: o.soft_depth_compare(field((3,), backend=b), field((3,), backend=b), "0.1"), TypeError, r"extent must be a real number > 0, got '0.1'"),
    ("extent array negative", lambda o, b: o.soft_depth_compare(field((3,), backend=b), field((3,), backend=b), b.array(-0.5)), ValueError, r"extent must be > 0 everywhere"),
    ("extent array wrong shape", lambda o, b: o.soft_depth_compare(field((3,), backend=b), field((3,), backend=b), field((2,), backend=b)), ValueError, r"extent must have the shape"),
    ("integer depth", lambda o, b: o.soft_depth_compare(b.array([1, 2], "int64"), b.array([1, 2], "int64"), 0.1), TypeError, r"z_a must have a floating dtype"),
    ("speed shape", lambda o, b: o.cone(field((4,), backend=b), field((1, 4), backend=b)), ValueError, r"speed must have the shape of distance"),
    ("cylinder integer", lambda o, b: o.cylinder(b.array([1, 2], "int32"), field((2,), backend=b)), TypeError, r"distance must have a floating dtype"),
    ("not an array", lambda o, b: o.cone([1.0, 2.0], field((2,), backend=b)), TypeError, r"distance must be a (torch.Tensor|jax.Array), got list"),
    ("displacement rank", lambda o, b: o.velocity_from_motion(field((2, 4, 4), backend=b)), ValueError, r"displacement must be a 4-d"),
    ("max_radius 0", lambda o, b: o.velocity_from_motion(field((1, 2, 4, 4), backend=b), max_radius=0.0), ValueError, r"max_radius must be > 0, got 0.0"),
    ("min_radius negative", lambda o, b: o.velocity_from_motion(field((1, 2, 4, 4), backend=b), min_radius=-0.5), ValueError, r"min_radius must be >= 0, got -0.5"),
    ("min above max", lambda o, b: o.velocity_from_motion(field((1, 2, 4, 4), backend=b), min_radius=3.0, max_radius=2.0), ValueError, r"min_radius must be <= max_radius \(2.0\), got 3.0"),
    ("exposure shape", lambda o, b: o.velocity_from_motion(field((2, 2, 4, 4), backend=b), exposure=field((3,), backend=b)), ValueError, r"exposure must be a number, a 0-d .* or a \(B,\) .* with B=2, got shape \(3,\)"),
    ("exposure dtype", lambda o, b: o.velocity_from_motion(field((1, 2, 4, 4), "float32", b), exposure=b.array(1.0, "float64")), TypeError, r"exposure must have the dtype of the input"),
    ("exposure string", lambda o, b: o.velocity_from_motion(field((1, 2, 4, 4), backend=b), exposure="1"), TypeError, r"exposure must be a real number"),
    ("axis out of range", lambda o, b: o.safe_length(field((1, 2, 4, 4), backend=b), axis=4), ValueError, r"axis must be in \[-4, 4\)"),
    ("noise height 0", lambda o, b: o.interleaved_gradient_noise(0, 4), ValueError, r"height must be an integer >= 1, got 0"),
]


@pytest.mark.parametrize("call,exception,pattern", [c[1:] for c in BAD_CALLS], ids=[c[0] for c in BAD_CALLS])
def test_bad_input_raises_naming_the_argument(backend, call, exception, pattern):
    with pytest.raises(exception, match=pattern):
        call(backend.ops, backend)
