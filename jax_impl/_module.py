"""`MotionBlur`, the Equinox layer: options static, arrays learnable, the functional op does the work."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from diffblur import checks
from diffblur.ops.module import CALL_DOC, blur, check_method_options, layer_doc, learnable_shutter_fields, shutter_option
from jax_impl._backend import JAX
from jax_impl._gather import gather_blur
from jax_impl._reconstruct import reconstruct
from jax_impl._scatter import bezier_scatter
from jax_impl._warp import accumulate_warps, warp_blend

_OPS = {"reconstruct": reconstruct, "gather": gather_blur, "bezier": bezier_scatter, "warp_blend": warp_blend, "accumulate": accumulate_warps}


class MotionBlur(eqx.Module):
    __doc__ = layer_doc("""
    >>> import jax, jax.numpy as jnp
    >>> layer = MotionBlur("gather", samples=5)
    >>> color = jax.random.uniform(jax.random.key(0), (2, 3, 16, 16))
    >>> velocity = jax.random.normal(jax.random.key(1), (2, 2, 16, 16))
    >>> layer(color, velocity).shape
    (2, 3, 16, 16)
""")

    exposure: Array | float
    shutter_shape: dict[str, Array]
    method: str = eqx.field(static=True)
    options: tuple = eqx.field(static=True)

    def __init__(self, method: str = "reconstruct", *, exposure: float = 1.0, learn_exposure: bool = False, learn_shutter: bool = False, **options):
        self.method = method
        op = _OPS.get(method, reconstruct)
        checked = check_method_options(method, op, options)
        self.options = tuple(sorted(checked.items()))
        exposure = checks.require_positive_number("exposure", exposure)
        self.exposure = jnp.asarray(exposure) if learn_exposure else exposure
        self.shutter_shape = {}
        if learn_shutter:
            self.shutter_shape = {k: jnp.asarray(v) for k, v in learnable_shutter_fields(shutter_option(op, checked)).items()}

    def __call__(
        self, color: Float[Array, "b c h w"], velocity: Float[Array, "b 2 h w"] | None = None, depth: Float[Array, "b 1 h w"] | None = None, *,
        offset_prev: Float[Array, "b 2 h w"] | None = None, offset_next: Float[Array, "b 2 h w"] | None = None, offset_mid_prev: Float[Array, "b 2 h w"] | None = None,
        arc_center: Float[Array, "b 2 h w"] | None = None, arc_angle: Float[Array, "b 1 h w"] | None = None, fill: Float[Array, "b c h w"] | None = None,
    ) -> Float[Array, "b c h w"]:
        paths = {"offset_prev": offset_prev, "offset_next": offset_next, "offset_mid_prev": offset_mid_prev, "arc_center": arc_center, "arc_angle": arc_angle}
        return blur(JAX, _OPS, self.method, dict(self.options), self.exposure, self.shutter_shape, color, velocity, depth, paths, fill)

    __call__.__doc__ = CALL_DOC
