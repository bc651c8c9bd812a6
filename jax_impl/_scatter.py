"""`bezier_scatter` in JAX, seed 003's curve scatter (defined in `diffblur.ops.scatter`)."""

from __future__ import annotations

from jax import Array
from jaxtyping import Float

from diffblur.ops import scatter
from diffblur.ops._options import public
from jax_impl._backend import JAX
from jax_impl._fused import forward_mode_hint

EXAMPLE = """
    >>> import jax.numpy as jnp
    >>> color = jnp.zeros((1, 1, 1, 5)).at[..., 2].set(1.0)
    >>> offset = jnp.zeros((1, 2, 1, 5)).at[:, 0, :, 2].set(1.0)
    >>> depth = jnp.ones((1, 1, 1, 5))
    >>> bezier_scatter(color, depth, -offset, offset, samples=3, fill=jnp.zeros_like(color)).round(4).tolist()  # the scene behind: black
    [[[[0.0, 0.2222, 0.5556, 0.2222, 0.0]]]]
    >>> bezier_scatter(color, depth, -offset, offset, samples=3, fill="color").round(4).tolist()  # fills with its own colour
    [[[[0.0, 0.2222, 1.0, 0.2222, 0.0]]]]
"""


@public(scatter.DOC, scatter.ScatterOptions, example=EXAMPLE)
@forward_mode_hint
def bezier_scatter(
    color: Float[Array, "b c h w"], depth: Float[Array, "b 1 h w"], offset_prev: Float[Array, "b 2 h w"] | None, offset_next: Float[Array, "b 2 h w"] | None, *,
    offset_mid_prev: Float[Array, "b 2 h w"] | None = None, arc_center: Float[Array, "b 2 h w"] | None = None, arc_angle: Float[Array, "b 1 h w"] | None = None, **options,
) -> Float[Array, "b c h w"]:
    return scatter.bezier_scatter(JAX, color, depth, offset_prev, offset_next, offset_mid_prev=offset_mid_prev, arc_center=arc_center, arc_angle=arc_angle, **options)
