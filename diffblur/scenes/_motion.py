"""Motions of scene layers over the normalised exposure t in [-1, 1], as 3 x 3 image-plane maps.

A layer point is named by where it is at t = 0 (its image position X0, pixels, x = column,
y = row). Its position at time t is p = H(t) X0 in homogeneous coordinates, with H(0) = I exactly.
Object motions (translation, curved path, rotation, affine) are affine; the camera adds parallax
that depends on the point's depth, given per layer as an inverse-depth plane
1 / depth(X0) = i0 + ix x0 + iy y0 (a world plane has an inverse depth affine in image coordinates),
so that a pan stays affine and a dolly (zoom by moving the camera) is a homography, exact for
tilted planes too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from diffblur import checks

__all__ = [
    "Affine",
    "Camera",
    "CurvedPath",
    "InverseDepthPlane",
    "Motion",
    "Rotation",
    "Static",
    "Translation",
]


def _pair(name: str, value: object) -> tuple[float, float]:
    try:
        x, y = value  # type: ignore[misc]
        pair = (float(x), float(y))
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a pair of numbers (x, y) in pixels, got {value!r}") from None
    if not all(math.isfinite(v) for v in pair):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return pair


def _identity(count: int) -> np.ndarray:
    return np.broadcast_to(np.eye(3), (count, 3, 3)).copy()


def _times(t: np.ndarray | float) -> np.ndarray:
    return np.atleast_1d(np.asarray(t, dtype=np.float64))


class Motion:
    """An object motion: `matrices(t)` gives H(t), shape (n, 3, 3) for n times, H(0) = I."""

    def matrices(self, t: np.ndarray | float) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    @property
    def is_static(self) -> bool:
        return False


@dataclass(frozen=True)
class Static(Motion):
    """No motion."""

    def matrices(self, t: np.ndarray | float) -> np.ndarray:
        return _identity(len(_times(t)))

    @property
    def is_static(self) -> bool:
        return True


@dataclass(frozen=True)
class Translation(Motion):
    """p(t) = X0 + velocity * t: linear motion; `velocity` is the half-spread (x, y) in pixels."""

    velocity: tuple[float, float]

    def __post_init__(self) -> None:
        object.__setattr__(self, "velocity", _pair("velocity", self.velocity))

    def matrices(self, t: np.ndarray | float) -> np.ndarray:
        t = _times(t)
        out = _identity(len(t))
        out[:, 0, 2] = self.velocity[0] * t
        out[:, 1, 2] = self.velocity[1] * t
        return out


@dataclass(frozen=True)
class CurvedPath(Motion):
    """p(t) = X0 + velocity t + acceleration t^2 / 2: a parabolic path (pixels).

    The point is at X0 - velocity + acceleration / 2 at t = -1 and X0 + velocity + acceleration / 2 at
    t = 1: the half-spread is `velocity`, and the path bends towards `acceleration`.
    """

    velocity: tuple[float, float]
    acceleration: tuple[float, float]

    def __post_init__(self) -> None:
        object.__setattr__(self, "velocity", _pair("velocity", self.velocity))
        object.__setattr__(self, "acceleration", _pair("acceleration", self.acceleration))

    def matrices(self, t: np.ndarray | float) -> np.ndarray:
        t = _times(t)
        out = _identity(len(t))
        for axis in (0, 1):
            out[:, axis, 2] = self.velocity[axis] * t + 0.5 * self.acceleration[axis] * t * t
        return out


@dataclass(frozen=True)
class Rotation(Motion):
    """Rotation about `center` (pixels) by angle * t radians.

    Positive angles turn +x towards +y (clockwise on screen, since y points down). `angle` is the
    rotation at t = 1; the whole exposure sweeps 2 * angle.
    """

    center: tuple[float, float]
    angle: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", _pair("center", self.center))
        checks.require_finite_number("angle", self.angle)

    def matrices(self, t: np.ndarray | float) -> np.ndarray:
        t = _times(t)
        cos, sin = np.cos(self.angle * t), np.sin(self.angle * t)
        cx, cy = self.center
        out = _identity(len(t))
        out[:, 0, 0], out[:, 0, 1] = cos, -sin
        out[:, 1, 0], out[:, 1, 1] = sin, cos
        # c - R c, so that the centre stays put (exactly 0 at t = 0).
        out[:, 0, 2] = cx - (cos * cx - sin * cy)
        out[:, 1, 2] = cy - (sin * cx + cos * cy)
        return out


@dataclass(frozen=True)
class Affine(Motion):
    """p(t) = center + (I + t * rate) (X0 - center) + velocity * t.

    rate: 2 x 2, the change of the linear part per unit t (its antisymmetric part turns, its
    symmetric part stretches); velocity: (x, y) pixels per unit t. Keep |t * rate| well below 1 so the
    map stays invertible over the exposure.
    """

    rate: tuple[tuple[float, float], tuple[float, float]]
    velocity: tuple[float, float] = (0.0, 0.0)
    center: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        rate = np.asarray(self.rate, dtype=np.float64)
        if rate.shape != (2, 2) or not np.all(np.isfinite(rate)):
            raise ValueError(f"rate must be a finite 2 x 2 matrix, got {self.rate!r}")
        for sign in (-1.0, 1.0):
            if np.linalg.det(np.eye(2) + sign * rate) <= 0:
                raise ValueError(f"rate must keep I + t * rate invertible for t in [-1, 1], got {self.rate!r}")
        object.__setattr__(self, "rate", tuple(tuple(float(v) for v in row) for row in rate))
        object.__setattr__(self, "velocity", _pair("velocity", self.velocity))
        object.__setattr__(self, "center", _pair("center", self.center))

    def matrices(self, t: np.ndarray | float) -> np.ndarray:
        t = _times(t)
        rate = np.asarray(self.rate)
        c = np.asarray(self.center)
        out = _identity(len(t))
        linear = np.eye(2)[None] + t[:, None, None] * rate[None]
        out[:, :2, :2] = linear
        out[:, :2, 2] = c[None] - linear @ c + t[:, None] * np.asarray(self.velocity)[None]
        return out


@dataclass(frozen=True)
class InverseDepthPlane:
    """Depth of a layer point from its t = 0 position: 1 / depth = i0 + ix * x0 + iy * y0.

    A constant depth d is InverseDepthPlane(1 / d); `through_rows` makes a plane seen as a ground or a
    ceiling. Depth is positive linear depth (larger = farther), in the scene's depth units.
    """

    i0: float
    ix: float = 0.0
    iy: float = 0.0

    @classmethod
    def constant(cls, depth: float) -> InverseDepthPlane:
        return cls(1.0 / checks.require_positive_number("depth", depth))

    @classmethod
    def through_rows(cls, row_a: float, depth_a: float, row_b: float, depth_b: float) -> InverseDepthPlane:
        """The plane with depth_a at image row row_a and depth_b at row_b, constant along rows."""
        checks.require_positive_number("depth_a", depth_a)
        checks.require_positive_number("depth_b", depth_b)
        if row_a == row_b:
            raise ValueError(f"row_a and row_b must differ, got {row_a} and {row_b}")
        iy = (1.0 / depth_b - 1.0 / depth_a) / (row_b - row_a)
        return cls(1.0 / depth_a - iy * row_a, 0.0, iy)

    @property
    def is_constant(self) -> bool:
        return self.ix == 0.0 and self.iy == 0.0

    def row(self) -> np.ndarray:
        """(ix, iy, i0): the plane as a row vector acting on homogeneous (x, y, 1)."""
        return np.array([self.ix, self.iy, self.i0])

    def inverse_depth(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return self.i0 + self.ix * x + self.iy * y


@dataclass(frozen=True)
class Camera:
    """Camera motion, seen as image motion of every layer with parallax by depth.

    pan: (x, y), pixels times depth units: a point at depth d moves by pan * t / d (a sideways camera
    translation; nearer layers move more). advance: depth units the camera moves forward at t = 1
    (a dolly: the point at depth d, at offset X0 - center from the principal point, is seen at
    center + (X0 - center) * d / (d - advance * t), and its depth becomes d - advance * t).
    |advance| must stay below every layer's depth.
    """

    pan: tuple[float, float] = (0.0, 0.0)
    advance: float = 0.0
    center: tuple[float, float] = (0.0, 0.0)
    _static: bool = field(init=False, repr=False, default=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "pan", _pair("pan", self.pan))
        object.__setattr__(self, "center", _pair("center", self.center))
        checks.require_finite_number("advance", self.advance)
        object.__setattr__(self, "_static", self.pan == (0.0, 0.0) and self.advance == 0.0)

    @property
    def is_static(self) -> bool:
        return self._static

    def compose(self, object_matrices: np.ndarray, plane: InverseDepthPlane, t: np.ndarray) -> np.ndarray:
        """H(t) of a layer: its object motion (n, 3, 3, affine) seen through this camera."""
        t = _times(t)
        out = object_matrices.copy()
        if self._static:
            return out
        row = plane.row()
        # Pan: p = O(t) X0 + pan * t * iota(X0), still affine.
        out[:, :2, :] += t[:, None, None] * np.asarray(self.pan)[None, :, None] * row[None, None, :]
        if self.advance != 0.0:
            # Dolly: p = c + (q - c) / den with den = 1 - advance * t * iota(X0), a homography.
            c = np.asarray(self.center)
            den = np.zeros((len(t), 3))
            den[:, 2] = 1.0
            den -= self.advance * t[:, None] * row[None, :]
            top = out[:, :2, :].copy()
            top[:, :, 2] -= c[None]
            top += c[None, :, None] * den[:, None, :]
            out[:, :2, :] = top
            out[:, 2, :] = den
        return out

    def depth_shift(self, t: np.ndarray) -> np.ndarray:
        """How much nearer every point is at time t (depth(t) = depth(0) - shift), depth units."""
        return self.advance * _times(t)
