"""`reconstruct` and `gather_blur` on the fused CPU kernels (`diffblur.kernels.reconstruct`,
`diffblur.kernels.gather`): `custom_vjp`s over host calls, `reconstruct`'s an XLA FFI call whose
kernels write into XLA's buffers (`jax_impl._ffi`), `gather_blur`'s a `pure_callback`.

The kernels run on the host, inside or outside `jax.jit`; reverse mode (grad, vjp) uses the
kernels' backward, for the differentiated inputs only (`symbolic_zeros=True` tells the rules which). Forward mode (jvp, jacfwd, linearize) is not defined for a custom_vjp: such
callers pass impl="tensor". NeighborMax, the tile classes and the shutter's masses stay jax.numpy
ops, so JAX carries the kernels' gradients w.r.t. NeighborMax and the masses back to the velocity
and the shutter's parameters as on the pure path.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from functools import lru_cache, partial

import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero

from diffblur.kernels import gather as gather_kernel
from diffblur.kernels import reconstruct as reconstruct_kernel
from diffblur.ops.adaptive import ADAPTIVE_TILE, STILL_SPEED
from diffblur.ops import primitives
from jax_impl._backend import JAX
from jax_impl._ffi import host_target


def _backend_reason() -> str | None:
    """Why no fused kernel can run in this JAX process, or None. Shared by every fused op."""
    if jax.default_backend() != "cpu":
        return f"JAX's default backend is {jax.default_backend()} (the fused kernel runs on the CPU)"
    if jax.device_count() > 1:
        # A pure_callback runs on one device: under a sharded jax.jit XLA gathers the whole batch to
        # it, and the gradient of bezier_scatter's fused splats then deadlocked in an all-reduce
        # until XLA aborted the process (2 host devices). The tensor ops shard.
        return (
            f"JAX has {jax.device_count()} devices and the fused kernel's host callback runs on one"
            " (under a sharded jax.jit it deadlocked); pass impl='tensor', or run with one device"
        )
    return None


def forward_mode_hint(op: Callable) -> Callable:
    """`op` (a public op with a fused kernel), with JAX's error for forward mode (jvp, jacfwd,
    linearize) through the kernel's custom_vjp made to say what to do: the tensor ops have both
    modes."""

    @functools.wraps(op)
    def hinted(*args, **options):
        try:
            return op(*args, **options)
        except TypeError as error:
            if "forward-mode" not in str(error) or options.get("impl") == "tensor":
                raise
            raise TypeError(
                f"{op.__name__} ran on its fused CPU kernel, which has a reverse-mode gradient only (a custom_vjp): for jax.jvp, "
                f"jax.jacfwd or jax.linearize pass {op.__name__}(..., impl='tensor') (or MotionBlur(..., impl='tensor')). JAX: {error}"
            ) from error

    return hinted


def unfused_reason(o, color, jitter=None) -> str | None:
    """Why the fused reconstruct cannot run these inputs and options, or None when it can. A jitter
    array is taken as it is: JAX cannot tell here whether it will be differentiated, and the
    kernel's rule gives it no gradient (PyTorch refuses a jitter that requires grad)."""
    return reconstruct_kernel.reconstruct_unfused_reason(o, str(jnp.dtype(color.dtype))) or _backend_reason()


def gather_unfused_reason(color, sampling: str) -> str | None:
    """Why the fused gather_blur cannot run these inputs and options, or None when it can."""
    return gather_kernel.gather_unfused_reason(sampling, str(jnp.dtype(color.dtype))) or _backend_reason()


@lru_cache(maxsize=None)
def _bound(function, settings):
    """The same host callable for the same settings: eager pure_callback calls then hit JAX's cache
    instead of compiling a new call each time, and an FFI call registers one target per settings
    (a handful per process: tile, band, radius, directions and the gradients asked for)."""
    return partial(function, settings)


def _host_forward(settings, arguments, results):
    """The FFI handler's body: color, velocity, depth, neighbors, counts, jitter -> out, weight."""
    reconstruct_kernel.reconstruct_forward(*arguments, **dict(settings), into=results)


def _host_backward(settings, arguments, results):
    """The FFI handler's body: the gradients asked for (settings' "needs"), in order."""
    reconstruct_kernel.reconstruct_backward(*arguments, **dict(settings), into=results)


def _host_call(function, settings, shapes):
    # "sequential" under vmap: the kernel already loops over its batch axis.
    return jax.ffi.ffi_call(host_target(_bound(function, settings)), shapes, vmap_method="sequential")


def _needs(*primals) -> tuple:
    """Which inputs are differentiated (`symbolic_zeros=True` hands the fwd rule each one with its
    `perturbed` bit), as a residual: () for yes, None for no. The pytree's structure, not leaves,
    carries the bits, so they stay Python bools under jit."""
    return tuple(() if primal.perturbed else None for primal in primals)


@partial(jax.custom_vjp, nondiff_argnums=(0,))
def _fused_core(settings, color, velocity, depth, neighbors, counts, jitter):
    return _forward(settings, color, velocity, depth, neighbors, counts, jitter)[0]


