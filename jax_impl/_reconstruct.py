"""Seed 000's reconstruction filter (Listing 1) as a batched, differentiable JAX op."""

from __future__ import annotations


import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from diffblur import checks, reference
from diffblur.conventions import (
    DEFAULT_MAX_RADIUS,
    DEFAULT_MIN_RADIUS,
    DEFAULT_RELATIVE_Z_EXTENT,
    DEFAULT_SAMPLES,
    DEFAULT_SHUTTER,
    DEPTH_CHANNELS,
    EARLY_OUT_SPEED,
    JITTER_MODES,
    VECTOR_CHANNELS,
)
from diffblur.shutters import ShutterWindow
from diffblur.taps import reconstruct_options, reconstruct_tap_time, shutter_factor
from jax_impl import _checks
from jax_impl._primitives import (
    _cone,
    _cylinder,
    _safe_length,
    _soft_depth_compare,
    neighbor_max,
    tile_max,
)
from jax_impl._pyramid import Pyramid
from jax_impl._sampling import pixel_grid, position_dtype, sample, widen_window


def _at_least(speed, floor: float):
    return jnp.where(speed < floor, floor, speed).astype(speed.dtype)


def _jitter_array(jitter: str | Array, color: Array) -> Array:
    """The per-pixel jitter j in [-0.5, 0.5), (B or 1, 1, H, W)."""
    batch, _, height, width = color.shape
    if isinstance(jitter, str):
        checks.require_choice("jitter", jitter, JITTER_MODES)
        if jitter == "none":
            return jnp.zeros((1, 1, height, width), dtype=color.dtype)
        return jnp.asarray(reference.noise_jitter(height, width).astype(color.dtype)).reshape(1, 1, height, width)
    jitter = _checks.image("jitter", jitter, channels=1)
    checks.require_same_batch_and_size("color", color.shape, [("jitter", jitter.shape)])
    _checks.same_dtype("jitter", jitter, "color", color)
    return jitter


