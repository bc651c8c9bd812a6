"""Seed 002's image-warping methods in JAX, `accumulate_warps` and `warp_blend` (defined in
`diffblur.ops.warp`)."""

from __future__ import annotations

from jaxtyping import Array, Float

from diffblur.ops import warp
from diffblur.ops._options import public
from jax_impl._backend import JAX

ACCUMULATE_EXAMPLE = """
    >>> import jax.numpy as jnp
    >>> color = jnp.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]).reshape(1, 1, 1, 7)
    >>> velocity = jnp.zeros((1, 2, 1, 7)).at[:, 0].set(4.0)
    >>> accumulate_warps(color, velocity, instants=2).round(4).tolist()  # two ghosts, 4 px apart
    [[[[0.0, 0.5, 0.0, 0.0, 0.0, 0.5, 0.0]]]]
"""


@public(warp.ACCUMULATE_DOC, warp.AccumulateOptions, example=ACCUMULATE_EXAMPLE)
def accumulate_warps(
    color: Float[Array, "b c h w"], velocity: Float[Array, "b 2 h w"] | None, *, offset_prev: Float[Array, "b 2 h w"] | None = None, offset_next: Float[Array, "b 2 h w"] | None = None, **options
) -> Float[Array, "b c h w"]:
    return warp.accumulate_warps(JAX, color, velocity, offset_prev=offset_prev, offset_next=offset_next, **options)


WARP_BLEND_EXAMPLE = """
    >>> import jax.numpy as jnp
    >>> color = jnp.zeros((1, 1, 1, 9)).at[..., 4].set(1.0)
    >>> velocity = jnp.zeros((1, 2, 1, 9)).at[:, 0].set(3.0)
    >>> warp_blend(color, velocity, iterations=1, alpha=0.5).tolist()  # taps at -2, 0, +2 px
    [[[[0.0, 0.0, 0.25, 0.0, 0.5, 0.0, 0.25, 0.0, 0.0]]]]
"""


@public(warp.WARP_BLEND_DOC, warp.WarpBlendOptions, example=WARP_BLEND_EXAMPLE)
def warp_blend(color: Float[Array, "b c h w"], velocity: Float[Array, "b 2 h w"], **options) -> Float[Array, "b c h w"]:
    return warp.warp_blend(JAX, color, velocity, **options)
