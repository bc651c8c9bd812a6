"""One small adapter per framework, imported only when used (einops' `_backends` idea): array
conversion, the ops, and the few array functions the models need that torch and jax.numpy spell
differently. Everything else the models write once with the adapter's `xp`."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np


class TorchAdapter:
    name = "torch"

    def __init__(self, dtype: str = "float64") -> None:
        import torch

        import torch_impl

        self.torch = torch
        self.xp = torch
        self.ops = torch_impl
        self.dtype = getattr(torch, dtype)

    def array(self, x: Any) -> Any:
        return self.torch.tensor(np.array(x, dtype=np.float64), dtype=self.dtype)

    def ints(self, x: Any) -> Any:
        return self.torch.as_tensor(np.asarray(x), dtype=self.torch.int64)

    def numpy(self, x: Any) -> np.ndarray:
        return x.detach().cpu().numpy().astype(np.float64)

    def stack(self, xs: list, axis: int = 0) -> Any:
        return self.torch.stack(xs, dim=axis)

    def concat(self, xs: list, axis: int = 0) -> Any:
        return self.torch.cat(xs, dim=axis)

    def broadcast(self, x: Any, shape: tuple[int, ...]) -> Any:
        return x.expand(*shape)

    def einsum(self, spec: str, *xs: Any) -> Any:
        return self.torch.einsum(spec, *xs)

    def value_and_grad(self, loss: Callable[[Any], Any]) -> Callable[[np.ndarray], tuple[float, np.ndarray]]:
        """NumPy y -> (loss(y), dloss/dy), float64, through autograd."""

        def evaluate(y: np.ndarray) -> tuple[float, np.ndarray]:
            t = self.torch.tensor(np.asarray(y, dtype=np.float64), dtype=self.dtype, requires_grad=True)
            value = loss(t)
            (grad,) = self.torch.autograd.grad(value, t)
            return float(value.detach()), grad.detach().cpu().numpy().astype(np.float64)

        return evaluate

    def compiled(self, f: Callable[[Any], Any]) -> Callable[[Any], Any]:
        """f itself: PyTorch runs eagerly."""
        return f


class JaxAdapter:
    name = "jax"

    def __init__(self, dtype: str = "float64") -> None:
        import jax
        import jax.numpy as jnp

        import jax_impl

        if dtype == "float64" and not jax.config.jax_enable_x64:
            jax.config.update("jax_enable_x64", True)
        self.jax = jax
        self.xp = jnp
        self.ops = jax_impl
        self.dtype = dtype

    def array(self, x: Any) -> Any:
        return self.xp.asarray(np.asarray(x, dtype=np.float64), dtype=self.dtype)

    def ints(self, x: Any) -> Any:
        return self.xp.asarray(np.asarray(x), dtype=self.xp.int32)

    def numpy(self, x: Any) -> np.ndarray:
        return np.asarray(x, dtype=np.float64)

    def stack(self, xs: list, axis: int = 0) -> Any:
        return self.xp.stack(xs, axis=axis)

    def concat(self, xs: list, axis: int = 0) -> Any:
        return self.xp.concatenate(xs, axis=axis)

    def broadcast(self, x: Any, shape: tuple[int, ...]) -> Any:
        return self.xp.broadcast_to(x, shape)

    def einsum(self, spec: str, *xs: Any) -> Any:
        return self.xp.einsum(spec, *xs)

    def value_and_grad(self, loss: Callable[[Any], Any]) -> Callable[[np.ndarray], tuple[float, np.ndarray]]:
        """NumPy y -> (loss(y), dloss/dy), float64: reverse mode (the fused kernels' custom_vjp),
        compiled once and reused for every evaluation."""
        import equinox as eqx

        compiled = eqx.filter_jit(self.jax.value_and_grad(loss))

        def evaluate(y: np.ndarray) -> tuple[float, np.ndarray]:
            value, grad = compiled(self.array(y))
            return float(value), np.asarray(grad, dtype=np.float64)

        return evaluate

    def compiled(self, f: Callable[[Any], Any]) -> Callable[[Any], Any]:
        """f under eqx.filter_jit (compiled once per input shape)."""
        import equinox as eqx

        return eqx.filter_jit(f)


BACKENDS = ("torch", "jax")


def adapter(backend: str, dtype: str = "float64") -> TorchAdapter | JaxAdapter:
    return TorchAdapter(dtype) if backend == "torch" else JaxAdapter(dtype)
