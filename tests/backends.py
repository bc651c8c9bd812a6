"""One small adapter per framework, so behaviour tests can be written once and run on both.

Each framework is imported only if installed: with one of them, the `backend` fixture's cases for
the other skip, naming what is missing, and BACKENDS lists only the installed ones."""

from __future__ import annotations

import importlib
from collections.abc import Callable

import numpy as np
import pytest


def _importable(name: str) -> bool:
    try:
        importlib.import_module(name)
    except ImportError:
        return False
    return True


#: Whether each framework (and so its backend package) can be imported here.
INSTALLED = {name: _importable(name) for name in ("torch", "jax")}

if INSTALLED["torch"]:
    import torch

    import torch_impl
if INSTALLED["jax"]:
    import jax
    import jax.numpy as jnp

    import jax_impl


class TorchBackend:
    name = "torch"
    ops = torch_impl if INSTALLED["torch"] else None

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
    ops = jax_impl if INSTALLED["jax"] else None

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


ALL_BACKENDS = [TorchBackend, JaxBackend]
#: The installed backends: tests that loop over frameworks loop over these.
BACKENDS = [b for b in ALL_BACKENDS if INSTALLED[b.name]]


def backend_params() -> list:
    """Both backends as pytest params, each one not installed marked to skip with the reason."""
    skip = lambda b: pytest.mark.skip(reason=f"{b.name} is not installed (pip install 'diffblur[{b.name}]')")  # noqa: E731
    return [pytest.param(b, id=b.name, marks=() if INSTALLED[b.name] else skip(b)) for b in ALL_BACKENDS]


@pytest.fixture(params=backend_params())
def backend(request):
    return request.param
