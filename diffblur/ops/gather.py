"""`gather_blur`: the per-pixel gather of seed 001 (Rosado 2007): each pixel averages the image along
its own velocity, weighted by the shutter. Options, docstring and math, for both frameworks."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from diffblur import checks
from diffblur.conventions import DEFAULT_SAMPLES, DEFAULT_SHUTTER, SAMPLING_MODES, STILL_SPEED, VECTOR_CHANNELS
from diffblur.ops import adaptive
from diffblur.ops._options import OpOptions, impl_option, takes_kernel
from diffblur.ops.primitives import safe_length, tile_max
from diffblur.ops.pyramid import Pyramid
from diffblur.ops.sampling import pixel_grid, position_dtype, sample
from diffblur.ops.taps import gather_tap_times, stratum_weights
from diffblur.shutters import ShutterWindow, get_shutter

__all__ = ["DOC", "GatherOptions", "gather_blur"]


@dataclasses.dataclass(frozen=True)
class GatherOptions(OpOptions):
    """gather_blur's options, checked; `window` and `classes` resolved from them."""

    samples: int = DEFAULT_SAMPLES
    shutter: str | ShutterWindow = DEFAULT_SHUTTER
    sampling: str = "bilinear"
    adaptive: bool | tuple[int, ...] = False
    impl: str = "auto"
    window: ShutterWindow = dataclasses.field(init=False, repr=False)
    #: The sample-count classes of tiled adaptive sampling (`diffblur.ops.adaptive`), None when off.
    classes: tuple[int, ...] | None = dataclasses.field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._resolve("samples", checks.require_odd_int("samples", self.samples))
        self._resolve("sampling", checks.require_choice("sampling", self.sampling, SAMPLING_MODES))
        self._resolve("impl", impl_option(self.impl))
        self._resolve("window", get_shutter(self.shutter))
        self._resolve("classes", adaptive.adaptive_classes(self.adaptive, self.samples))
        if self.sampling == "pyramid" and self.classes is not None:
            raise ValueError(f"sampling='pyramid' does not combine with adaptive sampling yet; got adaptive={self.adaptive!r}")


DOC = """Blur each pixel along its own velocity, weighted by the shutter (seed 001's gather).

    The exposure [-1, 1] is cut into `samples` equal strata with midpoints tau_k; pixel X shows
    C[X - tau_k V[X]] during stratum k, weighted by the shutter's mass on the stratum.

    Args:
        color: (B, C, H, W) linear intensities, any C.
        velocity: (B, 2, H, W) half-spread velocity in pixels (channel 0 = x, 1 = y).
        samples: taps per pixel, an odd integer >= 1 (1 returns the image).
        shutter: a name in `diffblur.shutters.SHUTTERS` or a `ShutterWindow`, whose parameters may be
            arrays to fit.
        sampling: how a tap reads the image. "bilinear" (default; differentiable in velocity),
            "nearest" (the documents' rounding; no gradient through the tap positions), or
            "pyramid": bilinear, but where the taps are farther apart than a pixel (2 |V| / samples
            > 1) from a pre-filtered pyramid level (seed 001's texture-space blur), trilinearly, so
            fewer taps than pixels travelled still give a smooth streak.
        adaptive: tiled adaptive sampling (seed 001): each 16 x 16 tile's largest |V| picks the
            fewest taps among a few classes that give one tap per pixel travelled (True: 3, 7,
            15, ... up to samples; or a tuple of odd counts); tiles with no motion (|V| <= 0.001
            px) return the image. Tiles of the full-rate class get the full-rate result. On the
            fused kernel each tile takes its class's taps inside the kernel, eagerly and compiled.
            On the tensor ops each class runs on its tiles' pixels only in eager mode; under
            torch.compile or jax.jit every class runs on every pixel and is selected per tile (same
            result, no saving). Not with sampling="pyramid".
        impl: "auto" (default): the fused CPU kernel (`diffblur.kernels.gather`, numba: the gather and
            its backward in one parallel loop each) where it applies, the tensor ops elsewhere.
            "fused": the kernel, or a ValueError naming what it does not cover. "tensor": always
            the tensor ops. The kernel covers CPU float32/float64 images, bilinear sampling, every
            shutter, adaptive sampling; in PyTorch eagerly and under torch.compile (custom
            operators), in JAX under jax.jit too (a host callback; reverse mode only: jax.jvp and
            jax.jacfwd need impl="tensor"). Same result and gradients either way (tested); the
            kernel's backward is not differentiable again.

    Returns:
        (B, C, H, W), color's dtype. Positions beyond the border read the border pixel.

    A bright pixel moving 1 px right: the taps sit at the stratum midpoints t = -2/3, 0, 2/3 of V
    and read bilinearly, so the streak is 0.22, 0.56, 0.22.
    """


