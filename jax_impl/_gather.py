"""The per-pixel gather of seed 001 (Rosado 2007): each pixel averages the image along its own velocity."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from diffblur import checks
from diffblur._adaptive import adaptive_classes
from diffblur._pyramid import pyramid_option
from diffblur.conventions import DEFAULT_SAMPLES, DEFAULT_SHUTTER, SAMPLING_MODES, VECTOR_CHANNELS
from diffblur.shutters import ShutterWindow, get_shutter
from diffblur.taps import gather_tap_times, stratum_weights
from jax_impl import _checks
from jax_impl._primitives import _safe_length
from jax_impl._pyramid import Pyramid
from jax_impl._sampling import pixel_grid, position_dtype, sample, widen_window


def gather_blur(
    color: Float[Array, "b c h w"],
    velocity: Float[Array, "b 2 h w"],
    *,
    samples: int = DEFAULT_SAMPLES,
    shutter: str | ShutterWindow = DEFAULT_SHUTTER,
    sampling: str = "bilinear",
    adaptive: bool | tuple[int, ...] = False,
    pyramid: bool = False,
    fused: bool | None = None,
) -> Float[Array, "b c h w"]:
    """Blur each pixel along its own velocity, weighted by the shutter (seed 001's gather).

    The exposure [-1, 1] is cut into `samples` equal strata with midpoints tau_k; pixel X shows
    C[X - tau_k V[X]] during stratum k, weighted by the shutter's mass on the stratum.

    Args:
        color: (B, C, H, W) linear intensities, any C.
        velocity: (B, 2, H, W) half-spread velocity in pixels (channel 0 = x, 1 = y).
        samples: taps per pixel, an odd integer >= 1 (1 returns the image).
        shutter: a name in `diffblur.shutters.SHUTTERS` or a `ShutterWindow`, whose parameters may be
            arrays to fit.
        sampling: "bilinear" (differentiable in velocity) or "nearest" (the documents' rounding).
        adaptive: tiled adaptive sampling (seed 001): each 16 x 16 tile's largest |V| picks the
            fewest taps among a few classes that give one tap per pixel travelled (True: 3, 7,
            15, ... up to samples; or a tuple of odd counts); tiles with no motion (|V| <= 0.001
            px) return the image. Tiles of the full-rate class get the full-rate result. On the
            fused path (see `fused`) each tile takes its class's taps inside the kernel, eagerly
            and under jax.jit. On the jax.numpy ops each class runs on its tiles' pixels only in
            eager mode; under compilation every class runs on every pixel and is selected per
            tile (same result, no saving).
        pyramid: where the taps are farther apart than a pixel (2 |V| / samples > 1), read the
            colour from a pre-filtered pyramid level (seed 001's texture-space blur), trilinearly,
            so fewer taps than pixels travelled still give a smooth streak; needs "bilinear".
        fused: run the gather and its backward in one parallel CPU loop (`diffblur.kernels.gather`,
            numba, through `jax.pure_callback` and a `custom_vjp`) instead of jax.numpy ops: same
            result and gradients (tested, the shutter's parameters included). None (default):
            fused where it applies (CPU backend, float32/float64, bilinear, no pyramid; any
            shutter, adaptive sampling included), jax.numpy ops elsewhere. True: fused or a
            ValueError saying why not. False: always the jax.numpy ops. The fused path has
            reverse-mode derivatives only: forward mode (jvp, jacfwd, optimistix's
            jac="fwd") needs fused=False.

    Returns:
        (B, C, H, W), color's dtype. Positions beyond the border read the border pixel.

    A bright pixel moving 1 px right: the taps sit at the stratum midpoints t = -2/3, 0, 2/3 of V
    and read bilinearly, so the streak is 0.22, 0.56, 0.22.

    >>> import jax.numpy as jnp
    >>> color = jnp.array([0.0, 0.0, 1.0, 0.0, 0.0]).reshape(1, 1, 1, 5)
    >>> velocity = jnp.zeros((1, 2, 1, 5)).at[:, 0].set(1.0)
    >>> gather_blur(color, velocity, samples=3).round(4).tolist()
    [[[[0.0, 0.2222, 0.5556, 0.2222, 0.0]]]]
    """
    color = _checks.image("color", color)
    velocity = _checks.image("velocity", velocity, channels=VECTOR_CHANNELS)
    checks.require_same_batch_and_size("color", color.shape, [("velocity", velocity.shape)])
    _checks.same_dtype("velocity", velocity, "color", color)
    velocity = _checks.finite_values("velocity", velocity)
    velocity = _checks.finite_values("color", color, carry=velocity)
    samples = checks.require_odd_int("samples", samples)
    sampling = checks.require_choice("sampling", sampling, SAMPLING_MODES)
    window = get_shutter(shutter)
    classes = adaptive_classes(adaptive, samples)
    pyramid = pyramid_option(pyramid, adaptive, sampling)
    if fused is not False:
        from diffblur.kernels.shared import use_fused
        from jax_impl._fused import fused_gather, gather_unfused_reason

        if use_fused("gather_blur", fused, gather_unfused_reason(color, sampling, pyramid)):
            return fused_gather(color, velocity, window, samples, classes, position_dtype(color.dtype))
    if classes is not None:
        from jax_impl._adaptive import adaptive_gather

        return adaptive_gather(color, velocity, classes, window, sampling)
    # Positions, tap offsets, weights and the sum in float32 for a half image (its dtype else).
    wide = position_dtype(color.dtype)
    times = gather_tap_times(samples)
    masses = stratum_weights(widen_window(window, wide), jnp.asarray(times, dtype=wide), 1.0 / samples, jnp)
    masses = (masses / masses.sum()).astype(wide)
    _, _, height, width = color.shape
    x, y = pixel_grid(height, width, color.dtype)
    velocity = velocity.astype(wide)
    read = lambda px, py: sample(color, px, py, sampling)  # noqa: E731
    if pyramid:
        levels = Pyramid(color)
        lod = levels.level_of_detail(2.0 * _safe_length(velocity)[:, 0] / samples)
        read = lambda px, py: levels.sample(px, py, lod)  # noqa: E731
    out = jnp.zeros_like(color, dtype=wide)
    for k, tau in enumerate(times):
        out = out + masses[k] * read(x - tau * velocity[:, 0], y - tau * velocity[:, 1])
    return out.astype(color.dtype)
