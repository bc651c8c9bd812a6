"""Seed 002's image-warping methods: the accumulation-buffer baseline and the iterative
warp-and-blend (definitions in `diffblur._warp_options`)."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
from jaxtyping import Array, Float

from diffblur import checks
from diffblur._warp_options import (
    DEFAULT_ALPHA,
    DEFAULT_BACKWARD_SCALE,
    DEFAULT_INSTANTS,
    DEFAULT_ITERATIONS,
    accumulate_options,
    instant_masses,
    lookup_offset,
    require_path,
    warp_blend_options,
)
from diffblur.conventions import DEFAULT_SHUTTER, VECTOR_CHANNELS
from diffblur.shutters import ShutterWindow
from jax_impl import _checks
from jax_impl._sampling import pixel_grid, position_dtype, sample, widen_window


def _vector_field(name: str, value: object, color: Array) -> Array:
    value = _checks.image(name, value, channels=VECTOR_CHANNELS)
    checks.require_same_batch_and_size("color", color.shape, [(name, value.shape)])
    _checks.same_dtype(name, value, "color", color)
    return _checks.finite_values(name, value)


def accumulate_warps(
    color: Float[Array, "b c h w"],
    velocity: Float[Array, "b 2 h w"] | None,
    *,
    instants: int = DEFAULT_INSTANTS,
    shutter: str | ShutterWindow = DEFAULT_SHUTTER,
    sampling: str = "bilinear",
    offset_prev: Float[Array, "b 2 h w"] | None = None,
    offset_next: Float[Array, "b 2 h w"] | None = None,
) -> Float[Array, "b c h w"]:
    """The accumulation-buffer baseline on the image (seed 002 sec. 1): `instants` warped copies of
    the image, one per instant of the exposure, weighted by the shutter.

    Copy k shows pixel X the point that is there at instant t_k: C[X + p(-t_k)], where X's own path
    p (p(t) = t V[X], or the parabola through offset_prev, 0 and offset_next at t = -1, 0, 1) is at
    -t_k, so a curved path keeps its bend (`diffblur._warp_options`). The instants are the
    midpoints of `instants` equal strata, each weighted by the shutter's mass on its stratum. With
    few instants and fast motion the copies separate (ghosting, seed 002 Figure 1); the brute-force
    reference of the trade. With a velocity and an odd count it equals `gather_blur(samples=instants)`.

    Args:
        color: (B, C, H, W) linear intensities, any C.
        velocity: (B, 2, H, W) half-spread velocity in pixels, or None when offsets are given.
        instants: number of renderings N, an integer >= 1 (1 returns the image).
        shutter: a window name or `ShutterWindow` (its parameters may be arrays to fit).
        sampling: "bilinear" (differentiable in the path) or "nearest".
        offset_prev, offset_next: (B, 2, H, W) where the point seen at X is at t = -1 and t = +1,
            relative to X, in pixels; instead of velocity.

    Returns:
        (B, C, H, W), color's dtype. Positions beyond the border read the border pixel.

    >>> import jax.numpy as jnp
    >>> color = jnp.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]).reshape(1, 1, 1, 7)
    >>> velocity = jnp.zeros((1, 2, 1, 7)).at[:, 0].set(4.0)
    >>> accumulate_warps(color, velocity, instants=2).round(4).tolist()  # two ghosts, 4 px apart
    [[[[0.0, 0.5, 0.0, 0.0, 0.0, 0.5, 0.0]]]]
    """
    color = _checks.image("color", color)
    o = accumulate_options(instants=instants, shutter=shutter, sampling=sampling)
    way = require_path(velocity, offset_prev, offset_next)
    if way == "velocity":
        velocity = _vector_field("velocity", velocity, color)
    else:
        offset_prev = _vector_field("offset_prev", offset_prev, color)
        offset_next = _vector_field("offset_next", offset_next, color)
    if way == "velocity":
        velocity = _checks.finite_values("color", color, carry=velocity)
    else:
        offset_prev = _checks.finite_values("color", color, carry=offset_prev)
    # Positions, offsets, weights and the sum in float32 for a half image (its dtype else).
    wide = position_dtype(color.dtype)
    velocity, offset_prev, offset_next = (None if v is None else v.astype(wide) for v in (velocity, offset_prev, offset_next))
    o = dataclasses.replace(o, window=widen_window(o.window, wide))
    masses = [m.astype(wide) for m in instant_masses(o, jnp, dtype=wide)]
    _, _, height, width = color.shape
    x, y = pixel_grid(height, width, color.dtype)
    out = jnp.zeros_like(color, dtype=wide)
    for t, mass in zip(o.times, masses):
        p = lookup_offset(t, velocity, offset_prev, offset_next)
        out = out + mass * sample(color, x + p[:, 0], y + p[:, 1], o.sampling)
    return out.astype(color.dtype)


def warp_blend(
    color: Float[Array, "b c h w"],
    velocity: Float[Array, "b 2 h w"],
    *,
    iterations: int = DEFAULT_ITERATIONS,
    backward_scale: float = DEFAULT_BACKWARD_SCALE,
    alpha: float | tuple[float, float] = DEFAULT_ALPHA,
    sampling: str = "bilinear",
) -> Float[Array, "b c h w"]:
    """Seed 002's iterative warp-and-blend line integral convolution.

    Starting from R = color, iteration i warps R by s_i = 2 / 3^(i + 1) of the velocity, along it
    and (scaled by `backward_scale`) against it, and blends both into R with alpha a_i:
    R <- (1 - a_i) R + a_i / 2 (R[X + s_i V] + R[X - backward_scale s_i V]). The blended image is
    warped again at the next, smaller warp, so the blur follows the velocity field. With the
    defaults a uniform translation gets the box filter of 3^iterations taps (gather_blur with
    3^iterations samples) from 2 x iterations lookups.

    Args:
        color: (B, C, H, W) linear intensities, any C.
        velocity: (B, 2, H, W) half-spread velocity in pixels.
        iterations: warp-and-blend passes n, an integer >= 1.
        backward_scale: scale of the warp against the velocity, in [0, 1]; below 1 the leading
            side blurs less than the trailing one (the document's look, for a sharp frame at the
            end of the exposure); 1 (default) is symmetric, as this project's mid-exposure frame.
        alpha: the blend weight of the warped images, a number or a ramp (first, last) run
            linearly from the first (largest) warp to the last (smallest); each in (0, 1]. The
            document lets it grow as the warp shrinks, e.g. (0.5, 0.8); flat 2/3 (default) gives
            the box filter.
        sampling: "bilinear" (differentiable in velocity) or "nearest".

    Returns:
        (B, C, H, W), color's dtype.

    >>> import jax.numpy as jnp
    >>> color = jnp.zeros((1, 1, 1, 9)).at[..., 4].set(1.0)
    >>> velocity = jnp.zeros((1, 2, 1, 9)).at[:, 0].set(3.0)
    >>> warp_blend(color, velocity, iterations=1, alpha=0.5).tolist()  # taps at -2, 0, +2 px
    [[[[0.0, 0.0, 0.25, 0.0, 0.5, 0.0, 0.25, 0.0, 0.0]]]]
    """
    color = _checks.image("color", color)
    velocity = _vector_field("velocity", velocity, color)
    velocity = _checks.finite_values("color", color, carry=velocity)
    o = warp_blend_options(iterations=iterations, backward_scale=backward_scale, alpha=alpha, sampling=sampling)
    _, _, height, width = color.shape
    # Positions, offsets and the blended image in float32 for a half image (its dtype else).
    x, y = pixel_grid(height, width, color.dtype)
    vx, vy = velocity[:, 0].astype(x.dtype), velocity[:, 1].astype(x.dtype)
    result = color.astype(x.dtype)
    for scale, a in o.schedule:
        along = sample(result, x + scale * vx, y + scale * vy, o.sampling)
        back = o.backward_scale * scale
        against = sample(result, x - back * vx, y - back * vy, o.sampling)
        result = ((1.0 - a) * result + (0.5 * a) * (along + against)).astype(x.dtype)
    return result.astype(color.dtype)
