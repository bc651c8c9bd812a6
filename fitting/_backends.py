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

    def value_and_grad(self, loss: Callable[..., Any], *args: Any) -> Callable[[np.ndarray], tuple[float, np.ndarray]]:
        """NumPy y -> (loss(y, *args), its gradient in y), float64, through autograd."""

        def evaluate(y: np.ndarray) -> tuple[float, np.ndarray]:
            t = self.torch.tensor(np.asarray(y, dtype=np.float64), dtype=self.dtype, requires_grad=True)
            value = loss(t, *args)
            (grad,) = self.torch.autograd.grad(value, t)
            return float(value.detach()), grad.detach().cpu().numpy().astype(np.float64)

        return evaluate

    def run(self, f: Callable[..., Any], *args: Any) -> Any:
        """f(*args) without recording a gradient."""
        with self.torch.no_grad():
            return f(*args)

    def compiled(self, f: Callable[..., Any]) -> Callable[..., Any]:
        """f itself: PyTorch runs eagerly."""
        return f

    def per_candidate(self, f: Callable[..., Any]) -> Callable[..., Any]:
        """(stacked, *args) -> f of each candidate's parameters (stacked: dict of (n, ...) arrays),
        concatenated along the batch axis: a loop."""

        def each(stacked: dict, *args: Any) -> Any:
            count = next(iter(stacked.values())).shape[0]
            return self.torch.cat([f({k: v[i] for k, v in stacked.items()}, *args) for i in range(count)])

        return each


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
        _register_pytrees()

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

    def __eq__(self, other: object) -> bool:
        # An adapter is static data of the compiled losses (`value_and_grad`): equal adapters share them.
        return isinstance(other, JaxAdapter) and other.dtype == self.dtype

    def __hash__(self) -> int:
        return hash((self.name, self.dtype))

    def value_and_grad(self, loss: Callable[..., Any], *args: Any) -> Callable[[np.ndarray], tuple[float, np.ndarray]]:
        """NumPy y -> (loss(y, *args), its gradient in y), float64: reverse mode (the fused kernels'
        custom_vjp), compiled (eqx.filter_jit) once per `loss` and per static part and shapes of the
        arguments: arrays are traced; the adapter, a context's sizes and options and the model's
        static options are static, so every level, pass and fit of the same size reuses it."""
        compiled = _compiled(loss, gradient=True)

        def evaluate(y: np.ndarray) -> tuple[float, np.ndarray]:
            value, grad = compiled(self.array(y), *args)
            return float(value), np.asarray(grad, dtype=np.float64)

        return evaluate

    def run(self, f: Callable[..., Any], *args: Any) -> Any:
        """f(*args) op by op: the pieces a fit runs a few times (search, coverage, speed, the final
        render). Each op compiles once per shape and is reused by every later fit whatever its
        shutter or speed, where a compiled whole would compile again for each (on the held-out
        family that made the cheap models' JAX fits twice as slow)."""
        return f(*args)

    def compiled(self, f: Callable[..., Any]) -> Callable[..., Any]:
        """f under eqx.filter_jit, one wrapper per function (compiled once per static part and shapes
        of its arguments): for a small piece a fit calls many times, where dispatching its ops one
        by one costs more than compiling it."""
        return _compiled(f, gradient=False)

    def per_candidate(self, f: Callable[..., Any]) -> Callable[..., Any]:
        """(stacked, *args) -> f of each candidate's parameters (stacked: dict of (n, ...) arrays),
        concatenated along the batch axis: one compiled, vmapped call (calling a compiled f per
        candidate cost the search about 1.4 ms of dispatch each, most of a small fit's time)."""
        if (f, "per_candidate") not in _COMPILED:
            import equinox as eqx

            def each(stacked: dict, *args: Any) -> Any:
                out = eqx.filter_vmap(f, in_axes=(0,) + (None,) * len(args))(stacked, *args)
                return out.reshape((out.shape[0] * out.shape[1],) + out.shape[2:])

            _COMPILED[(f, "per_candidate")] = eqx.filter_jit(each)
        return _COMPILED[(f, "per_candidate")]


#: eqx.filter_jit of each function `JaxAdapter.value_and_grad` was given, by function.
_COMPILED: dict[tuple[Callable[..., Any], bool | str], Callable[..., Any]] = {}


def _compiled(f: Callable[..., Any], *, gradient: bool) -> Callable[..., Any]:
    if (f, gradient) not in _COMPILED:
        import equinox as eqx
        import jax

        _COMPILED[(f, gradient)] = eqx.filter_jit(jax.value_and_grad(f) if gradient else f)
    return _COMPILED[(f, gradient)]


_REGISTERED: list[bool] = []


def _register_pytrees() -> None:
    """Let JAX trace the fitting's level contexts: arrays are leaves, the adapter, sizes and options
    static (`fitting._models.Context`, `LayerStack`)."""
    if _REGISTERED:
        return
    import jax

    from fitting._models import Context, LayerStack

    def flatten_context(c: Context) -> tuple[tuple, tuple]:
        return (c.color, c.depth, c.target, c.extras), (c.be, c.height, c.width, c.scale, tuple(sorted(c.options.items())))

    def unflatten_context(aux: tuple, children: tuple) -> Context:
        be, height, width, scale, options = aux
        color, depth, target, extras = children
        return Context(be, color, depth, target, height, width, scale, dict(options), extras)

    jax.tree_util.register_pytree_node(Context, flatten_context, unflatten_context)
    jax.tree_util.register_pytree_node(
        LayerStack, lambda s: ((s.sources, s.depth, s.fill, s.velocity), s.ids), lambda ids, children: LayerStack(*children[:3], ids, children[3])
    )
    _REGISTERED.append(True)


BACKENDS = ("torch", "jax")


def adapter(backend: str, dtype: str = "float64") -> TorchAdapter | JaxAdapter:
    return TorchAdapter(dtype) if backend == "torch" else JaxAdapter(dtype)
