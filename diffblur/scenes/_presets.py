"""The preset scenes. Sizes and motions scale with min(height, width) / 128, so the half-spread of
the fastest points is a few to ~15 pixels at 128 x 128 whatever the size. `seed` jitters positions,
speeds and directions a little (deterministically); the structure of each preset stays the same."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from diffblur.scenes._motion import Affine, Camera, CurvedPath, InverseDepthPlane, Rotation, Static, Translation
from diffblur.scenes._render import Layer, Scene
from diffblur.scenes._textures import ImageTexture, checkers, coverage, pad, photo, stripes

__all__ = ["PRESETS", "build_preset"]


class _Frame:
    """Geometry of one preset: size, scale and the seeded jitter."""

    def __init__(self, height: int, width: int, seed: int) -> None:
        self.height, self.width = height, width
        self.scale = min(height, width) / 128.0
        self.rng = np.random.default_rng(seed)

    def jitter(self, spread: float) -> float:
        return 1.0 + spread * (2.0 * self.rng.random() - 1.0)

    def at(self, fx: float, fy: float, spread: float = 0.03) -> tuple[float, float]:
        """A point at fractions (fx, fy) of the image, moved by up to `spread` of the size."""
        return (
            (fx + spread * (2 * self.rng.random() - 1)) * (self.width - 1),
            (fy + spread * (2 * self.rng.random() - 1)) * (self.height - 1),
        )

    def vector(self, length: float, angle: float, spread: float = 0.15) -> tuple[float, float]:
        """A vector of `length` pixels at 128 x 128 (scaled), direction `angle`, both jittered."""
        length = length * self.scale * self.jitter(spread)
        angle = angle + 0.15 * (2 * self.rng.random() - 1)
        return (length * math.cos(angle), length * math.sin(angle))


def _background(frame: _Frame, name: str, depth: float, margin: float = 0.0, **photo_kw) -> Layer:
    """An opaque photograph covering the image plus `margin` pixels on every side."""
    m = int(math.ceil(margin)) + 2
    color = photo(name, frame.height + 2 * m, frame.width + 2 * m, **photo_kw)
    return Layer(ImageTexture(color, None, (-m, -m)), depth, Static(), name=f"background ({name})")


def _object(
    frame: _Frame,
    inside: Callable[[np.ndarray, np.ndarray], np.ndarray],
    box: tuple[float, float, float, float],
    paint: Callable[[int, int, tuple[int, int]], np.ndarray],
) -> ImageTexture:
    """A textured shape: `inside(x, y)` at image coordinates, within box (x0, y0, x1, y1); paint(h, w,
    origin) gives the colour of the box's texels."""
    x0, y0 = int(math.floor(box[0])) - 1, int(math.floor(box[1])) - 1
    x1, y1 = int(math.ceil(box[2])) + 1, int(math.ceil(box[3])) + 1
    h, w = y1 - y0 + 1, x1 - x0 + 1
    alpha = coverage(inside, h, w, origin=(x0, y0))
    return pad(paint(h, w, (x0, y0)), alpha, (x0, y0))


def _disk(center: tuple[float, float], radius: float):
    cx, cy = center
    return lambda x, y: (x - cx) ** 2 + (y - cy) ** 2 <= radius * radius


def _rounded_box(center: tuple[float, float], half: tuple[float, float], radius: float):
    cx, cy = center
    hx, hy = half[0] - radius, half[1] - radius

    def inside(x, y):
        qx = np.maximum(np.abs(x - cx) - hx, 0.0)
        qy = np.maximum(np.abs(y - cy) - hy, 0.0)
        return qx * qx + qy * qy <= radius * radius

    return inside


def _gear(center: tuple[float, float], radius: float, teeth: int, hole: float):
    cx, cy = center
    depth = 0.16 * radius

    def inside(x, y):
        dx, dy = x - cx, y - cy
        r = np.hypot(dx, dy)
        # Trapezoidal teeth: a clipped sine wave of the angle.
        wave = np.clip(1.6 * np.sin(teeth * np.arctan2(dy, dx)), -1.0, 1.0)
        outline = radius - depth + depth * wave
        return (r <= outline) & (r >= hole)

    return inside


