"""`bezier_scatter`'s splats on the fused CPU kernel (`diffblur.kernels.scatter`): a `custom_vjp` over
`pure_callback`.

The kernel runs on the host, inside or outside `jax.jit`; reverse mode (grad, vjp) uses its
backward. Forward mode (jvp, jacfwd, linearize) is not defined for a custom_vjp: such callers pass
impl="tensor". The path's power-basis terms (or the arc's centre and angle) and the shutter's masses
stay jax.numpy ops, so JAX carries the kernel's gradients w.r.t. them back to the offsets and the
shutter's parameters as on the pure path.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from diffblur.kernels import scatter as scatter_kernel
from jax_impl._fused import _backend_reason, _bound
from diffblur.ops.primitives import floor_extent
from jax_impl._backend import JAX


def unfused_reason(color) -> str | None:
    """Why the fused splats cannot run on these inputs, or None when they can."""
    return scatter_kernel.splat_unfused_reason(str(jnp.dtype(color.dtype))) or _backend_reason()


def _host_forward(flags, *arrays):
    # order="C", not np.ascontiguousarray, which makes the 0-d extent 1-d.
    return scatter_kernel.splat_forward(*(np.asarray(a, order="C") for a in arrays), **dict(flags))


def _host_backward(flags, *arrays):
    return scatter_kernel.splat_backward(*(np.asarray(a, order="C") for a in arrays), **dict(flags))


@partial(jax.custom_vjp, nondiff_argnums=(0,))
def _fused_splat_core(flags, color, depth, path, masses, extent, moving):
    batch, channels, height, width = color.shape
    shape = jax.ShapeDtypeStruct((batch, channels + 1, height, width), color.dtype)
    # "sequential" under vmap: the kernel already loops over its batch axis.
    return jax.pure_callback(_bound(_host_forward, flags), shape, color, depth, path, masses, extent, moving, vmap_method="sequential")


def _fused_splat_core_fwd(flags, color, depth, path, masses, extent, moving):
    return _fused_splat_core(flags, color, depth, path, masses, extent, moving), (color, depth, path, masses, extent, moving)


def _fused_splat_core_bwd(flags, residuals, grad_sums):
    shapes = tuple(jax.ShapeDtypeStruct(a.shape, a.dtype) for a in residuals[:5])
    grads = jax.pure_callback(_bound(_host_backward, flags), shapes, *residuals, grad_sums, vmap_method="sequential")
    moving = residuals[5]
    return (*grads, np.zeros(moving.shape, dtype=jax.dtypes.float0))  # moving is boolean: a float0 cotangent


_fused_splat_core.defvjp(_fused_splat_core_fwd, _fused_splat_core_bwd)


def _path(kind: str, terms: tuple):
    """The kernel's (B, P, H, W) path: the arc's centre and angle, or the four power-basis terms
    (zeros for those the degree lacks; see `diffblur.kernels.scatter.BEZIER_CHANNELS`)."""
    if kind == "arc":
        return jnp.concatenate(terms, axis=1)
    like = next(term for term in terms if term is not None)
    return jnp.concatenate([jnp.zeros_like(like) if term is None else term for term in terms], axis=1)


def fused_splat(color, depth, kind: str, terms: tuple, masses, extent, moving, paper: bool):
    """The sums (B, C + 1, H, W) of omega * [color, 1] over every moving pixel's points (`_scatter`'s
    accumulation, cropped to the image), on the fused kernel; see `unfused_reason`."""
    extent = jnp.asarray(floor_extent(JAX, extent), dtype=depth.dtype)
    flags = (("arc", kind == "arc"), ("paper", paper))
    return _fused_splat_core(flags, color, depth, _path(kind, terms), masses.astype(color.dtype), extent, moving)


def _host_instant_forward(flags, *arrays):
    return scatter_kernel.instant_forward(*(np.asarray(a, order="C") for a in arrays), **dict(flags))


def _host_instant_backward(flags, *arrays):
    return scatter_kernel.instant_backward(*(np.asarray(a, order="C") for a in arrays), **dict(flags))


@partial(jax.custom_vjp, nondiff_argnums=(0,))
def _fused_instants_core(flags, color, log_depth, depth, path, times, extent, moving):
    batch, channels, height, width = color.shape
    shape = jax.ShapeDtypeStruct((times.shape[0], batch, 2 * channels + 3, height, width), color.dtype)
    return jax.pure_callback(_bound(_host_instant_forward, flags), shape, color, log_depth, depth, path, times, extent, moving, vmap_method="sequential")


def _fused_instants_core_fwd(flags, color, log_depth, depth, path, times, extent, moving):
    residuals = (color, log_depth, depth, path, times, extent, moving)
    return _fused_instants_core(flags, *residuals), residuals


def _fused_instants_core_bwd(flags, residuals, grad_sums):
    color, log_depth, depth, path, times, extent, moving = residuals
    shapes = tuple(jax.ShapeDtypeStruct(a.shape, a.dtype) for a in (color, log_depth, depth, path, extent))
    grad_color, grad_log, grad_depth, grad_path, grad_extent = jax.pure_callback(
        _bound(_host_instant_backward, flags), shapes, *residuals, grad_sums, vmap_method="sequential"
    )
    # The times are the strata's fixed midpoints: no gradient; moving is boolean: a float0 cotangent.
    return grad_color, grad_log, grad_depth, grad_path, jnp.zeros_like(times), grad_extent, np.zeros(moving.shape, dtype=jax.dtypes.float0)


_fused_instants_core.defvjp(_fused_instants_core_fwd, _fused_instants_core_bwd)


def fused_instants(color, log_depth, depth, kind: str, terms: tuple, times, extent, moving):
    """composite="instants"'s sums (K, B, 2 C + 3, H, W) at `times` (K,) on the fused kernel
    (`diffblur.ops.scatter._instant_sums`); color, log_depth and depth in one dtype."""
    extent = jnp.asarray(floor_extent(JAX, extent), dtype=depth.dtype)
    flags = (("arc", kind == "arc"),)
    return _fused_instants_core(flags, color, log_depth, depth, _path(kind, terms), times.astype(depth.dtype), extent, moving)
