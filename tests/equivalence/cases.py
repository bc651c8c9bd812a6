"""The ops under test, one `Case` each, for the equivalence harness.

A case builds seeded float64 NumPy inputs and names the NumPy reference, the PyTorch op and the
JAX op that must agree on them. Later ops plug in by appending a Case to CASES.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

import jax_impl
import torch_impl
from diffblur import reference
from diffblur.shutters import Tukey


@dataclass(frozen=True)
class Case:
    name: str
    #: Builds the inputs (float64 arrays) from a seeded generator.
    make_inputs: Callable[[np.random.Generator], dict[str, np.ndarray]]
    #: The three implementations, each called as fn(**inputs) with its own arrays.
    reference: Callable[..., np.ndarray]
    torch_op: Callable
    jax_op: Callable
    #: Inputs to differentiate with respect to.
    differentiable: tuple[str, ...]
    #: Differentiable inputs on which the op acts element by element (so a per-element finite
    #: difference can say where the gradient must be nonzero).
    elementwise: tuple[str, ...] = field(default=())
    #: True where the inputs sit on kinks on purpose (tied depths): there a finite difference
    #: averages two one-sided derivatives, so only the frameworks are compared with each other.
    on_kinks: bool = False

    def inputs(self) -> dict[str, np.ndarray]:
        return self.make_inputs(np.random.default_rng(zlib.crc32(self.name.encode())))


def _depth_pair(rng):
    z_a = rng.uniform(1.0, 3.0, size=(2, 1, 5, 6))
    # Spread z_b across the whole soft band and both clamps.
    return {"z_a": z_a, "z_b": z_a + rng.uniform(-0.5, 1.0, size=z_a.shape), "extent": np.array(0.6)}


def _distance_speed(rng, *, around_speed: bool):
    speed = rng.uniform(0.3, 4.0, size=(2, 1, 5, 6))
    if around_speed:  # the cylinder's smoothstep band is 0.95 .. 1.05 times the speed
        distance = speed * rng.uniform(0.9, 1.1, size=speed.shape)
    else:
        distance = rng.uniform(0.0, 4.5, size=speed.shape)
    return {"distance": distance, "speed": speed}


def _displacement(rng, batch=2):
    # Lengths of q = displacement / 2 from ~0.1 px to ~25 px: below min_radius, inside, beyond max_radius.
    d = rng.normal(size=(batch, 2, 5, 7))
    d *= np.exp(rng.uniform(np.log(0.2), np.log(50.0), size=(batch, 1, 5, 7))) / np.linalg.norm(d, axis=1, keepdims=True)
    return d


CASES = [
    Case(
        "soft_depth_compare",
        _depth_pair,
        reference.soft_depth_compare,
        torch_impl.soft_depth_compare,
        jax_impl.soft_depth_compare,
        differentiable=("z_a", "z_b", "extent"),
        elementwise=("z_a", "z_b"),
    ),
    Case(
        "cone",
        lambda rng: _distance_speed(rng, around_speed=False),
        reference.cone,
        torch_impl.cone,
        jax_impl.cone,
        differentiable=("distance", "speed"),
        elementwise=("distance", "speed"),
    ),
    Case(
        "cylinder",
        lambda rng: _distance_speed(rng, around_speed=True),
        reference.cylinder,
        torch_impl.cylinder,
        jax_impl.cylinder,
        differentiable=("distance", "speed"),
        elementwise=("distance", "speed"),
    ),
    Case(
        "safe_length",
        lambda rng: {"vector": rng.normal(size=(2, 2, 4, 5)) * 3.0},
        reference.safe_length,
        torch_impl.safe_length,
        jax_impl.safe_length,
        differentiable=("vector",),
    ),
    Case(
        "velocity_from_motion",
        lambda rng: {"displacement": _displacement(rng), "exposure": np.array(0.8)},
        lambda **a: reference.velocity_from_motion(**a, max_radius=8.0, min_radius=0.5),
        lambda **a: torch_impl.velocity_from_motion(**a, max_radius=8.0, min_radius=0.5),
        lambda **a: jax_impl.velocity_from_motion(**a, max_radius=8.0, min_radius=0.5),
        differentiable=("displacement", "exposure"),
    ),
    Case(
        "velocity_from_motion_per_image_exposure",
        lambda rng: {"displacement": _displacement(rng, batch=3), "exposure": rng.uniform(0.3, 1.5, size=(3,))},
        lambda **a: reference.velocity_from_motion(**a, max_radius=20.0),
        lambda **a: torch_impl.velocity_from_motion(**a, max_radius=20.0),
        lambda **a: jax_impl.velocity_from_motion(**a, max_radius=20.0),
        differentiable=("displacement", "exposure"),
    ),
    Case(
        "tile_max",
        lambda rng: {"velocity": rng.normal(size=(2, 2, 7, 11)) * 4.0},
        lambda **a: reference.tile_max(**a, tile=3),
        lambda **a: torch_impl.tile_max(**a, tile=3),
        lambda **a: jax_impl.tile_max(**a, tile=3),
        differentiable=("velocity",),
    ),
    Case(
        "neighbor_max",
        lambda rng: {"tile_velocity": rng.normal(size=(2, 2, 4, 5)) * 4.0},
        reference.neighbor_max,
        torch_impl.neighbor_max,
        jax_impl.neighbor_max,
        differentiable=("tile_velocity",),
    ),
]



def _color_velocity(rng):
    return {"color": rng.random((2, 3, 6, 7)), "velocity": rng.normal(size=(2, 2, 6, 7)) * 2.5}


def _gather_case(name, sampling, shutter="box", differentiable=("color", "velocity")):
    options = dict(samples=5, sampling=sampling, shutter=shutter)
    return Case(
        name,
        _color_velocity,
        lambda **a: reference.gather_blur(**a, **options),
        lambda **a: torch_impl.gather_blur(**a, **options),
        lambda **a: jax_impl.gather_blur(**a, **options),
        differentiable=differentiable,
    )


CASES += [
    _gather_case("gather_blur_bilinear", "bilinear"),
    _gather_case("gather_blur_nearest", "nearest", differentiable=("color",)),
    _gather_case("gather_blur_tent", "bilinear", shutter="tent"),
    Case(
        "gather_blur_tukey_shape",
        lambda rng: dict(_color_velocity(rng), taper=np.array(0.4)),
        lambda taper, **a: reference.gather_blur(**a, samples=5, shutter=Tukey(taper)),
        lambda taper, **a: torch_impl.gather_blur(**a, samples=5, shutter=Tukey(taper)),
        lambda taper, **a: jax_impl.gather_blur(**a, samples=5, shutter=Tukey(taper)),
        differentiable=("velocity", "taper"),
    ),
]


def _reconstruct_inputs(rng, *, tied=False):
    depth = rng.uniform(1.0, 1.3, size=(2, 1, 8, 9))
    # A nearer object, so all three cases of the filter occur; flat (tied depths) or not.
    depth[:, :, 2:5, 3:7] = 0.9 if tied else rng.uniform(0.85, 0.95, size=(2, 1, 3, 4))
    return {"color": rng.random((2, 3, 8, 9)), "velocity": rng.normal(size=(2, 2, 8, 9)) * 2.5, "depth": depth}


def _reconstruct_case(name, differentiable=("color", "velocity", "depth"), tied=False, **options):
    options = dict(samples=5, max_radius=4.0, **options)
    return Case(
        name,
        lambda rng: _reconstruct_inputs(rng, tied=tied),
        lambda **a: reference.reconstruct(**a, **options),
        lambda **a: torch_impl.reconstruct(**a, **options),
        lambda **a: jax_impl.reconstruct(**a, **options),
        differentiable=differentiable,
        on_kinks=tied,
    )


CASES += [
    _reconstruct_case("reconstruct_bilinear"),
    _reconstruct_case("reconstruct_bilinear_tied_depths", tied=True),
    _reconstruct_case("reconstruct_nearest_tied_depths", tied=True, sampling="nearest"),
    _reconstruct_case("reconstruct_bilinear_no_jitter", jitter="none"),
    _reconstruct_case("reconstruct_nearest", sampling="nearest"),
    _reconstruct_case("reconstruct_nearest_no_jitter_no_early_out", sampling="nearest", jitter="none", early_out=False),
    _reconstruct_case("reconstruct_tent_shutter", shutter="tent"),
    _reconstruct_case("reconstruct_own_directions", directions="neighbor_and_own"),
    Case(
        "reconstruct_tukey_shape",
        lambda rng: dict(_reconstruct_inputs(rng), taper=np.array(0.6)),
        lambda taper, **a: reference.reconstruct(**a, samples=5, max_radius=4.0, shutter=Tukey(taper)),
        lambda taper, **a: torch_impl.reconstruct(**a, samples=5, max_radius=4.0, shutter=Tukey(taper)),
        lambda taper, **a: jax_impl.reconstruct(**a, samples=5, max_radius=4.0, shutter=Tukey(taper)),
        differentiable=("velocity", "taper"),
    ),
]

# Ops developed in their own modules register their cases there.
from tests.equivalence.cases_scatter import CASES as _SCATTER_CASES  # noqa: E402

CASES += _SCATTER_CASES

from tests.equivalence.cases_motion_ids import CASES as _MOTION_ID_CASES  # noqa: E402

CASES += _MOTION_ID_CASES

from tests.equivalence.cases_warp import CASES as _WARP_CASES  # noqa: E402

CASES += _WARP_CASES

from tests.equivalence.cases_tiles import CASES as _TILE_CASES  # noqa: E402

CASES += _TILE_CASES
