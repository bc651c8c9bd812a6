"""Equivalence cases of vector motion IDs (seed 001); `cases.CASES` includes them.

The harness hands every input over as a floating array of the tested dtype, so the ID map travels
as whole numbers in a float array and each call converts it to integers first.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

import jax_impl
import torch_impl
from diffblur import reference
from tests.equivalence.cases import Case

SHAPE = (2, 1, 5, 6)
PALETTE_SIZE = 4


def _ids(rng):
    return rng.integers(0, PALETTE_SIZE, size=SHAPE).astype(np.float64)


def _image_palette(rng):
    return {"ids": _ids(rng), "palette": rng.normal(size=(SHAPE[0], PALETTE_SIZE, 2)) * 3.0}


def _world_palette(rng):
    palette = rng.normal(size=(SHAPE[0], PALETTE_SIZE, 3))
    palette[..., 2] *= 0.4  # |Vz| well below the depths, so every point stays in front of the camera
    return {"ids": _ids(rng), "palette": palette, "depth": rng.uniform(2.0, 4.0, size=SHAPE)}


WORLD = dict(focal=12.0, principal_point=(2.0, 1.5))

CASES = [
    Case(
        "velocity_from_motion_ids_image",
        _image_palette,
        lambda ids, **a: reference.velocity_from_motion_ids(ids.astype(np.int64), **a),
        lambda ids, **a: torch_impl.velocity_from_motion_ids(ids.long(), **a),
        lambda ids, **a: jax_impl.velocity_from_motion_ids(ids.astype(jnp.int32), **a),
        differentiable=("palette",),
    ),
    Case(
        "velocity_from_motion_ids_world",
        _world_palette,
        lambda ids, **a: reference.velocity_from_motion_ids(ids.astype(np.int64), **a, **WORLD),
        lambda ids, **a: torch_impl.velocity_from_motion_ids(ids.long(), **a, **WORLD),
        lambda ids, **a: jax_impl.velocity_from_motion_ids(ids.astype(jnp.int32), **a, **WORLD),
        differentiable=("palette", "depth"),
    ),
]
