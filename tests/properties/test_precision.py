"""float16 and bfloat16 inputs give finite outputs close to float32; float64 is kept throughout.

The inputs are rounded to the half type first and the float32 result is computed from those
rounded values, so the error measured is the op's own arithmetic, not the rounding of its inputs.
Errors are relative to the output's scale (max |float32 output|, at least 1). Tolerances
(measured errors in the report): see TOLERANCE.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tests.properties.ops import OPS, Example
from tests.properties.runner import forward, forward_and_grads

#: Largest error allowed, relative to the output's scale, per half type: about twice the worst
#: measured on these 20 x 21 images (float16: 6.2e-3, warp_blend; bfloat16: 5.5e-2, the layer's
#: warp_blend): rounding of positions and of a few taps summed in the half type (float16 has 11
#: significant bits, bfloat16 8). Wider images are much worse: positions are held in the input's
#: type (test_half_precision_wide_images_stay_finite; the README says to blur in float32).
TOLERANCE = {"float16": 1.5e-2, "bfloat16": 1.2e-1}

HALF_OPS = [op for op in OPS if op.differentiable]
#: Speeds 0, 1e-8, 0.3, 2.5 and 1e4 px times 1 to 1.5 (no two alike: a tie between vectors of one
#: length is decided by rounding, so tile_max could pick another of them in each type), with
#: depths all different, or in layers with ties.
PRECISION_EXAMPLES = {
    "random-depths": Example(seed=7, speed="spread", depth="random", extent=0.1),
    "tied-depths": Example(seed=8, speed="spread", depth="layers", extent=0.1),
}


def rounded_to(inputs: dict[str, np.ndarray], dtype: str) -> dict[str, np.ndarray]:
    """Inputs rounded to `dtype` and back to float64 (integer inputs unchanged)."""
    out = {}
    for name, value in inputs.items():
        if np.issubdtype(value.dtype, np.integer):
            out[name] = value
        else:
            out[name] = torch.tensor(value).to(getattr(torch, dtype)).double().numpy()
    return out


def half_error(op, backend: str, dtype: str, example: str) -> float:
    inputs = rounded_to(op.make(PRECISION_EXAMPLES[example]), dtype)
    reference = forward(op, "torch", inputs, dtype="float32")
    if backend == "jax" and dtype == "bfloat16":
        # Forward only (a quarter of the compile time). Overflow is float16's risk (bfloat16 has
        # float32's range); PyTorch checks bfloat16 gradients on the same formulas.
        out, grads = forward(op, backend, inputs, dtype=dtype), {}
    else:
        out, grads = forward_and_grads(op, backend, inputs, dtype=dtype)
    assert np.all(np.isfinite(out)), f"{op.name} {dtype}: non-finite output"
    for name, grad in grads.items():
        assert np.all(np.isfinite(grad)), f"{op.name} {dtype}: non-finite gradient w.r.t. {name}"
    scale = max(1.0, float(np.abs(reference).max()))
    return float(np.abs(out - reference).max()) / scale


CASES = [(op, backend) for op in HALF_OPS for backend in op.backends]


@pytest.mark.parametrize("example", list(PRECISION_EXAMPLES))
@pytest.mark.parametrize("dtype", list(TOLERANCE))
@pytest.mark.parametrize("op,backend", CASES, ids=[f"{op.name}-{backend}" for op, backend in CASES])
def test_half_precision_is_finite_and_close_to_float32(op, backend, dtype, example):
    error = half_error(op, backend, dtype, example)
    assert error <= TOLERANCE[dtype], f"{op.name} {backend} {dtype} {example}: error {error:.3g} > {TOLERANCE[dtype]}"


WIDE = (1, 2, 2, 300)  # wider than 256 px: the border W - 1 = 299 rounds to 300 in bfloat16
# JAX: the two code paths (bilinear reads, which reconstruct and warp_blend share, and splats).
WIDE_CASES = [(n, "torch") for n in ("gather_blur", "reconstruct", "bezier_scatter", "warp_blend")] + [(n, "jax") for n in ("gather_blur", "bezier_scatter")]


@pytest.mark.parametrize("name,backend", WIDE_CASES, ids=[f"{n}-{b}" for n, b in WIDE_CASES])
def test_half_precision_wide_images_stay_finite(name, backend):
    """Positions are held in the input's type, so in bfloat16 beyond 256 px the border pixel's
    coordinate rounds past the image: the reads and splats must stay inside it (they indexed out of
    bounds: an IndexError in PyTorch, -inf in JAX). Not close to float32 there (see the README)."""
    op = next(op for op in OPS if op.name == name)
    rng = np.random.default_rng(4)
    b, c, h, w = WIDE
    inputs = {"color": rng.random(WIDE), "velocity": rng.normal(size=(b, 2, h, w)) * 3.0, "depth": rng.uniform(1.0, 2.0, size=(b, 1, h, w))}
    out = forward(op, backend, rounded_to(inputs, "bfloat16"), dtype="bfloat16")
    assert out.shape == WIDE and np.all(np.isfinite(out))