def gather_blur(be: Any, color: Any, velocity: Any, **options: Any) -> Any:
    """The op: its arguments checked, then the fused kernel or the tensor ops."""
    o = GatherOptions.take("gather_blur", options)
    color = checks.image_array(be, "color", color)
    velocity = checks.image_array(be, "velocity", velocity, channels=VECTOR_CHANNELS)
    checks.require_same_batch_and_size("color", color.shape, [("velocity", velocity.shape)])
    checks.same_dtype_and_device(be, "velocity", velocity, "color", color)
    velocity = be.check_finite("velocity", velocity)
    velocity = be.check_finite("color", color, carry=velocity)
    if o.impl != "tensor" and takes_kernel("gather_blur", o.impl, be.kernel_reason("gather_blur", color, o)):
        return be.run_kernel("gather_blur", color, velocity, o)
    if o.classes is not None:
        return _adaptive_gather(be, color, velocity, o)
    return _gather(be, color, velocity, o.samples, o.window, o.sampling)


def _masses(be: Any, window: ShutterWindow, samples: int, like: Any) -> Any:
    """The shutter's mass on each of the `samples` strata, renormalised to sum to 1, in `like`'s dtype."""
    times = be.asarray(gather_tap_times(samples), like.dtype, like)
    masses = stratum_weights(be.widen_window(window, like.dtype), times, 1.0 / samples, be.xp)
    return be.astype(masses / masses.sum(), like.dtype)


def _gather(be: Any, color: Any, velocity: Any, samples: int, window: ShutterWindow, sampling: str) -> Any:
    """The full-image gather by tensor ops. Positions, tap offsets, weights and the sum in float32
    for a half image (its dtype else)."""
    _, _, height, width = color.shape
    x, y = pixel_grid(be, height, width, color)
    velocity = be.astype(velocity, x.dtype)
    masses = _masses(be, window, samples, x)
    if sampling == "pyramid":
        levels = Pyramid(be, color)
        lod = levels.level_of_detail(2.0 * safe_length(be, velocity)[:, 0] / samples)
        read = lambda px, py: levels.sample(px, py, lod)  # noqa: E731
    else:
        read = lambda px, py: sample(be, color, px, py, sampling)  # noqa: E731
    out = be.xp.zeros_like(color, dtype=x.dtype)
    for k, tau in enumerate(gather_tap_times(samples)):
        out = out + masses[k] * read(x - tau * velocity[:, 0], y - tau * velocity[:, 1])
    return be.astype(out, color.dtype)


def _adaptive_gather(be: Any, color: Any, velocity: Any, o: GatherOptions) -> Any:
    """gather_blur with tiled adaptive sampling (tiles of ADAPTIVE_TILE px, speed = max |V|)."""
    batch, _, height, width = color.shape
    tile = adaptive.ADAPTIVE_TILE
    speed = safe_length(be, tile_max(be, be.stop_gradient(velocity), tile))[:, 0]
    concrete = be.values(speed)
    if concrete is None:  # compiled: every class on every pixel, selected per tile
        counts = adaptive.tile_sample_counts(speed, o.classes, STILL_SPEED, be.xp)
        full = {c: _gather(be, color, velocity, c, o.window, o.sampling) for c in o.classes}
        return adaptive.select(be, color, full, adaptive.pixel_counts(be, counts, tile, height, width))
    found = adaptive.class_rows(be, adaptive.tile_sample_counts(concrete, o.classes, STILL_SPEED, np), o.classes, tile, color)
    if not found:
        return color
    wide = position_dtype(be, color.dtype)
    masses = tuple(_masses(be, o.window, rows.count, be.zeros((), wide, color)) for rows in found)
    run = adaptive.compiled_if_worth(be, _gather_compacted, found, ("be", "counts", "sampling"))
    return run(be, color, velocity, masses, tuple(r.read for r in found), tuple(r.write for r in found), counts=tuple(r.count for r in found), sampling=o.sampling)


def _gather_compacted(be: Any, color: Any, velocity: Any, masses: tuple, reads: tuple, writes: tuple, *, counts: tuple[int, ...], sampling: str) -> Any:
    """Each class's gather on its pixels only, written into the image (the full-image gather's
    arithmetic on a flat list of pixels, so a full-rate tile gets the same values)."""
    batch, _, height, width = color.shape
    color_table, velocity_table = adaptive.table(be, color), adaptive.table(be, velocity)
    out = color_table
    for count, mass, read, write in zip(counts, masses, reads, writes):
        base, x, y = adaptive.coordinates(be, read, height, width, color.dtype)  # float32 for a half image
        v = be.astype(velocity_table[read], x.dtype)
        values = be.zeros((read.shape[0], color_table.shape[1]), x.dtype, color)
        for k, tau in enumerate(gather_tap_times(count)):
            values = values + mass[k] * adaptive.sample_rows(be, color_table, base, x - tau * v[:, 0], y - tau * v[:, 1], height, width, sampling)
        out = be.write_rows(out, write, be.astype(values, out.dtype))
    return adaptive.untable(be, out, batch, height, width)
