"""Equivalence cases of the tile options of `gather_blur` and `reconstruct`: tiled adaptive sampling
(seed 001, `adaptive=`) and the pyramid for large motion (`pyramid=`); `cases.CASES` includes them.

The velocity is zero on part of the image (still tiles), slow in another (a small class) and fast in
a third (the full rate), with speeds away from the class boundaries so that finite differences do
not cross them."""

from __future__ import annotations

import numpy as np

import jax_impl
import torch_impl
from diffblur import reference
from tests.equivalence.cases import Case


def _gather_inputs(rng):
    # 16 x 16 tiles on 17 x 17: (0, 0) fast (|V| ~ 3 px: 7 taps), (1, 0) slow (|V| = 0.8: 3 taps), the rest still.
    velocity = np.zeros((1, 2, 17, 17))
    velocity[:, :, 2:9, 3:10] = rng.normal(size=(1, 2, 7, 7)) + np.array([2.5, 1.0])[None, :, None, None]
    direction = rng.normal(size=(1, 2, 1, 5))
    velocity[:, :, 16:17, 4:9] = 0.8 * direction / np.linalg.norm(direction, axis=1, keepdims=True)
    return {"color": rng.random((1, 1, 17, 17)), "velocity": velocity}


def _reconstruct_inputs(rng):
    # 3 x 3 tiles on 6 x 15: fast motion in tile (0, 0), slow in tile (1, 4); tiles (0, 2) and (1, 2)
    # have still neighbourhoods.
    velocity = np.zeros((1, 2, 6, 15))
    velocity[:, :, 0:3, 0:3] = rng.normal(size=(1, 2, 3, 3)) * 0.5 + np.array([2.0, -1.5])[None, :, None, None]
    velocity[:, :, 3:6, 12:15] = rng.normal(size=(1, 2, 3, 3)) * 0.2 + np.array([0.9, 0.0])[None, :, None, None]
    depth = rng.uniform(1.0, 1.3, size=(1, 1, 6, 15))
    depth[:, :, 0:2, 0:2] = rng.uniform(0.85, 0.95, size=(1, 1, 2, 2))
    return {"color": rng.random((1, 1, 6, 15)), "velocity": velocity, "depth": depth}


def _case(name, op_name, make_inputs, differentiable, **options):
    def build(module):
        op = getattr(module, op_name)
        return lambda **a: op(**a, **options)

    return Case(name, make_inputs, build(reference), build(torch_impl), build(jax_impl), differentiable=differentiable)


CASES = [
    _case("gather_blur_adaptive", "gather_blur", _gather_inputs, ("velocity",), samples=7, adaptive=(3, 7)),
    _case("reconstruct_adaptive", "reconstruct", _reconstruct_inputs, ("velocity", "depth"), samples=7, max_radius=3.0, adaptive=True),
    _case(
        "reconstruct_adaptive_nearest_early_out",
        "reconstruct",
        _reconstruct_inputs,
        ("color",),
        samples=7,
        max_radius=3.0,
        adaptive=(3,),
        sampling="nearest",
        early_out=True,
    ),
]


def _fast(rng):
    # Taps 2 |V| / S apart with |V| ~ 4 px and S = 3 or 5: most pixels read levels 0 to 2.
    return {
        "color": rng.random((1, 1, 5, 6)),
        "velocity": rng.normal(size=(1, 2, 5, 6)) * 4.0,
        "depth": rng.uniform(1.0, 1.3, size=(1, 1, 5, 6)),
    }


def _without_depth(rng):
    inputs = _fast(rng)
    del inputs["depth"]
    return inputs


CASES += [
    _case("gather_blur_pyramid", "gather_blur", _without_depth, ("color", "velocity"), samples=3, sampling="pyramid"),
    _case("reconstruct_pyramid", "reconstruct", _fast, ("velocity",), samples=5, max_radius=4.0, sampling="pyramid"),
]
