"""Odd shapes for every blur of `ops.OPS`: 1x1 and 1xN and Nx1 images, sizes not multiples of the
reconstruct tile (4), batch 1 and 64, one and many channels; and in PyTorch non-contiguous and
channels-last inputs. Outputs keep the input's shape, are finite, stay in the input's colour
range, and batch items do not mix (permuting the batch permutes the output).

JAX compiles each op per shape, so it gets the two shapes that combine the cases, forward only;
PyTorch gets them all, with gradients (finite, of the input's shape).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

import torch_impl
from tests.properties.ops import OPS, Example, depths, vectors
from tests.properties.runner import _torch_inputs, forward, forward_and_grads

BLURS = [op for op in OPS if op.constant]
#: (B, C, H, W): 1x1 with batch 1 and one channel; 1xN with batch 64 and 5 channels.
SHAPES = [(1, 1, 1, 1), (64, 5, 1, 9)]
#: PyTorch only: Nx1, and sizes that are not multiples of the tile, with many channels.
TORCH_SHAPES = [(3, 2, 9, 1), (1, 8, 13, 22)]
CASES = [(op, b, s) for op in BLURS for b in op.backends for s in SHAPES + (TORCH_SHAPES if b == "torch" else [])]


def inputs_of(shape, seed=0):
    b, c, h, w = shape
    example = Example(seed=seed, speed="mixed", depth="layers", extent=0.1)
    rng = example.rng()
    return {"color": rng.random(shape), "velocity": vectors(example, rng, b, h, w), "depth": depths(example, rng, b, h, w)}


@pytest.mark.parametrize("op,backend,shape", CASES, ids=[f"{op.name}-{b}-{'x'.join(map(str, s))}" for op, b, s in CASES])
def test_odd_shapes(op, backend, shape):
    inputs = inputs_of(shape)
    # JAX: forward only (a quarter of the compile time of output and gradients, per shape);
    # PyTorch: with gradients.
    out, grads = forward_and_grads(op, backend, inputs) if backend == "torch" else (forward(op, backend, inputs), {})
    assert out.shape == shape
    assert np.all(np.isfinite(out))
    low, high = op.bounds(inputs)
    assert np.all(out >= low - 1e-12) and np.all(out <= high + 1e-12)
    if shape[0] > 1:  # batch items do not mix
        order = np.random.default_rng(1).permutation(shape[0])
        permuted = forward(op, backend, {k: v[order] for k, v in inputs.items()})
        np.testing.assert_allclose(permuted, out[order], rtol=0, atol=1e-13)
    for name, grad in grads.items():
        assert grad.shape == inputs[name].shape and np.all(np.isfinite(grad)), name


def _layouts(x: torch.Tensor) -> dict[str, torch.Tensor]:
    transposed = x.transpose(2, 3).contiguous().transpose(2, 3)
    sliced = torch.stack([x, -x], dim=-1).flatten(3)[..., ::2]  # every other column of a wider tensor
    return {"channels_last": x.contiguous(memory_format=torch.channels_last), "transposed": transposed, "strided": sliced}


@pytest.mark.parametrize("op", [op for op in BLURS if "torch" in op.backends], ids=lambda op: op.name)
def test_torch_non_contiguous_and_channels_last_inputs(op):
    inputs = _torch_inputs(inputs_of((2, 3, 9, 11), seed=5), "float64")
    expected = op.call(torch_impl, inputs, 0.1)
    for layout in ("channels_last", "transposed", "strided"):
        variant = {name: _layouts(value)[layout] for name, value in inputs.items()}
        assert not variant["color"].is_contiguous() and not variant["velocity"].is_contiguous(), layout
        torch.testing.assert_close(op.call(torch_impl, variant, 0.1), expected, rtol=0, atol=1e-13, msg=layout)