def _propeller(center: tuple[float, float], length: float, width: float, blades: int, hub: float, turn: float):
    cx, cy = center

    def inside(x, y):
        dx, dy = x - cx, y - cy
        hit = dx * dx + dy * dy <= hub * hub
        for k in range(blades):
            a = turn + 2 * math.pi * k / blades
            along = dx * math.cos(a) + dy * math.sin(a)
            across = -dx * math.sin(a) + dy * math.cos(a)
            # A blade: an ellipse from the hub to the tip, widest at 60 % of its length.
            u = (along - 0.5 * length) / (0.5 * length)
            half_width = width * (1 - u * u) * (1 + 0.4 * u)
            hit = hit | ((along > 0) & (np.abs(across) <= half_width))
        return hit

    return inside


def _photo_paint(name: str, tint: tuple[float, float, float] = (1, 1, 1), **kw):
    return lambda h, w, origin: photo(name, h, w, **kw) * np.asarray(tint)


def _spoked(base: Callable, center: tuple[float, float], spokes: int):
    """Darken `base` along radial spokes, so that a rotation shows even on smooth texture."""

    def paint(h, w, origin):
        color = base(h, w, origin)
        y, x = np.mgrid[0:h, 0:w].astype(np.float64)
        theta = np.arctan2(y + origin[1] - center[1], x + origin[0] - center[0])
        shade = 0.55 + 0.45 * (0.5 + 0.5 * np.cos(spokes * theta))
        return color * shade[:, :, None]

    return paint


def _static(f: _Frame) -> Scene:
    s = f.scale
    cat = f.at(0.35, 0.55)
    ball = f.at(0.72, 0.35)
    cat_tex = _object(
        f,
        _rounded_box(cat, (26 * s, 20 * s), 6 * s),
        (cat[0] - 26 * s, cat[1] - 20 * s, cat[0] + 26 * s, cat[1] + 20 * s),
        _photo_paint("chelsea", zoom=1.6, focus=(0.45, 0.4)),
    )
    ball_tex = _object(
        f,
        _disk(ball, 16 * s),
        (ball[0] - 16 * s, ball[1] - 16 * s, ball[0] + 16 * s, ball[1] + 16 * s),
        lambda h, w, o: checkers(h, w, 9 * s, (0.9, 0.75, 0.1), (0.05, 0.1, 0.4), origin=o),
    )
    layers = (
        _background(f, "astronaut", 12.0),
        Layer(cat_tex, 3.0, Static(), "cat"),
        Layer(ball_tex, 5.0, Static(), "ball"),
    )
    return Scene(f.height, f.width, layers)


def _translate(f: _Frame) -> Scene:
    s = f.scale
    center = f.at(0.5, 0.5)
    half = (30 * s, 22 * s)
    tex = _object(
        f,
        _rounded_box(center, half, 5 * s),
        (center[0] - half[0], center[1] - half[1], center[0] + half[0], center[1] + half[1]),
        _photo_paint("chelsea", zoom=1.3, focus=(0.45, 0.45)),
    )
    velocity = f.vector(12.0, 0.35)
    layers = (_background(f, "coffee", 10.0), Layer(tex, 2.5, Translation(velocity), "cat card"))
    return Scene(f.height, f.width, layers)


