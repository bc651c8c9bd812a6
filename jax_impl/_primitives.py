"""The building blocks of seed 000 as batched, differentiable JAX ops (defined in
`diffblur.ops.primitives`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from diffblur.conventions import DEFAULT_MAX_RADIUS, DEFAULT_MIN_RADIUS
from diffblur.ops import primitives as p
from diffblur.ops._options import public
from jax_impl._backend import JAX

__all__ = ["cone", "cylinder", "interleaved_gradient_noise", "neighbor_max", "safe_length", "soft_depth_compare", "tile_max", "velocity_from_motion"]


@public(p.SOFT_DEPTH_COMPARE_DOC, example="""
    >>> import jax.numpy as jnp
    >>> soft_depth_compare(jnp.array([2.0, 2.0, 2.0]), jnp.array([1.0, 2.5, 4.0]), 1.0).tolist()
    [1.0, 0.5, 0.0]""")
def soft_depth_compare(z_a: Float[Array, "*shape"], z_b: Float[Array, "*shape"], extent: float | Array) -> Float[Array, "*shape"]:
    return p.soft_depth_compare_op(JAX, z_a, z_b, extent)


@public(p.CONE_DOC, example="""
    >>> import jax.numpy as jnp
    >>> cone(jnp.array([0.0, 1.0, 3.0]), jnp.array([2.0, 2.0, 2.0])).tolist()
    [1.0, 0.5, 0.0]""")
def cone(distance: Float[Array, "*shape"], speed: Float[Array, "*shape"]) -> Float[Array, "*shape"]:
    return p.cone_op(JAX, distance, speed)


@public(p.CYLINDER_DOC, example="""
    >>> import jax.numpy as jnp
    >>> cylinder(jnp.array([0.0, 2.0, 3.0]), jnp.array([2.0, 2.0, 2.0])).tolist()
    [1.0, 0.5, 0.0]""")
def cylinder(distance: Float[Array, "*shape"], speed: Float[Array, "*shape"]) -> Float[Array, "*shape"]:
    return p.cylinder_op(JAX, distance, speed)


@public(p.SAFE_LENGTH_DOC, example="""
    >>> import jax, jax.numpy as jnp
    >>> jax.grad(lambda v: safe_length(v).sum())(jnp.zeros((1, 2, 1, 1))).ravel().tolist()
    [0.0, 0.0]""")
def safe_length(vector: Float[Array, "b c h w"], *, axis: int = 1) -> Float[Array, "b 1 h w"]:
    return p.safe_length_op(JAX, vector, axis)


@public(p.TILE_MAX_DOC, example="""
    >>> import jax.numpy as jnp
    >>> v = jnp.zeros((1, 2, 2, 4)).at[0, 0, 1, 1].set(3.0).at[0, 1, 0, 3].set(-1.0)
    >>> tile_max(v, 2)[0].tolist()  # the longest vector of each 2 x 2 tile
    [[[3.0, 0.0]], [[0.0, -1.0]]]""")
def tile_max(velocity: Float[Array, "b 2 h w"], tile: int) -> Float[Array, "b 2 th tw"]:
    return p.tile_max_op(JAX, velocity, tile)


@public(p.NEIGHBOR_MAX_DOC, example="""
    >>> import jax.numpy as jnp
    >>> tiles = jnp.zeros((1, 2, 1, 4)).at[0, 0, 0, 0].set(2.0)
    >>> neighbor_max(tiles)[0, 0].tolist()  # the longest of each tile's 3 x 3 neighbours
    [[2.0, 2.0, 0.0, 0.0]]""")
def neighbor_max(tile_velocity: Float[Array, "b 2 th tw"]) -> Float[Array, "b 2 th tw"]:
    return p.neighbor_max_op(JAX, tile_velocity)


@public(p.INTERLEAVED_GRADIENT_NOISE_DOC, example="""
    >>> import jax.numpy as jnp
    >>> noise = interleaved_gradient_noise(4, 6)
    >>> noise.shape, bool(((noise >= 0) & (noise < 1)).all())
    ((4, 6), True)""")
def interleaved_gradient_noise(height: int, width: int, *, dtype: jnp.dtype | None = None, device: jax.Device | None = None) -> Float[Array, "h w"]:
    return p.interleaved_gradient_noise_op(JAX, height, width, dtype=dtype, device=device)


@public(p.VELOCITY_FROM_MOTION_DOC, example="""
    >>> import jax.numpy as jnp
    >>> d = jnp.array([[3.0, 0.2, 60.0], [4.0, 0.0, 80.0]]).reshape(1, 2, 1, 3)
    >>> velocity_from_motion(d, exposure=1.0, max_radius=20.0)[0, :, 0].T.tolist()
    [[1.5, 2.0], [0.5, 0.0], [12.0, 16.0]]""")
def velocity_from_motion(displacement: Float[Array, "b 2 h w"], *, exposure: float | Array = 1.0, max_radius: float = DEFAULT_MAX_RADIUS, min_radius: float = DEFAULT_MIN_RADIUS) -> Float[Array, "b 2 h w"]:
    return p.velocity_from_motion_op(JAX, displacement, exposure=exposure, max_radius=max_radius, min_radius=min_radius)
