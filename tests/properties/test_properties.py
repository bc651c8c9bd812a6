"""Property-based tests (hypothesis) of every op in `ops.OPS`, in both frameworks.

Each test runs on the entries that declare its property. The exact properties run in float64;
finiteness runs in float32 (where overflow and underflow come first) at every extreme of the
examples: velocities 0, 1e-8 and 1e4 px (and a mix per pixel), tied depths, a soft depth band
of 1e-9. Explicit @example rows make sure each extreme runs whatever hypothesis draws.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from tests.properties.ops import DEPTHS, EXTENTS, OPS, SPEEDS, Example
from tests.properties.runner import forward, forward_and_grads

examples = st.builds(
    Example,
    seed=st.integers(0, 2**32 - 1),
    speed=st.sampled_from([*SPEEDS, "mixed"]),
    depth=st.sampled_from(DEPTHS),
    extent=st.sampled_from(EXTENTS),
)
EXTREMES = [
    Example(seed=1, speed="huge", depth="tied", extent=1e-9),
    Example(seed=2, speed="tiny", depth="layers", extent=1e-9),
    Example(seed=3, speed="zero", depth="tied", extent=0.1),
    Example(seed=4, speed="mixed", depth="layers", extent=1e-9),
]


def with_extremes(**others):
    """Add each of EXTREMES as an explicit example (with `others` for the test's other arguments)."""

    def decorate(test):
        for case in reversed(EXTREMES):
            test = example(ex=case, **others)(test)
        return test

    return decorate


def cases(attribute):
    """(op, backend) pairs of the entries that declare `attribute`, with readable ids."""
    chosen = [(op, b) for op in OPS if getattr(op, attribute) not in (None, False) for b in op.backends]
    return pytest.mark.parametrize("op,backend", chosen, ids=[f"{op.name}-{b}" for op, b in chosen])


#: The soft depth band of the finiteness test, for the ops that take a number (soft_depth_compare
#: takes an array and draws EXTENTS). The other tests keep the default, 0.1: JAX compiles each op
#: once per band and dtype.
TINY_EXTENT = 1e-9


def assert_close(actual, expected, atol, what):
    actual, expected = np.broadcast_arrays(actual, expected)
    assert np.all(np.isfinite(actual)), f"{what}: non-finite output"
    error = np.abs(actual - expected)
    worst = np.unravel_index(np.argmax(error), error.shape)
    assert error[worst] <= atol, f"{what}: off by {error[worst]:.3g} at {worst} (tolerance {atol:g})"


@cases("bounds")
@with_extremes()
@given(ex=examples)
def test_output_within_bounds(op, backend, ex):
    """A blur's output is a convex combination of input colours: per image and channel within
    [min, max] of the input; the classifiers stay in [0, 1]; vectors are never longer than given."""
    inputs = op.make(ex)
    out = forward(op, backend, inputs)
    low, high = op.bounds(inputs)
    assert np.all(np.isfinite(out))
    bounds = np.abs(np.concatenate([np.ravel(low), np.ravel(high)]))
    slack = 1e-12 * max(1.0, float(np.max(bounds[np.isfinite(bounds)])))
    assert np.all(out >= np.asarray(low) - slack), f"below {low}: min {out.min()}"
    assert np.all(out <= np.asarray(high) + slack), f"above {high}: max {out.max()}"


@cases("constant")
@with_extremes(level=0.37)
@given(ex=examples, level=st.sampled_from([0.0, 0.37, 1.0, 1e3]))
def test_constant_image_stays_constant(op, backend, ex, level):
    inputs = op.make(ex)
    inputs["color"] = np.full_like(inputs["color"], level)
    out = forward(op, backend, inputs)
    assert_close(out, level, 1e-12 * max(1.0, level), "constant image")


@cases("identity")
@with_extremes()
@given(ex=examples)
def test_zero_motion_is_the_identity(op, backend, ex):
    inputs = op.make(ex)
    inputs[op.motion] = np.zeros_like(inputs[op.motion])
    out = forward(op, backend, inputs)
    assert_close(out, op.identity(inputs), 1e-12, "zero motion")


@cases("parity")
@with_extremes()
@given(ex=examples)
def test_negated_motion(op, backend, ex):
    """With a symmetric shutter v and -v give the same image; vector ops are odd in the motion."""
    inputs = op.make(ex)
    out = forward(op, backend, inputs)
    negated = forward(op, backend, {**inputs, op.motion: -inputs[op.motion]})
    # Tap order differs (the sums are the same terms added in another order): a few ulps.
    assert_close(negated, op.parity * out, 1e-10 * max(1.0, float(np.abs(out).max())), "negated motion")


@cases("shift")
@with_extremes(rows=1, columns=2)
@given(ex=examples, rows=st.integers(0, 2), columns=st.integers(0, 2))
def test_translation_commutes_away_from_the_borders(op, backend, ex, rows, columns):
    """A global velocity (one per image) commutes with translating the image, depth and motion."""
    ex = Example(ex.seed, ex.speed, ex.depth, ex.extent, global_motion=True)
    inputs = op.make(ex)
    dy, dx = rows * op.shift, columns * op.shift
    moved = {k: np.roll(v, (dy, dx), axis=(2, 3)) if k in op.spatial else v for k, v in inputs.items()}
    out = forward(op, backend, inputs)
    out_moved = forward(op, backend, moved)
    s = op.output_stride
    expected = np.roll(out, (dy // s, dx // s), axis=(2, 3))
    m = op.margin(inputs)
    height, width = out.shape[2:]
    window = (slice(None), slice(None), slice(dy // s + m, height - m), slice(dx // s + m, width - m))
    assert out[window].size > 0, "the translation test needs a bigger image"
    # Positions x + v t are rounded at other x: a few ulps.
    assert_close(out_moved[window], expected[window], 1e-10 * max(1.0, float(np.abs(out).max())), f"shift ({dy}, {dx})")


@cases("name")
@with_extremes()
@given(ex=examples)
def test_outputs_and_gradients_are_finite_in_float32(op, backend, ex):
    inputs = op.make(ex)
    out, grads = forward_and_grads(op, backend, inputs, dtype="float32", extent=TINY_EXTENT if op.uses_extent else 0.1)
    assert np.all(np.isfinite(out)), "non-finite output"
    for name, grad in grads.items():
        assert grad.shape == inputs[name].shape
        assert np.all(np.isfinite(grad)), f"non-finite gradient w.r.t. {name}"
