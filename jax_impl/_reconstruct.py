"""`reconstruct` in JAX (defined in `diffblur.ops.reconstruct`)."""

from __future__ import annotations

from jaxtyping import Array, Float

from diffblur.ops import reconstruct as op
from diffblur.ops._options import public
from jax_impl._backend import JAX
from jax_impl._fused import forward_mode_hint


@public(op.DOC, op.ReconstructOptions)
@forward_mode_hint
def reconstruct(color: Float[Array, "b c h w"], velocity: Float[Array, "b 2 h w"], depth: Float[Array, "b 1 h w"], **options) -> Float[Array, "b c h w"]:
    return op.reconstruct(JAX, color, velocity, depth, **options)
