"""Equivalence cases of the Bezier scatter (seed 003); `cases.CASES` includes them.

Seven cases cover degrees 1, 2 and 3, the arc, both normalisations, both fills and the background, the
three composites ("instants", the default; the cubic's "sum"; one quadratic's "layers"), a shutter
shape parameter and the soft depth extent, with small
images (6 x 7) and 5 points per curve so that the full-Jacobian gradcheck and the compilations stay
cheap.
Offsets are random and never exactly 0 (a still pixel is skipped, a kink the finite differences of
the harness would straddle; the extremes tests cover it), except in the still-fill case, which has
still pixels and differentiates only colour and depth.
"""

from __future__ import annotations

import numpy as np

import jax_impl
import torch_impl
from diffblur import reference
from diffblur.shutters import LinearRamp
from tests.equivalence.cases import Case

SHAPE = (1, 2, 6, 7)
OPTIONS = dict(samples=5, soft_z_extent=0.3)


def _scene(rng, *, spread=1.5, batch=1):
    _, channels, height, width = SHAPE
    return {
        "color": rng.random((batch, channels, height, width)),
        "depth": rng.uniform(1.0, 2.0, size=(batch, 1, height, width)),
        "offset_prev": rng.normal(size=(batch, 2, height, width)) * spread,
        "offset_next": rng.normal(size=(batch, 2, height, width)) * spread,
    }


def _with_still_pixels(rng):
    inputs = _scene(rng)
    still = rng.random((1, 1, *SHAPE[2:])) < 0.4
    for name in ("offset_prev", "offset_next"):
        inputs[name] = np.where(still, 0.0, inputs[name])
    return inputs


def _cubic(rng):
    inputs = _scene(rng)
    inputs["offset_mid_prev"] = rng.normal(size=inputs["offset_prev"].shape)
    return inputs


def _arc_with_background(rng):
    inputs = _scene(rng)
    batch, _, height, width = SHAPE
    del inputs["offset_prev"], inputs["offset_next"]
    inputs["background"] = rng.random(SHAPE)
    inputs["arc_center"] = rng.uniform(0.0, [width - 1.0, height - 1.0], size=(batch, height, width, 2)).transpose(0, 3, 1, 2)
    inputs["arc_angle"] = rng.normal(size=(batch, 1, height, width)) * 0.4
    return inputs


def _with_slope_and_extent(rng):
    inputs = _scene(rng)
    inputs["slope"] = np.array(0.6)
    inputs["soft_z_extent"] = np.array(0.3)
    return inputs


def _arc_call(op, options):
    def call(color, depth, arc_center, arc_angle, background, **extra):
        return op(color, depth, None, None, arc_center=arc_center, arc_angle=arc_angle, fill=background, **options, **extra)

    return call


def _case(name, make_inputs, differentiable, call=None, **options):
    options = {**OPTIONS, **options}

    def build(op):
        if call is not None:
            return call(op, options)
        return lambda **a: op(**a, **options)

    return Case(
        name,
        make_inputs,
        build(reference.bezier_scatter),
        build(torch_impl.bezier_scatter),
        build(jax_impl.bezier_scatter),
        differentiable=differentiable,
    )


def _shaped(op):
    """The scatter with an asymmetric shutter whose slope, and the soft depth extent, are inputs."""

    def call(slope, soft_z_extent, **a):
        return op(**a, samples=5, shutter=LinearRamp(slope), soft_z_extent=soft_z_extent)

    return call


_FIELDS = ("color", "depth", "offset_prev", "offset_next")

CASES = [
    _case("bezier_scatter_quadratic_batch", lambda rng: _scene(rng, batch=2), _FIELDS),
    _case("bezier_scatter_linear_paper", _scene, _FIELDS, degree=1, normalization="paper", background_weight=2.0, shutter="trapezoid", fill="color"),
    _case("bezier_scatter_still_fill", _with_still_pixels, ("color", "depth")),
    _case("bezier_scatter_layers", _with_still_pixels, ("color", "depth"), composite="layers"),
    _case("bezier_scatter_cubic", _cubic, (*_FIELDS, "offset_mid_prev"), degree=3, shutter="tent", composite="sum"),
    _case(
        "bezier_scatter_arc_background",
        _arc_with_background,
        ("color", "depth", "arc_center", "arc_angle", "background"),
        call=_arc_call,
        shutter="box",
    ),
    Case(
        "bezier_scatter_shutter_slope_and_extent",
        _with_slope_and_extent,
        _shaped(reference.bezier_scatter),
        _shaped(torch_impl.bezier_scatter),
        _shaped(jax_impl.bezier_scatter),
        differentiable=("depth", "offset_next", "slope", "soft_z_extent"),
    ),
]
