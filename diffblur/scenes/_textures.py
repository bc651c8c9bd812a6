"""Layer textures: photographs (scikit-image's bundled ones), procedural patterns, shape masks.

A texture is a function of the layer coordinates X0 (a point's image position at t = 0, pixels) to a
premultiplied colour and a coverage alpha. `ImageTexture` stores texels one pixel apart, so at t = 0
the pixel centres fall exactly on texels and the sharp frame reproduces the texture; in between the
scene is the bilinear interpolant (that continuous image is what the ground truth integrates).
Colours are linear (photographs are decoded from sRGB).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from diffblur.metrics import srgb_to_linear

__all__ = [
    "FunctionTexture",
    "ImageTexture",
    "checkers",
    "coverage",
    "photo",
    "stripes",
]

PHOTOS = ("astronaut", "coffee", "chelsea", "rocket", "camera")


@functools.lru_cache(maxsize=8)
def _photo_linear(name: str) -> np.ndarray:
    import skimage.data

    image = getattr(skimage.data, name)()
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    image = srgb_to_linear(image[:, :, :3] / 255.0)
    image.setflags(write=False)
    return image


def photo(
    name: str, height: int, width: int, *, zoom: float = 1.0, focus: tuple[float, float] = (0.5, 0.5)
) -> np.ndarray:
    """A scikit-image photograph, linear RGB, (height, width, 3) float64 in [0, 1].

    The largest crop of the photograph with the target's aspect ratio, shrunk by `zoom` (>= 1 crops
    tighter) around `focus` (fractions of the photograph's width and height), resized with
    anti-aliasing. Loads offline: these photographs ship with scikit-image.
    """
    from skimage.transform import resize

    if name not in PHOTOS:
        raise ValueError(f"photo must be one of {', '.join(repr(p) for p in PHOTOS)}; got {name!r}")
    image = _photo_linear(name)
    ph, pw = image.shape[:2]
    aspect = width / height
    crop_h = min(ph, pw / aspect) / zoom
    crop_w = crop_h * aspect
    top = int(round(np.clip(focus[1] * ph - crop_h / 2, 0, ph - crop_h)))
    left = int(round(np.clip(focus[0] * pw - crop_w / 2, 0, pw - crop_w)))
    crop = image[top : top + int(round(crop_h)), left : left + int(round(crop_w))]
    return resize(crop, (height, width, 3), order=1, anti_aliasing=True, mode="edge")


def _grid(height: int, width: int, origin: tuple[float, float], supersample: int) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel sample positions of a (height, width) raster whose texel (0, 0) sits at `origin`."""
    offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
    ys = origin[1] + np.arange(height)[:, None] + offsets[None, :]
    xs = origin[0] + np.arange(width)[:, None] + offsets[None, :]
    return xs.reshape(-1), ys.reshape(-1)


def coverage(
    inside: Callable[[np.ndarray, np.ndarray], np.ndarray],
    height: int,
    width: int,
    *,
    origin: tuple[float, float] = (0.0, 0.0),
    supersample: int = 4,
) -> np.ndarray:
    """Anti-aliased coverage of a shape: the fraction of supersample^2 sub-pixel points inside.

    inside(x, y) -> bool array takes image coordinates (pixels) of broadcastable arrays. Returns
    (height, width) float64 in [0, 1]; texel (i, j) is centred at (origin x + j, origin y + i).
    """
    xs, ys = _grid(height, width, origin, supersample)
    hit = inside(xs[None, :], ys[:, None]).astype(np.float64)
    return hit.reshape(height, supersample, width, supersample).mean(axis=(1, 3))


def _smooth_pattern(
    value: Callable[[np.ndarray, np.ndarray], np.ndarray], height: int, width: int, origin: tuple[float, float]
) -> np.ndarray:
    return coverage(lambda x, y: value(x, y) > 0, height, width, origin=origin, supersample=4)


def checkers(
    height: int,
    width: int,
    period: float,
    color_a: tuple[float, float, float],
    color_b: tuple[float, float, float],
    *,
    angle: float = 0.0,
    origin: tuple[float, float] = (0.0, 0.0),
) -> np.ndarray:
    """Anti-aliased checkerboard, (height, width, 3) linear RGB; squares of side period / 2 pixels."""
    cos, sin = np.cos(angle), np.sin(angle)

    def value(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        u, v = cos * x + sin * y, -sin * x + cos * y
        return np.sin(2 * np.pi * u / period) * np.sin(2 * np.pi * v / period)

    mix = _smooth_pattern(value, height, width, origin)[:, :, None]
    return mix * np.asarray(color_a) + (1 - mix) * np.asarray(color_b)


def stripes(
    height: int,
    width: int,
    period: float,
    color_a: tuple[float, float, float],
    color_b: tuple[float, float, float],
    *,
    angle: float = 0.0,
    origin: tuple[float, float] = (0.0, 0.0),
) -> np.ndarray:
    """Anti-aliased stripes across the direction `angle` (radians from +x), period in pixels."""
    cos, sin = np.cos(angle), np.sin(angle)
    mix = _smooth_pattern(lambda x, y: np.sin(2 * np.pi * (cos * x + sin * y) / period), height, width, origin)
    return mix[:, :, None] * np.asarray(color_a) + (1 - mix[:, :, None]) * np.asarray(color_b)


@dataclass(frozen=True, eq=False)
class ImageTexture:
    """Texels one pixel apart; texel (i, j) sits at layer coordinates (origin x + j, origin y + i).

    color: (Ht, Wt, 3) linear RGB; alpha: (Ht, Wt) coverage in [0, 1], or None for opaque. Sampling is
    bilinear on premultiplied colour, clamped to the border texels outside: give an object layer a
    transparent border (`pad` does) so that outside it is transparent.
    """

    color: np.ndarray
    alpha: np.ndarray | None = None
    origin: tuple[int, int] = (0, 0)

    def __post_init__(self) -> None:
        color = np.asarray(self.color, dtype=np.float64)
        if color.ndim != 3 or color.shape[2] != 3 or min(color.shape[:2]) < 2:
            raise ValueError(f"color must be (Ht, Wt, 3) with Ht, Wt >= 2, got shape {color.shape}")
        if self.alpha is None:
            alpha = np.ones(color.shape[:2])
        else:
            alpha = np.asarray(self.alpha, dtype=np.float64)
            if alpha.shape != color.shape[:2]:
                raise ValueError(f"alpha must have shape {color.shape[:2]}, got {alpha.shape}")
        planes = np.concatenate([(color * alpha[:, :, None]).transpose(2, 0, 1), alpha[None]], axis=0)
        object.__setattr__(self, "_planes", np.ascontiguousarray(planes))
        object.__setattr__(self, "_opaque", bool(np.all(alpha == 1.0)))
        object.__setattr__(self, "origin", (int(self.origin[0]), int(self.origin[1])))
        rows, cols = np.nonzero(alpha > 0)
        if len(rows):
            ox, oy = self.origin
            # Bilinear taps reach one texel beyond the last covered one.
            bounds = (ox + cols.min() - 1.0, ox + cols.max() + 1.0, oy + rows.min() - 1.0, oy + rows.max() + 1.0)
        else:
            bounds = (0.0, -1.0, 0.0, -1.0)
        object.__setattr__(self, "_bounds", bounds)

    @property
    def opaque(self) -> bool:
        return self._opaque  # type: ignore[attr-defined]

    @property
    def planes(self) -> np.ndarray:
        """(4, Ht, Wt): premultiplied colour and alpha, channel first."""
        return self._planes  # type: ignore[attr-defined]

    def bounds(self) -> tuple[float, float, float, float] | None:
        """(x_min, x_max, y_min, y_max) of the layer points that can show, None if opaque (everywhere)."""
        return None if self.opaque else self._bounds  # type: ignore[attr-defined]

    def support(self) -> tuple[np.ndarray, np.ndarray]:
        """Layer coordinates (x, y) of the texels with alpha > 0, flattened."""
        rows, cols = np.nonzero(self.planes[3] > 0)
        return cols + float(self.origin[0]), rows + float(self.origin[1])

    def sample(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Bilinear premultiplied colour (3, ...) and alpha (...) at layer coordinates x, y (equal
        shapes), clamped to the border texels; alpha is None for an opaque texture."""
        from scipy.ndimage import map_coordinates  # scipy ships with scikit-image

        coords = np.stack([y - self.origin[1], x - self.origin[0]])
        channels = 3 if self.opaque else 4
        out = np.empty((channels,) + x.shape)
        for c in range(channels):
            # order=1 is plain bilinear interpolation (no spline prefilter); 'nearest' clamps.
            map_coordinates(self.planes[c], coords, output=out[c], order=1, mode="nearest")
        return out[:3], (None if self.opaque else out[3])


@dataclass(frozen=True, eq=False)
class FunctionTexture:
    """An analytic texture: fn(x, y) -> (color (..., 3) linear RGB, alpha (...)) at layer coordinates.

    Sampled at points (no filtering): a hard-edged shape stays hard-edged, as the analytic orbiting
    disk of seed 004 needs. support_points (x (N,), y (N,)), pixels: layer points spaced at most one
    pixel apart covering everything with alpha > 0; they bound the layer's footprint and set the
    instant rule. opaque: alpha is 1 everywhere (then the points are not used for bounds).
    """

    fn: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
    support_points: tuple[np.ndarray, np.ndarray]
    opaque: bool = False

    def support(self) -> tuple[np.ndarray, np.ndarray]:
        return self.support_points

    def bounds(self) -> tuple[float, float, float, float] | None:
        if self.opaque:
            return None
        x, y = self.support_points
        if len(x) == 0:
            return (0.0, -1.0, 0.0, -1.0)
        return (float(np.min(x)) - 1.0, float(np.max(x)) + 1.0, float(np.min(y)) - 1.0, float(np.max(y)) + 1.0)

    def sample(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        color, alpha = self.fn(x, y)
        alpha = np.broadcast_to(np.asarray(alpha, dtype=np.float64), x.shape)
        color = np.broadcast_to(np.asarray(color, dtype=np.float64), x.shape + (3,))
        rgb = np.moveaxis(color, -1, 0) * alpha[None]
        return rgb, (None if self.opaque else alpha)


def pad(color: np.ndarray, alpha: np.ndarray, origin: tuple[int, int], border: int = 2) -> ImageTexture:
    """An object texture with a transparent border of `border` texels, so outside it is transparent."""
    color = np.pad(color, ((border, border), (border, border), (0, 0)), mode="edge")
    alpha = np.pad(alpha, border)
    return ImageTexture(color, alpha, (origin[0] - border, origin[1] - border))