def _forward(settings, color, velocity, depth, neighbors, counts, jitter):
    batch, _, height, width = color.shape
    shapes = (jax.ShapeDtypeStruct(color.shape, color.dtype), jax.ShapeDtypeStruct((batch, height, width), color.dtype))
    return _host_call(_host_forward, settings, shapes)(color, velocity, depth, neighbors, counts, jitter)


def _fused_core_fwd(settings, *primals):
    values = [primal.value for primal in primals]
    out, weight = _forward(settings, *values)
    color, velocity, depth, neighbors = primals[:4]
    return out, (_needs(color, velocity, depth, neighbors), *values, out, weight)


def _fused_core_bwd(settings, residuals, grad_out):
    (need_color, need_velocity, need_depth, need_neighbors), *arrays = residuals
    color, velocity, depth, neighbors, counts, jitter, _, _ = arrays
    # Only the gradients asked for (the scatter of the others is most of the kernel's time):
    # fitting a velocity skips the colour's and depth's. NeighborMax's comes with the velocity's.
    needs = (need_color is not None, need_velocity is not None or need_neighbors is not None, need_depth is not None)
    if isinstance(grad_out, SymbolicZero) or not any(needs):
        return (None,) * 6
    wanted = [a for a, need in zip((color, velocity, depth, neighbors), (*needs, needs[1])) if need]
    shapes = tuple(jax.ShapeDtypeStruct(a.shape, a.dtype) for a in wanted)
    grads = iter(_host_call(_host_backward, (*settings, ("needs", needs)), shapes)(*arrays, grad_out))
    # counts (integers) and jitter (not differentiated on the fused path) get none.
    return (*(next(grads) if need else None for need in (*needs, needs[1])), None, None)


_fused_core.defvjp(_fused_core_fwd, _fused_core_bwd, symbolic_zeros=True)


def fused_reconstruct(color, velocity, depth, jitter, o):
    """reconstruct (options `o`, adaptive or not) on the fused kernel; see `unfused_reason`."""
    neighbors = primitives.neighbor_max_of_velocity(JAX, velocity, o.tile)
    speed = primitives.safe_length(JAX, jax.lax.stop_gradient(neighbors))[:, 0]
    counts = reconstruct_kernel.tile_counts(speed, o, jnp)
    settings = (("tile", o.tile), ("soft_z_extent", o.band), ("min_radius", o.min_radius), ("own_odd", o.directions == "neighbor_and_own"))
    jitter = jnp.broadcast_to(jitter, (jitter.shape[0], 1, *color.shape[2:]))
    return _fused_core(settings, color, velocity, depth, neighbors, counts.astype(jnp.int32), jitter)



def _host_gather_forward(settings, color, velocity, masses):
    return gather_kernel.gather_forward(*(np.ascontiguousarray(a) for a in (color, velocity, masses)), **dict(settings))


def _host_gather_backward(settings, *arrays):
    """The gradients asked for (settings' "needs"), in order, without the Nones."""
    grads = gather_kernel.gather_backward(*(np.ascontiguousarray(a) for a in arrays), **dict(settings))
    return tuple(g for g in grads if g is not None)


@partial(jax.custom_vjp, nondiff_argnums=(0,))
def _fused_gather_core(settings, color, velocity, masses):
    shape = jax.ShapeDtypeStruct(color.shape, color.dtype)
    return jax.pure_callback(_bound(_host_gather_forward, settings), shape, color, velocity, masses, vmap_method="sequential")


def _fused_gather_core_fwd(settings, *primals):
    values = [primal.value for primal in primals]
    return _fused_gather_core(settings, *values), (_needs(*primals), *values)


def _fused_gather_core_bwd(settings, residuals, grad_out):
    marks, *arrays = residuals
    # Without the colour's gradient the kernel skips its scatter, most of the backward's time.
    needs = tuple(mark is not None for mark in marks)
    if isinstance(grad_out, SymbolicZero) or not any(needs):
        return (None,) * 3
    shapes = tuple(jax.ShapeDtypeStruct(a.shape, a.dtype) for a, need in zip(arrays, needs) if need)
    grads = iter(jax.pure_callback(_bound(_host_gather_backward, (*settings, ("needs", needs))), shapes, *arrays, grad_out, vmap_method="sequential"))
    return tuple(next(grads) if need else None for need in needs)


_fused_gather_core.defvjp(_fused_gather_core_fwd, _fused_gather_core_bwd, symbolic_zeros=True)


def fused_gather(color, velocity, window, samples: int, classes: tuple[int, ...] | None, wide):
    """gather_blur (full rate, or the adaptive `classes`) on the fused kernel; see `gather_unfused_reason`.
    The kernel sizes the adaptive classes itself, from the velocity."""
    settings = (("samples", samples), ("classes", classes), ("still", STILL_SPEED), ("tile", ADAPTIVE_TILE))
    table = gather_kernel.gather_mass_table(JAX.widen_window(window, wide), samples, classes or (samples,), jnp, wide).astype(color.dtype)
    return _fused_gather_core(settings, color, velocity, table)
