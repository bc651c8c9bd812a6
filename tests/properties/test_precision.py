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

from tests.properties.ops import OPS, OPS_BY_NAME, Example
from tests.properties.runner import forward, forward_and_grads
from tests.tolerances import tolerance

#: Largest error allowed, relative to the output's scale, per half type (tests/tolerances.py, "half";
#: with half-type positions the 300 px wide images were 0.03-0.67 / 0.43-0.82 off).
TOLERANCE = {dtype: tolerance(dtype, "half") for dtype in ("float16", "bfloat16")}

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


WIDE = (1, 2, 4, 300)  # past 256 px, where float16 rounds coordinates to 0.25 px, bfloat16 to 2 px
#: Every method, adaptive included (its tile index and reads), in both frameworks: PyTorch in both
#: half types, JAX in bfloat16 only (the coarser; each dtype costs JAX a compilation). JAX's adaptive
#: runs eagerly, on the compacted pixels (under jit every class runs on every pixel instead).
_WIDE_METHODS = ("gather_blur", "reconstruct", "reconstruct-adaptive", "bezier_scatter", "warp_blend")
WIDE_CASES = [(name, "torch", dtype) for name in _WIDE_METHODS for dtype in TOLERANCE] + [
    (name, "jax-eager" if name.endswith("adaptive") else "jax", "bfloat16") for name in _WIDE_METHODS
]


def _wide_forward(op, backend: str, inputs: dict[str, np.ndarray], dtype: str) -> np.ndarray:
    if backend != "jax-eager":
        return forward(op, backend, inputs, dtype=dtype)
    import jax.numpy as jnp

    import jax_impl

    out = op.call(jax_impl, {n: jnp.asarray(v, dtype=dtype) for n, v in inputs.items()}, 0.1)
    return np.asarray(out.astype(jnp.float32))


@pytest.mark.parametrize("name,backend,dtype", WIDE_CASES, ids=["-".join(case) for case in WIDE_CASES])
def test_half_precision_wide_images_close_to_float32(name, backend, dtype):
    """Positions, tap offsets and interpolation weights are float32 for half inputs, so a 300 px
    wide image in float16 or bfloat16 is as close to float32 as a small one (positions held in the
    half type were 0.03 to 0.67 off in float16, 0.43 to 0.82 in bfloat16, and adaptive reconstruct
    indexed out of bounds in bfloat16). The reference is the same framework's float32 on the same
    rounded inputs (jit-compiled and eager JAX differ by up to 3e-2 on warp_blend in float32 alone;
    eager JAX adaptive is compared with PyTorch's float32, which equals it there)."""
    op = OPS_BY_NAME[name]
    rng = np.random.default_rng(4)
    b, c, h, w = WIDE
    inputs = {"color": rng.random(WIDE), "velocity": rng.normal(size=(b, 2, h, w)) * 3.0, "depth": rng.uniform(1.0, 2.0, size=(b, 1, h, w))}
    inputs = rounded_to(inputs, dtype)
    out = _wide_forward(op, backend, inputs, dtype)
    reference = _wide_forward(op, "torch" if backend == "jax-eager" else backend, inputs, "float32")  # eager JAX: slow
    assert out.shape == WIDE and np.all(np.isfinite(out))
    error = float(np.abs(out - reference).max()) / max(1.0, float(np.abs(reference).max()))
    assert error <= TOLERANCE[dtype], f"{name} {backend} {dtype}: error {error:.3g} > {TOLERANCE[dtype]}"