def reconstruct(
    color: Float[Array, "b c h w"],
    velocity: Float[Array, "b 2 h w"],
    depth: Float[Array, "b 1 h w"],
    *,
    max_radius: float = DEFAULT_MAX_RADIUS,
    samples: int = DEFAULT_SAMPLES,
    soft_z_extent: float | None = None,
    relative_z_extent: float = DEFAULT_RELATIVE_Z_EXTENT,
    jitter: str | Array = "noise",
    sampling: str = "bilinear",
    shutter: str | ShutterWindow = DEFAULT_SHUTTER,
    early_out: bool | None = None,
    directions: str = "neighbor",
    min_radius: float = DEFAULT_MIN_RADIUS,
    adaptive: bool | tuple[int, ...] = False,
    pyramid: bool = False,
    fused: bool | None = None,
) -> Float[Array, "b c h w"]:
    """Seed 000's reconstruction filter: plausible motion blur from color, velocity and depth.

    TileMax and NeighborMax over tiles of ceil(max_radius) pixels give each pixel X the dominant
    velocity v_N of its neighbourhood; S - 1 taps Y = X + v_N t, t = mix(-1, 1, (i + j + 1) / (S + 1)),
    with the whole filter jittered by j, are classified by soft_depth_compare, cone and cylinder
    (blurry Y in front of X; Y behind blurry X; both blurry) and averaged with X itself, whose
    weight is 1 / |V[X]|. Each tap also carries the shutter's weight at exposure time -t (1 for
    the box, which reproduces the paper).

    Args:
        color: (B, C, H, W) linear intensities, any C.
        velocity: (B, 2, H, W) half-spread velocity in pixels, usually `velocity_from_motion`'s
            output (lengths in [0.5, max_radius]); longer vectors are not clamped here, but
            neighbours farther than one tile are not gathered.
        depth: (B, 1, H, W) positive depth, larger = farther.
        max_radius: the largest blur radius k in pixels; tiles are ceil(k) pixels.
        samples: taps S, an odd integer >= 1.
        soft_z_extent: depth band of soft_depth_compare in depth units, a number > 0; None
            (default): the band relative to depth, `relative_z_extent`.
        relative_z_extent: with soft_z_extent=None, the band as a fraction of depth, > 0: Y counts
            as in front of X up to z_Y = z_X (1 + relative_z_extent), fading linearly in log depth,
            so that the output does not depend on the scene's depth units.
        jitter: "noise" (interleaved gradient noise, deterministic), "none", or a (B, 1, H, W)
            array with values in [-0.5, 0.5].
        sampling: "bilinear" (differentiable through the tap positions) or "nearest" (the paper).
        shutter: a window name or `ShutterWindow` (its parameters may be arrays to fit).
        early_out: return C[X] where |v_N| <= EARLY_OUT_SPEED (0.501 px), as the paper does. None (default)
            turns it on for "nearest" only: on the differentiable path it would zero the gradient
            of a velocity that starts small.
        directions: "neighbor" (the paper) or "neighbor_and_own": odd taps along V[X] instead
            (seed 000 sec. 4.3), for neighbourhoods with more than one motion.
        min_radius: speeds |V| below it count as min_radius px (seed 000 sec. 2.2 clamps the
            velocity buffer to at least 0.5 px), so a still pixel has centre weight 1 / min_radius
            rather than an infinite one that would keep blurry foregrounds from covering it.
        adaptive: tiled adaptive sampling (seed 001) with the still-tile early-out: each tile's
            |NeighborMax| picks the fewest taps among a few classes that give one tap per pixel
            travelled (True: 3, 7, 15, ... up to samples; or a tuple of odd counts), and still
            tiles (|NeighborMax| <= 0.001 px, or the early-out's 0.5 px when early_out is on)
            return the image. Tiles of the full-rate class get the full-rate result. On the fused
            path (see `fused`) each tile takes its class's taps inside the kernel, eagerly and
            under jax.jit. On the tensor ops each class runs on its tiles' pixels only in eager
            mode; under compilation every class runs on every pixel and is selected per tile
            (same result, no saving).
        pyramid: where the taps are farther apart than a pixel (2 |v| / (samples + 1) > 1 along
            the tap direction v), read the taps' colour from a pre-filtered pyramid level (seed
            001's texture-space blur), trilinearly; depth and velocity stay full resolution.
            Needs "bilinear"; not combined with adaptive yet.
        fused: run the filter and its backward in one parallel CPU loop (`diffblur.kernels.reconstruct`, numba,
            through `jax.pure_callback`, also under `jax.jit`) instead of jax.numpy ops: same
            result and gradients (tested), faster on the CPU (timings: docs/fused.md). None (default): fused
            where it applies (CPU backend, float32/float64, bilinear, box shutter, no pyramid;
            adaptive sampling included), jax.numpy ops elsewhere. True: fused or a ValueError
            saying why not. False: always the jax.numpy ops. The fused path has reverse-mode
            gradients only (a custom_vjp): forward mode (jax.jvp, jacfwd, optimistix's
            jac="fwd") needs fused=False. jitter gets no gradient on it.

    Returns:
        (B, C, H, W), color's dtype.
    """
    color = _checks.image("color", color)
    velocity = _checks.image("velocity", velocity, channels=VECTOR_CHANNELS)
    depth = _checks.image("depth", depth, channels=DEPTH_CHANNELS)
    checks.require_same_batch_and_size("color", color.shape, [("velocity", velocity.shape), ("depth", depth.shape)])
    _checks.same_dtype("velocity", velocity, "color", color)
    _checks.same_dtype("depth", depth, "color", color)
    velocity = _checks.finite_values("velocity", velocity)
    depth = _checks.finite_values("depth", _checks.positive_values("depth", depth))
    depth = _checks.finite_values("color", color, carry=depth)
    o = reconstruct_options(
        max_radius=max_radius,
        samples=samples,
        soft_z_extent=soft_z_extent,
        relative_z_extent=relative_z_extent,
        sampling=sampling,
        shutter=shutter,
        early_out=early_out,
        directions=directions,
        min_radius=min_radius,
        adaptive=adaptive,
        pyramid=pyramid,
    )
    jitter = _jitter_array(jitter, color)
    if o.log_depth:  # the band relative to depth: compare log depths (`diffblur.checks.depth_band`)
        depth = jnp.log(depth)
    if fused is not False:
        from diffblur.kernels.shared import use_fused
        from jax_impl._fused import fused_reconstruct, unfused_reason

        if use_fused("reconstruct", fused, unfused_reason(o, color)):
            return fused_reconstruct(color, velocity, depth, jitter, o)
    if o.classes is not None:
        from jax_impl._adaptive import adaptive_reconstruct

        return adaptive_reconstruct(color, velocity, depth, jitter, o)
    return _reconstruct(
        color, velocity, depth, o.tile, o.samples, o.soft_z_extent, jitter, o.sampling, o.window, o.early_out, o.directions, o.min_radius, pyramid=o.pyramid
    )