def _pan(f: _Frame) -> Scene:
    s = f.scale
    near_depth = 2.0
    pan = f.vector(14.0 * near_depth, 0.08)  # the nearest layer moves ~14 px
    pan_len = math.hypot(*pan)
    horizon = 0.62 * (f.height - 1)
    ground_depth = InverseDepthPlane.through_rows(horizon, 14.0, f.height - 1, 2.6)
    margin = int(math.ceil(pan_len / 2.6)) + 3
    y0 = int(math.floor(horizon)) - 2
    gh, gw = f.height + margin - y0, f.width + 2 * margin
    ground_alpha = coverage(lambda x, y: y >= horizon + 0 * x, gh, gw, origin=(-margin, y0))
    ground_color = checkers(gh, gw, 14 * s, (0.55, 0.5, 0.45), (0.08, 0.1, 0.07), angle=0.5, origin=(-margin, y0))
    ground = Layer(ImageTexture(ground_color, ground_alpha, (-margin, y0)), ground_depth, Static(), "ground")
    tower = f.at(0.42, 0.42)
    tower_half = (13 * s, 30 * s)
    tower_tex = _object(
        f,
        _rounded_box(tower, tower_half, 3 * s),
        (tower[0] - tower_half[0], tower[1] - tower_half[1], tower[0] + tower_half[0], tower[1] + tower_half[1]),
        _photo_paint("rocket", zoom=2.0, focus=(0.5, 0.6)),
    )
    post = f.at(0.76, 0.5)
    post_half = (6 * s, 60 * s)
    post_tex = _object(
        f,
        _rounded_box(post, post_half, 2 * s),
        (post[0] - post_half[0], post[1] - post_half[1], post[0] + post_half[0], post[1] + post_half[1]),
        lambda h, w, o: stripes(h, w, 8 * s, (0.8, 0.1, 0.05), (0.95, 0.9, 0.85), angle=math.pi / 2, origin=o),
    )
    layers = (
        _background(f, "astronaut", 25.0, margin=pan_len / 25.0),
        ground,
        Layer(tower_tex, 6.0, Static(), "tower"),
        Layer(post_tex, near_depth, Static(), "post"),
    )
    return Scene(f.height, f.width, layers, Camera(pan=pan))


def _crossing(f: _Frame) -> Scene:
    s = f.scale
    a_center = f.at(0.44, 0.5)
    a_radius = 17 * s
    a_tex = _object(
        f,
        _disk(a_center, a_radius),
        (a_center[0] - a_radius, a_center[1] - a_radius, a_center[0] + a_radius, a_center[1] + a_radius),
        lambda h, w, o: stripes(h, w, 7 * s, (0.95, 0.55, 0.05), (0.1, 0.2, 0.7), angle=0.6, origin=o),
    )
    b_center = f.at(0.58, 0.45)
    b_half = (24 * s, 18 * s)
    b_tex = _object(
        f,
        _rounded_box(b_center, b_half, 4 * s),
        (b_center[0] - b_half[0], b_center[1] - b_half[1], b_center[0] + b_half[0], b_center[1] + b_half[1]),
        _photo_paint("coffee", zoom=1.5, focus=(0.35, 0.45)),
    )
    # A bends along a parabola; B slides the other way while turning and growing a little (affine).
    a_motion = CurvedPath(f.vector(13.0, 0.0), f.vector(9.0, -math.pi / 2))
    b_motion = Affine(((0.05, -0.12), (0.12, 0.05)), f.vector(10.0, math.pi - 0.25), b_center)
    layers = (
        _background(f, "camera", 20.0),
        Layer(a_tex, 4.0, a_motion, "striped disk"),
        Layer(b_tex, 7.0, b_motion, "coffee card"),
    )
    return Scene(f.height, f.width, layers)


def _propeller_scene(f: _Frame) -> Scene:
    s = f.scale
    center = f.at(0.5, 0.5, spread=0.02)
    length = 0.42 * min(f.width, f.height)
    width = 0.075 * min(f.width, f.height)
    tip_speed = 14.0 * s * f.jitter(0.1)
    angle = math.asin(min(tip_speed / length, 0.9)) * (1 if f.rng.random() < 0.5 else -1)
    inside = _propeller(center, length, width, 3, 7 * s, turn=f.rng.random() * 2 * math.pi)
    paint = _spoked(_photo_paint("astronaut", zoom=1.2, focus=(0.5, 0.6)), center, 12)
    tex = _object(f, inside, (center[0] - length, center[1] - length, center[0] + length, center[1] + length), paint)
    layers = (_background(f, "coffee", 15.0), Layer(tex, 3.0, Rotation(center, angle), "propeller"))
    return Scene(f.height, f.width, layers)


