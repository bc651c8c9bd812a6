"""`velocity_from_motion_ids` in JAX (defined in `diffblur.ops.motion_ids`)."""

from __future__ import annotations

from jaxtyping import Array, Float, Int

from diffblur.ops import motion_ids
from diffblur.ops._options import public
from jax_impl._backend import JAX

EXAMPLE = """
    >>> import jax.numpy as jnp
    >>> ids = jnp.array([[[[0, 1], [1, 0]]]])
    >>> palette = jnp.array([[[0.0, 0.0], [3.0, -1.0]]])
    >>> velocity_from_motion_ids(ids, palette)[0, 0].tolist()
    [[0.0, 3.0], [3.0, 0.0]]
"""


@public(motion_ids.DOC, example=EXAMPLE)
def velocity_from_motion_ids(
    ids: Int[Array, "b 1 h w"], palette: Float[Array, "b k d"], *, depth: Float[Array, "b 1 h w"] | None = None, focal: float | None = None, principal_point: tuple[float, float] | None = None
) -> Float[Array, "b 2 h w"]:
    return motion_ids.velocity_from_motion_ids(JAX, ids, palette, depth=depth, focal=focal, principal_point=principal_point)
