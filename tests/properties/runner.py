"""Runs a table entry (`ops.Op`) on NumPy inputs in either framework: output and gradients as NumPy.

JAX runs each entry under one `jax.jit` per (entry, extent, gradients or not), compiled once per
shape and dtype; hypothesis then varies only the data, so every example after the first reuses
the compiled function (a forward-only one compiles about 4x faster). PyTorch runs eagerly.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import torch

import jax_impl
import torch_impl
from tests.properties.ops import OPS_BY_NAME, Op

BACKENDS = ("torch", "jax")
#: XLA's backend optimisation off for these jits only: it halves their compile time (measured on
#: the 2-core CI machine), and the properties do not depend on fusion.
COMPILER_OPTIONS = {"xla_backend_optimization_level": 0}


def cotangent(shape: tuple[int, ...], seed: int = 0) -> np.ndarray:
    """A seeded random weighting of the output, so no gradient cancels by symmetry."""
    return np.random.default_rng(seed).uniform(0.5, 1.5, size=shape)


def _torch_inputs(inputs: dict[str, np.ndarray], dtype: str, requires_grad: tuple[str, ...] = ()) -> dict:
    out = {}
    for name, value in inputs.items():
        if np.issubdtype(value.dtype, np.integer):
            out[name] = torch.as_tensor(value)
        else:
            out[name] = torch.tensor(value, dtype=getattr(torch, dtype), requires_grad=name in requires_grad)
    return out


def _jax_inputs(inputs: dict[str, np.ndarray], dtype: str) -> dict:
    return {n: jnp.asarray(v) if np.issubdtype(v.dtype, np.integer) else jnp.asarray(v, dtype=dtype) for n, v in inputs.items()}


def _numpy(x) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        x = x.detach()
        return (x.float() if x.dtype in (torch.float16, torch.bfloat16) else x).numpy()
    return np.asarray(x.astype(jnp.float32) if x.dtype in (jnp.float16, jnp.bfloat16) else x)


@functools.lru_cache(maxsize=None)
def _jax_forward(name: str, extent: float):
    op = OPS_BY_NAME[name]
    return jax.jit(lambda x: op.call(jax_impl, x, extent), compiler_options=COMPILER_OPTIONS)


@functools.lru_cache(maxsize=None)
def _jax_forward_and_grads(name: str, extent: float):
    op = OPS_BY_NAME[name]

    def run(x):
        fixed = {k: v for k, v in x.items() if k not in op.differentiable}
        out, vjp = jax.vjp(lambda d: op.call(jax_impl, {**fixed, **d}, extent), {k: x[k] for k in op.differentiable})
        return out, vjp(jnp.asarray(cotangent(out.shape), dtype=out.dtype))[0]

    return jax.jit(run, compiler_options=COMPILER_OPTIONS)


def forward(op: Op, backend: str, inputs: dict[str, np.ndarray], *, dtype: str = "float64", extent: float = 0.1) -> np.ndarray:
    """The op's output on `inputs` cast to `dtype` (integer inputs kept), as NumPy."""
    if backend == "torch":
        return _numpy(op.call(torch_impl, _torch_inputs(inputs, dtype), extent))
    return _numpy(_jax_forward(op.name, extent)(_jax_inputs(inputs, dtype)))


def forward_and_grads(op: Op, backend: str, inputs: dict[str, np.ndarray], *, dtype: str = "float64", extent: float = 0.1):
    """(output, {input: gradient of sum(output * cotangent)}) as NumPy."""
    if backend == "torch":
        x = _torch_inputs(inputs, dtype, requires_grad=op.differentiable)
        out = op.call(torch_impl, x, extent)
        leaves = [x[k] for k in op.differentiable]
        cot = torch.tensor(cotangent(tuple(out.shape)), dtype=out.dtype)
        grads = torch.autograd.grad(out, leaves, cot, allow_unused=True) if leaves else ()
        return _numpy(out), {k: np.zeros(inputs[k].shape) if g is None else _numpy(g) for k, g in zip(op.differentiable, grads)}
    out, grads = _jax_forward_and_grads(op.name, extent)(_jax_inputs(inputs, dtype))
    return _numpy(out), {k: _numpy(g) for k, g in grads.items()}
