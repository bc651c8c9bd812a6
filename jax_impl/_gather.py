"""`gather_blur` in JAX (defined in `diffblur.ops.gather`)."""

from __future__ import annotations

from jaxtyping import Array, Float

from diffblur.ops import gather
from diffblur.ops._options import public
from jax_impl._backend import JAX
from jax_impl._fused import forward_mode_hint

EXAMPLE = """
    >>> import jax.numpy as jnp
    >>> color = jnp.array([0.0, 0.0, 1.0, 0.0, 0.0]).reshape(1, 1, 1, 5)
    >>> velocity = jnp.zeros((1, 2, 1, 5)).at[:, 0].set(1.0)
    >>> gather_blur(color, velocity, samples=3).round(4).tolist()
    [[[[0.0, 0.2222, 0.5556, 0.2222, 0.0]]]]
"""


@public(gather.DOC, gather.GatherOptions, example=EXAMPLE)
@forward_mode_hint
def gather_blur(color: Float[Array, "b c h w"], velocity: Float[Array, "b 2 h w"], **options) -> Float[Array, "b c h w"]:
    return gather.gather_blur(JAX, color, velocity, **options)
