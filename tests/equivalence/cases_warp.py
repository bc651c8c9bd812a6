"""Equivalence cases of seed 002's image-warping methods (`accumulate_warps`, `warp_blend`);
`cases.CASES` includes them. Small images (6 x 7), few instants and iterations, so the
full-Jacobian gradcheck and the compilations stay cheap."""

from __future__ import annotations

import numpy as np

import jax_impl
import torch_impl
from diffblur import reference
from diffblur.shutters import Tukey
from tests.equivalence.cases import Case


def _color_velocity(rng, batch=2):
    return {"color": rng.random((batch, 3, 6, 7)), "velocity": rng.normal(size=(batch, 2, 6, 7)) * 2.0}


def _offsets(rng):
    return {
        "color": rng.random((1, 2, 6, 7)),
        "offset_prev": rng.normal(size=(1, 2, 6, 7)) * 1.5,
        "offset_next": rng.normal(size=(1, 2, 6, 7)) * 1.5,
    }


def _case(name, op_name, make_inputs, differentiable, **options):
    def build(module):
        op = getattr(module, op_name)
        return lambda **a: op(**a, **options)

    return Case(name, make_inputs, build(reference), build(torch_impl), build(jax_impl), differentiable=differentiable)


def _with_taper(rng):
    return dict(_color_velocity(rng, batch=1), taper=np.array(0.5))


def _tukey(op):
    return lambda taper, **a: op(**a, instants=4, shutter=Tukey(taper))


CASES = [
    _case("accumulate_warps_velocity", "accumulate_warps", _color_velocity, ("color", "velocity"), instants=4),
    _case("accumulate_warps_nearest", "accumulate_warps", _color_velocity, ("color",), instants=3, sampling="nearest"),
    _case("accumulate_warps_offsets_tent", "accumulate_warps", _offsets, ("color", "offset_prev", "offset_next"), velocity=None, instants=5, shutter="tent"),
    Case(
        "accumulate_warps_tukey_shape",
        _with_taper,
        _tukey(reference.accumulate_warps),
        _tukey(torch_impl.accumulate_warps),
        _tukey(jax_impl.accumulate_warps),
        differentiable=("velocity", "taper"),
    ),
    _case("warp_blend_default", "warp_blend", _color_velocity, ("color", "velocity"), iterations=2),
    _case("warp_blend_ramp_backward", "warp_blend", _color_velocity, ("color", "velocity"), iterations=3, backward_scale=0.4, alpha=(0.5, 0.8)),
    _case("warp_blend_nearest", "warp_blend", _color_velocity, ("color",), iterations=2, sampling="nearest"),
]
