"""Image metrics on NCHW NumPy arrays and the pictures that go with them.

`psnr` and `ssim` call scikit-image's maintained implementations with `data_range` given
explicitly (never guessed from the data) and average over the batch. `velocity_to_color` draws a
velocity field on a colour wheel (hue = direction, saturation = speed); `error_map_figure` and
`save_error_map` draw |prediction - target|; `linear_to_srgb` and `srgb_to_linear` convert between
the linear colour the ops take and the encoded values of pictures. Figures are made with matplotlib's
object API on the Agg canvas, so no global backend is touched.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from diffblur import checks
from diffblur.conventions import VECTOR_CHANNELS, X_CHANNEL, Y_CHANNEL

__all__ = [
    "color_wheel",
    "error_map_figure",
    "linear_to_srgb",
    "psnr",
    "save_error_map",
    "srgb_to_linear",
    "ssim",
    "to_display",
    "velocity_to_color",
]


def srgb_to_linear(encoded: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] to linear intensities (IEC 61966-2-1)."""
    encoded = np.asarray(encoded, dtype=np.float64)
    return np.where(encoded <= 0.04045, encoded / 12.92, ((encoded + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(linear: np.ndarray) -> np.ndarray:
    """Linear intensities to sRGB-encoded values, clipped to [0, 1] first (for display)."""
    linear = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear ** (1 / 2.4) - 0.055)


def _pair(prediction: Any, target: Any) -> tuple[np.ndarray, np.ndarray]:
    prediction = np.asarray(prediction)
    target = np.asarray(target)
    checks.require_image("prediction", prediction.shape)
    checks.require_image("target", target.shape)
    checks.require_same_shape("prediction", prediction.shape, "target", target.shape)
    checks.require_floating("prediction", prediction.dtype, np.issubdtype(prediction.dtype, np.floating))
    checks.require_floating("target", target.dtype, np.issubdtype(target.dtype, np.floating))
    return prediction.astype(np.float64), target.astype(np.float64)


def _reduce(values: list[float], reduction: str) -> float | np.ndarray:
    checks.require_choice("reduction", reduction, ("mean", "none"))
    return float(np.mean(values)) if reduction == "mean" else np.asarray(values)


def psnr(prediction: Any, target: Any, *, data_range: float = 1.0, reduction: str = "mean") -> float | np.ndarray:
    """Peak signal-to-noise ratio in dB of (B, C, H, W) arrays, per image then averaged over B.

    data_range: the span of valid values (1.0 for linear colour in [0, 1]). reduction: "mean" (a
    float) or "none" (an array of B values). Identical images give inf.
    """
    from skimage.metrics import peak_signal_noise_ratio

    prediction, target = _pair(prediction, target)
    data_range = checks.require_positive_number("data_range", data_range)
    values = []
    for p, t in zip(prediction, target):
        if np.array_equal(p, t):
            values.append(float("inf"))  # skimage divides by a zero MSE (a RuntimeWarning)
        else:
            values.append(float(peak_signal_noise_ratio(t, p, data_range=data_range)))
    return _reduce(values, reduction)


def ssim(
    prediction: Any, target: Any, *, data_range: float = 1.0, win_size: int = 7, reduction: str = "mean"
) -> float | np.ndarray:
    """Structural similarity of (B, C, H, W) arrays (scikit-image, channels averaged), over B.

    data_range: span of valid values; win_size: odd side of the square window, <= H and W.
    """
    from skimage.metrics import structural_similarity

    prediction, target = _pair(prediction, target)
    data_range = checks.require_positive_number("data_range", data_range)
    win_size = checks.require_odd_int("win_size", win_size)
    height, width = target.shape[2:]
    if win_size > min(height, width):
        raise ValueError(f"win_size must be <= min(H, W) = {min(height, width)}, got {win_size}")
    values = []
    for p, t in zip(prediction, target):
        values.append(
            float(
                structural_similarity(
                    t.transpose(1, 2, 0),
                    p.transpose(1, 2, 0),
                    data_range=data_range,
                    win_size=win_size,
                    channel_axis=-1,
                )
            )
        )
    return _reduce(values, reduction)


def to_display(color: Any) -> np.ndarray:
    """Linear (B, C, H, W) colour to displayable sRGB (B, H, W, C) in [0, 1] (C = 1 or 3)."""
    color = np.asarray(color, dtype=np.float64)
    checks.require_image("color", color.shape)
    return linear_to_srgb(color).transpose(0, 2, 3, 1)


def velocity_to_color(velocity: Any, *, max_magnitude: float | None = None) -> np.ndarray:
    """A velocity field (B, 2, H, W) as colours (B, 3, H, W) in [0, 1] on a colour wheel.

    Hue is the direction (red = +x, rightwards; then, turning towards +y, downwards: yellow, green,
    ...), saturation the speed relative to max_magnitude (pixels; default the field's largest
    speed), so zero is white. Display values (sRGB), not linear colour.
    """
    from matplotlib.colors import hsv_to_rgb

    velocity = np.asarray(velocity, dtype=np.float64)
    checks.require_image("velocity", velocity.shape, channels=VECTOR_CHANNELS)
    vx, vy = velocity[:, X_CHANNEL], velocity[:, Y_CHANNEL]
    speed = np.hypot(vx, vy)
    if max_magnitude is None:
        max_magnitude = float(speed.max()) if speed.max() > 0 else 1.0
    else:
        max_magnitude = checks.require_positive_number("max_magnitude", max_magnitude)
    hue = np.mod(np.arctan2(vy, vx) / (2 * np.pi), 1.0)
    saturation = np.clip(speed / max_magnitude, 0.0, 1.0)
    hsv = np.stack([hue, saturation, np.ones_like(hue)], axis=-1)
    return hsv_to_rgb(hsv).transpose(0, 3, 1, 2)


def color_wheel(size: int = 64) -> np.ndarray:
    """The legend of `velocity_to_color`: (1, 3, size, size), the wheel for speeds up to the radius."""
    size = checks.require_positive_int("size", size)
    c = (size - 1) / 2
    y, x = np.mgrid[0:size, 0:size].astype(np.float64)
    field = np.stack([x - c, y - c])[None]
    wheel = velocity_to_color(field, max_magnitude=max(c, 1.0))
    outside = np.hypot(x - c, y - c) > c
    wheel[:, :, outside] = 1.0
    return wheel


def error_map_figure(
    prediction: Any,
    target: Any,
    *,
    vmax: float | None = None,
    titles: tuple[str, str] = ("prediction", "target"),
    data_range: float = 1.0,
) -> Any:
    """A matplotlib Figure: per image of the batch (rows), prediction, target and the error map
    mean_c |prediction - target| (linear units; colour scale 0 .. vmax, default the largest error),
    titled with PSNR and SSIM. Save it with fig.savefig(path)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    prediction, target = _pair(prediction, target)
    error = np.abs(prediction - target).mean(axis=1)
    if vmax is None:
        vmax = float(error.max()) if error.max() > 0 else 1.0
    else:
        vmax = checks.require_positive_number("vmax", vmax)
    batch = prediction.shape[0]
    fig = Figure(figsize=(9, 3 * batch), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(batch, 3, squeeze=False)
    shown_p, shown_t = to_display(prediction), to_display(target)
    min_side = min(target.shape[2:])
    for b in range(batch):
        p_db = psnr(prediction[b : b + 1], target[b : b + 1], data_range=data_range)
        win = min(7, min_side if min_side % 2 else min_side - 1)
        s = float("nan")
        if win >= 3:
            s = ssim(prediction[b : b + 1], target[b : b + 1], data_range=data_range, win_size=win)
        for ax, image, title in ((axes[b, 0], shown_p[b], titles[0]), (axes[b, 1], shown_t[b], titles[1])):
            ax.imshow(image.squeeze(), cmap="gray" if image.shape[-1] == 1 else None, vmin=0, vmax=1)
            ax.set_title(title)
            ax.axis("off")
        im = axes[b, 2].imshow(error[b], cmap="magma", vmin=0, vmax=vmax)
        axes[b, 2].set_title(f"|error|: PSNR {p_db:.2f} dB, SSIM {s:.4f}")
        axes[b, 2].axis("off")
        fig.colorbar(im, ax=axes[b, 2], fraction=0.046)
    return fig


def save_error_map(path: str | os.PathLike, prediction: Any, target: Any, **options: Any) -> str:
    """Draw `error_map_figure(prediction, target, **options)` to a PNG at path; returns the path."""
    fig = error_map_figure(prediction, target, **options)
    fig.savefig(os.fspath(path), dpi=100)
    return os.fspath(path)
