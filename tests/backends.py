"""One small adapter per framework, so behaviour tests can be written once and run on both."""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import torch

import jax_impl
import torch_impl


class TorchBackend:
    name = "torch"
    ops = torch_impl

    @staticmethod
    def array(x, dtype: str = "float64"):
        return torch.tensor(np.asarray(x), dtype=getattr(torch, dtype))

    @staticmethod
    def numpy(x) -> np.ndarray:
        return x.detach().float().numpy() if x.dtype == torch.bfloat16 else x.detach().numpy()

    @classmethod
    def grad(cls, fn: Callable, *args) -> list[np.ndarray]:
        """Gradients of fn(*args).sum() with respect to every argument."""
        leaves = [a.detach().clone().requires_grad_(True) for a in args]
        out = fn(*leaves)
        grads = torch.autograd.grad(out.sum(), leaves)
        return [g.numpy() for g in grads]


class JaxBackend:
    name = "jax"
    ops = jax_impl

    @staticmethod
    def array(x, dtype: str = "float64"):
        return jnp.asarray(np.asarray(x), dtype=dtype)

    @staticmethod
    def numpy(x) -> np.ndarray:
        return np.asarray(x.astype(jnp.float32) if x.dtype == jnp.bfloat16 else x)

    @classmethod
    def grad(cls, fn: Callable, *args) -> list[np.ndarray]:
        grads = jax.grad(lambda *a: fn(*a).sum(), argnums=tuple(range(len(args))))(*args)
        return [np.asarray(g) for g in grads]


BACKENDS = [TorchBackend, JaxBackend]


@pytest.fixture(params=BACKENDS, ids=lambda b: b.name)
def backend(request):
    return request.param