def _reconstruct(color, velocity, depth, tile, samples, soft_z_extent, jitter, sampling, window, early_out, directions, min_radius, *, pyramid=False):
    _, channels, height, width = color.shape
    # Positions, tap offsets, the classifiers' weights and the sums in float32 for a half image (in
    # its dtype else); the buffers read stay in the image's dtype, the values read are widened.
    wide = position_dtype(color.dtype)
    window = widen_window(window, wide)
    neighbors = neighbor_max(tile_max(velocity, tile))
    v_n = jnp.repeat(jnp.repeat(neighbors, tile, axis=2), tile, axis=3)[:, :, :height, :width].astype(wide)
    speed_n = _safe_length(v_n)
    own_velocity = velocity.astype(wide)
    length_x = _safe_length(own_velocity)  # the tap offset along V[X] is |t| |V[X]|
    speed_x = _at_least(length_x, min_radius)  # the classifiers' speed, floored as the paper's buffer
    x, y = pixel_grid(height, width, color.dtype)
    x, y = x[:, None], y[:, None]
    buffers = jnp.concatenate([color, velocity, depth], axis=1)  # read C, V and Z at a tap in one gather
    jitter, wide_depth = jitter.astype(wide), depth.astype(wide)
    levels = Pyramid(color) if pyramid else None

    taps = jnp.asarray([k for k in range(samples) if k != (samples - 1) // 2], dtype=jnp.int32)

    # Recompute each tap in the backward pass instead of keeping its full-resolution intermediates,
    # and loop with scan (not unrolled): the backward's memory then stays O(pixels), not
    # O(pixels x taps). The accumulation is a sum, so its VJP needs none of the carries.
    @jax.checkpoint
    def tap(k, buffers, depth, v_n, speed_n, velocity, length_x, speed_x, jitter):
        """Tap k's weight alpha and alpha * C[Y], (B, 1, H, W) and (B, C, H, W)."""
        t = reconstruct_tap_time(k.astype(wide), jitter, samples).astype(wide)
        if directions == "neighbor_and_own":
            own = k % 2 == 1
            direction, speed = jnp.where(own, velocity, v_n), jnp.where(own, length_x, speed_n)
        else:
            direction, speed = v_n, speed_n
        tap_x = x + direction[:, :1] * t
        tap_y = y + direction[:, 1:] * t
        read = sample(buffers, tap_x[:, 0], tap_y[:, 0], sampling)
        if sampling == "nearest":
            distance = jnp.hypot(jnp.floor(tap_x + 0.5) - x, jnp.floor(tap_y + 0.5) - y)
        else:
            distance = jnp.abs(t) * speed
        c_y, v_y, z_y = read[:, :channels], read[:, channels : channels + 2], read[:, channels + 2 :]
        if levels is not None:  # the colour from the pyramid level that matches the tap spacing
            c_y = levels.sample(tap_x[:, 0], tap_y[:, 0], levels.level_of_detail(2.0 * speed[:, 0] / (samples + 1)))
        speed_y = _at_least(_safe_length(v_y), min_radius)
        alpha = (
            _soft_depth_compare(depth, z_y, soft_z_extent) * _cone(distance, speed_y)  # blurry Y in front of any X
            + _soft_depth_compare(z_y, depth, soft_z_extent) * _cone(distance, speed_x)  # any Y behind blurry X
            + _cylinder(distance, speed_y) * _cylinder(distance, speed_x) * 2.0  # both blurry
        ) * shutter_factor(window, -t, samples, jnp)
        return alpha.astype(wide), (alpha * c_y).astype(wide)

    def accumulate(carry, k):
        weight, total = carry
        alpha, contribution = tap(k, buffers, wide_depth, v_n, speed_n, own_velocity, length_x, speed_x, jitter)
        return (weight + alpha, total + contribution), None

    center = shutter_factor(window, jnp.zeros((), dtype=wide), samples, jnp)
    weight = (center / speed_x).astype(wide)
    total = weight * color.astype(wide)
    if samples > 1:
        (weight, total), _ = jax.lax.scan(accumulate, (weight, total), taps)
    # In float32 for the half types (weight and total are): the backward divides by weight**2, and
    # a weight of 1 / |V| (1e-4 at 1e4 px) squares to 0 in float16, an infinite gradient.
    out = total / weight
    if early_out:
        out = jnp.where(speed_n <= EARLY_OUT_SPEED, color.astype(wide), out)
    return out.astype(color.dtype)