def _zoom(f: _Frame) -> Scene:
    s = f.scale
    center = ((f.width - 1) / 2, (f.height - 1) / 2)
    advance = 0.4 * f.jitter(0.1)
    # At t = -1 every layer shows (1 + advance / depth) times more of itself: size the background.
    margin = 0.5 * max(f.width, f.height) * advance / (10.0 - advance) * 1.2 + 2
    ball = f.at(0.3, 0.32)
    ball_tex = _object(
        f,
        _disk(ball, 15 * s),
        (ball[0] - 15 * s, ball[1] - 15 * s, ball[0] + 15 * s, ball[1] + 15 * s),
        lambda h, w, o: checkers(h, w, 8 * s, (0.95, 0.95, 0.9), (0.6, 0.05, 0.1), angle=0.3, origin=o),
    )
    card = f.at(0.64, 0.62)
    half = (25 * s, 19 * s)
    card_tex = _object(
        f,
        _rounded_box(card, half, 4 * s),
        (card[0] - half[0], card[1] - half[1], card[0] + half[0], card[1] + half[1]),
        _photo_paint("chelsea", zoom=1.5, focus=(0.45, 0.4)),
    )
    layers = (
        _background(f, "astronaut", 10.0, margin=margin),
        Layer(ball_tex, 3.0, Static(), "checker ball"),
        Layer(card_tex, 5.0, Static(), "cat card"),
    )
    return Scene(f.height, f.width, layers, Camera(advance=advance, center=center))


def _gears(f: _Frame) -> Scene:
    s = f.scale
    m = min(f.width, f.height)
    # (centre fraction, radius fraction, teeth, depth, photo); neighbours mesh and turn the other way.
    specs = [
        ((0.33, 0.38), 0.27, 12, 4.0, "astronaut"),
        ((0.74, 0.3), 0.17, 8, 4.5, "chelsea"),
        ((0.68, 0.76), 0.22, 10, 3.5, "coffee"),
        ((0.2, 0.8), 0.13, 6, 5.0, "rocket"),
    ]
    tip = 12.0 * s * f.jitter(0.1)
    layers = [_background(f, "camera", 20.0, zoom=1.0)]
    direction = 1.0
    for (fx, fy), fr, teeth, depth, name in specs:
        center = f.at(fx, fy, spread=0.015)
        radius = fr * m
        # Meshing gears share the tip speed: angular speed ~ 1 / radius, alternating direction.
        angle = direction * math.asin(min(tip / radius, 0.9))
        direction = -direction
        focus = (0.5, 0.85) if name == "rocket" else (0.5, 0.5)
        paint = _spoked(_photo_paint(name, zoom=1.3, focus=focus), center, teeth)
        tex = _object(
            f,
            _gear(center, radius, teeth, 0.18 * radius),
            (center[0] - radius, center[1] - radius, center[0] + radius, center[1] + radius),
            paint,
        )
        layers.append(Layer(tex, depth, Rotation(center, angle), f"gear ({name})"))
    return Scene(f.height, f.width, tuple(layers))


_BUILDERS: dict[str, Callable[[_Frame], Scene]] = {
    "static": _static,
    "translate": _translate,
    "pan": _pan,
    "crossing": _crossing,
    "propeller": _propeller_scene,
    "zoom": _zoom,
    "gears": _gears,
}

#: The preset names `make_scene` accepts.
PRESETS: tuple[str, ...] = tuple(_BUILDERS)


def build_preset(name: str, height: int, width: int, seed: int) -> Scene:
    """The Scene (layers, motions, camera) of a preset; arguments already checked by the caller."""
    return _BUILDERS[name](_Frame(height, width, seed))
