"""`reconstruct` on the fused CPU kernel (`diffblur._fused`): a `custom_vjp` over `pure_callback`.

The kernel runs on the host, inside or outside `jax.jit`; reverse mode (grad, vjp) uses the
kernel's backward. Forward mode (jvp, jacfwd, linearize) is not defined for a custom_vjp: such
callers pass fused=False. NeighborMax and the tile classes stay jax.numpy ops, so JAX carries the
kernel's NeighborMax gradient back to the velocity as on the pure path.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from diffblur import _fused
from jax_impl._primitives import _safe_length, neighbor_max, tile_max


def unfused_reason(o, color) -> str | None:
    """Why the fused kernel cannot run these inputs and options, or None when it can."""
    reason = _fused.reconstruct_unfused_reason(o, str(jnp.dtype(color.dtype)))
    if reason is not None:
        return reason
    if jax.default_backend() != "cpu":
        return f"JAX's default backend is {jax.default_backend()} (the fused kernel runs on the CPU)"
    return None


def _host_forward(settings, color, velocity, depth, neighbors, counts, jitter):
    arrays = (np.ascontiguousarray(a) for a in (color, velocity, depth, neighbors, counts, jitter))
    return _fused.reconstruct_forward(*arrays, **dict(settings))


def _host_backward(settings, *arrays):
    return _fused.reconstruct_backward(*(np.ascontiguousarray(a) for a in arrays), **dict(settings))


@partial(jax.custom_vjp, nondiff_argnums=(0,))
def _fused_core(settings, color, velocity, depth, neighbors, counts, jitter):
    return _forward(settings, color, velocity, depth, neighbors, counts, jitter)[0]


def _forward(settings, color, velocity, depth, neighbors, counts, jitter):
    batch, _, height, width = color.shape
    shapes = (jax.ShapeDtypeStruct(color.shape, color.dtype), jax.ShapeDtypeStruct((batch, height, width), color.dtype))
    # "sequential" under vmap: the kernel already loops over its batch axis.
    return jax.pure_callback(partial(_host_forward, settings), shapes, color, velocity, depth, neighbors, counts, jitter, vmap_method="sequential")


def _fused_core_fwd(settings, color, velocity, depth, neighbors, counts, jitter):
    out, weight = _forward(settings, color, velocity, depth, neighbors, counts, jitter)
    return out, (color, velocity, depth, neighbors, counts, jitter, out, weight)


def _fused_core_bwd(settings, residuals, grad_out):
    color, velocity, depth, neighbors, counts, jitter, _, _ = residuals
    shapes = tuple(jax.ShapeDtypeStruct(a.shape, a.dtype) for a in (color, velocity, depth, neighbors))
    grads = jax.pure_callback(partial(_host_backward, settings), shapes, *residuals, grad_out, vmap_method="sequential")
    # counts are integers (float0 cotangent); jitter gets no gradient on the fused path.
    return (*grads, np.zeros(counts.shape, dtype=jax.dtypes.float0), jnp.zeros_like(jitter))


_fused_core.defvjp(_fused_core_fwd, _fused_core_bwd)


def fused_reconstruct(color, velocity, depth, jitter, o):
    """reconstruct (options `o`, adaptive or not) on the fused kernel; see `unfused_reason`."""
    neighbors = neighbor_max(tile_max(velocity, o.tile))
    speed = _safe_length(jax.lax.stop_gradient(neighbors))[:, 0]
    counts = _fused.tile_counts(speed, o, jnp)
    settings = (("tile", o.tile), ("soft_z_extent", o.soft_z_extent), ("min_radius", o.min_radius), ("own_odd", o.directions == "neighbor_and_own"))
    jitter = jnp.broadcast_to(jitter, (jitter.shape[0], 1, *color.shape[2:]))
    return _fused_core(settings, color, velocity, depth, neighbors, counts.astype(jnp.int32), jitter)

