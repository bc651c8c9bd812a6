"""The layered 2.5D renderer: instants by inverse mapping, accumulation over the exposure, buffers.

Each output pixel X is mapped through each layer's motion back to the layer point X0 = H(t)^-1 X
seen there at time t, whose texture is sampled bilinearly; layers are composited front to back with
premultiplied alpha, nearest depth first (per pixel and instant when a layer's depth varies). The
accumulation ground truth is sum_k w_k frame(t_k) over stratified instants (`shutters.instants`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from diffblur import checks
from diffblur.scenes._motion import Camera, InverseDepthPlane, Motion, Static
from diffblur.scenes._textures import FunctionTexture, ImageTexture
from diffblur.shutters import ShutterWindow, get_shutter, instants as shutter_instants

__all__ = [
    "FAR_DEPTH",
    "Frame",
    "Layer",
    "Scene",
    "accumulate",
    "render",
    "required_instants",
    "trace",
]

#: Depth reported where no layer covers a pixel (alpha < 1/2 everywhere): far behind every layer.
FAR_DEPTH = 1.0e4
#: Coverage from which a layer is the one "seen" at a pixel for the depth, velocity and offsets.
VISIBLE_ALPHA = 0.5
#: Largest move (pixels) of any visible point between consecutive instants under the default rule.
MAX_STEP = 0.25
# Working memory per chunk of instants, in float64 values (about 64 MB).
_CHUNK_VALUES = 8_000_000
_INSTANT_CAP = 1 << 16


@dataclass(frozen=True, eq=False)
class Layer:
    """A textured layer with a depth and a motion.

    texture: ImageTexture or FunctionTexture in layer coordinates (the t = 0 image position, pixels).
    depth: a positive number (constant depth) or an InverseDepthPlane.
    motion: the object's own motion (Static, Translation, CurvedPath, Rotation, Affine).
    """

    texture: ImageTexture | FunctionTexture
    depth: float | InverseDepthPlane
    motion: Motion = field(default_factory=Static)
    name: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.texture, (ImageTexture, FunctionTexture)):
            raise TypeError(f"texture must be an ImageTexture or FunctionTexture, got {type(self.texture).__name__}")
        if not isinstance(self.motion, Motion):
            raise TypeError(f"motion must be a Motion (Static, Translation, ...), got {type(self.motion).__name__}")
        if not isinstance(self.depth, InverseDepthPlane):
            object.__setattr__(self, "depth", InverseDepthPlane.constant(self.depth))


@dataclass(frozen=True, eq=False)
class Scene:
    """Layers (any order; depth decides occlusion, ties go to the earlier layer) seen by a camera.

    height, width: output size in pixels. Pixel centres are at integer coordinates.
    """

    height: int
    width: int
    layers: tuple[Layer, ...]
    camera: Camera = field(default_factory=Camera)

    def __post_init__(self) -> None:
        checks.require_positive_int("height", self.height)
        checks.require_positive_int("width", self.width)
        layers = tuple(self.layers)
        for index, layer in enumerate(layers):
            if not isinstance(layer, Layer):
                raise TypeError(f"layers[{index}] must be a Layer, got {type(layer).__name__}")
        object.__setattr__(self, "layers", layers)
        if not isinstance(self.camera, Camera):
            raise TypeError(f"camera must be a Camera, got {type(self.camera).__name__}")
        # A dolly must not reach a layer: 1 - advance * t / depth must stay > 0.
        for layer in layers:
            x, y = layer.texture.support()
            if len(x):
                inverse = layer.depth.inverse_depth(x, y)
                if np.min(inverse) <= 0:
                    raise ValueError(f"layer {layer.name!r} has depth <= 0 (or infinite) on its texture")
                if abs(self.camera.advance) * float(np.max(inverse)) >= 1.0:
                    raise ValueError(
                        f"camera advance must stay below every layer's depth, got advance {self.camera.advance} "
                        f"and a depth of {1.0 / float(np.max(inverse)):.4g} in layer {layer.name!r}"
                    )

    def matrices(self, index: int, t: np.ndarray) -> np.ndarray:
        """H(t) of layer `index` at times t (n,): (n, 3, 3), X0 -> image position."""
        layer = self.layers[index]
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        return self.camera.compose(layer.motion.matrices(t), layer.depth, t)

    def is_static_layer(self, index: int) -> bool:
        return self.layers[index].motion.is_static and self.camera.is_static


class Frame(NamedTuple):
    """One instant. color (1, 3, H, W) linear; alpha (1, 1, H, W) total coverage; depth (1, 1, H, W) of
    the visible point (front-most layer with alpha >= 1/2; FAR_DEPTH where none); layer (1, 1, H, W)
    int, its index (-1 where none); source (1, 2, H, W), its layer coordinates X0 (pixels; 0 where
    none)."""

    color: np.ndarray
    alpha: np.ndarray
    depth: np.ndarray
    layer: np.ndarray
    source: np.ndarray


def _apply(matrices: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Homographies (n, 3, 3) applied to points x, y (broadcast to (n, ...)): (n, ...) each."""
    shape = (len(matrices),) + (1,) * np.ndim(x)
    m = matrices.reshape(len(matrices), 9)
    h = [m[:, k].reshape(shape) for k in range(9)]
    px = h[0] * x + h[1] * y + h[2]
    py = h[3] * x + h[4] * y + h[5]
    if np.any(m[:, 6:8] != 0) or np.any(m[:, 8] != 1):
        w = h[6] * x + h[7] * y + h[8]
        px, py = px / w, py / w
    return px, py


@dataclass
class _Samples:
    """One layer sampled at n instants inside its footprint `window` (rows, cols of the image)."""

    index: int
    window: tuple[slice, slice]
    rgb: np.ndarray  # (3, n, h, w) premultiplied; n may be 1 for a static layer (broadcasts)
    alpha: np.ndarray | None  # (n, h, w); None: opaque
    depth: np.ndarray  # (n, h, w) or (n, 1, 1)
    source: tuple[np.ndarray, np.ndarray]  # layer coordinates x0, y0, (n, h, w) each


def _footprint(scene: Scene, index: int, times: np.ndarray) -> tuple[slice, slice] | None:
    """Rows and columns of the image that layer `index` can cover at `times`, or None if none."""
    bounds = scene.layers[index].texture.bounds()
    if bounds is None:
        return slice(0, scene.height), slice(0, scene.width)
    x_lo, x_hi, y_lo, y_hi = bounds
    cx = np.array([x_lo, x_hi, x_lo, x_hi])
    cy = np.array([y_lo, y_lo, y_hi, y_hi])
    # The image of a rectangle under an affine map or a homography that keeps it in front of the camera
    # is a convex quadrilateral: the bounding box of its corners covers it.
    px, py = _apply(scene.matrices(index, times), cx, cy)
    c0 = max(int(np.floor(px.min())) - 1, 0)
    c1 = min(int(np.ceil(px.max())) + 2, scene.width)
    r0 = max(int(np.floor(py.min())) - 1, 0)
    r1 = min(int(np.ceil(py.max())) + 2, scene.height)
    if c0 >= c1 or r0 >= r1:
        return None
    return slice(r0, r1), slice(c0, c1)


def _layer_samples(scene: Scene, index: int, times: np.ndarray) -> _Samples | None:
    """Layer `index` at `times` (n,), sampled by inverse mapping inside its footprint."""
    layer = scene.layers[index]
    window = _footprint(scene, index, times)
    if window is None:
        return None
    rows, cols = window
    xs = np.arange(cols.start, cols.stop, dtype=np.float64)[None, :]
    ys = np.arange(rows.start, rows.stop, dtype=np.float64)[:, None]
    x0, y0 = _apply(np.linalg.inv(scene.matrices(index, times)), xs, ys)
    x0 = np.broadcast_to(x0, (len(times), len(ys), xs.shape[1]))
    y0 = np.broadcast_to(y0, x0.shape)
    rgb, alpha = layer.texture.sample(x0, y0)
    if layer.depth.is_constant:
        depth = np.full((len(times), 1, 1), 1.0 / layer.depth.i0)
    else:
        # Where the layer is absent X0 may leave the plane's valid side; its alpha is 0 there anyway.
        depth = 1.0 / np.maximum(layer.depth.inverse_depth(x0, y0), 1.0 / FAR_DEPTH)
    depth = depth - scene.camera.depth_shift(times)[:, None, None]
    return _Samples(index, window, rgb, alpha, depth, (x0, y0))


def _composite(
    scene: Scene, times: np.ndarray, *, buffers: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """Composite all layers at `times` (n,). Returns color (3, n, H, W), alpha (n, H, W) and, with
    buffers=True, the visible layer's depth (n, H, W), index (n, H, W) and source (2, n, H, W)."""
    height, width = scene.height, scene.width
    n = len(times)
    samples = []
    for index in range(len(scene.layers)):
        # A static layer shows the same picture at every instant: sample it once and broadcast.
        at = np.zeros(1) if scene.is_static_layer(index) else times
        sampled = _layer_samples(scene, index, at)
        if sampled is not None:
            samples.append(sampled)
    color = np.zeros((3, n, height, width))
    transmittance = np.ones((n, height, width))
    visible_depth = np.full((n, height, width), FAR_DEPTH) if buffers else None
    visible_layer = np.full((n, height, width), -1, dtype=np.intp) if buffers else None
    visible_source = np.zeros((2, n, height, width)) if buffers else None

    def note_visible(s: _Samples, first: np.ndarray) -> None:
        win = (slice(None),) + s.window
        visible_depth[win] = np.where(first, s.depth, visible_depth[win])
        visible_layer[win] = np.where(first, s.index, visible_layer[win])
        for axis in (0, 1):
            visible_source[(axis,) + win] = np.where(first, s.source[axis], visible_source[(axis,) + win])

    if all(layer.depth.is_constant for layer in scene.layers):
        # One depth per layer, shifted equally by the camera: one order everywhere, composited front
        # to back (ties: the earlier layer in front).
        for s in sorted(samples, key=lambda s: (1.0 / scene.layers[s.index].depth.i0, s.index)):
            win = (slice(None),) + s.window
            color[(slice(None),) + win] += transmittance[win] * s.rgb
            if buffers:
                covered = s.alpha >= VISIBLE_ALPHA if s.alpha is not None else True
                note_visible(s, (visible_layer[win] < 0) & covered)
            if s.alpha is None:
                transmittance[win] = 0.0
            else:
                transmittance[win] *= 1.0 - s.alpha
        return color, 1.0 - transmittance, visible_depth, visible_layer, visible_source

    # Depth varies within a layer: per pixel and instant, layer l is seen through every layer m in
    # front of it, color = sum_l rgb_l prod_{m in front of l} (1 - alpha_m), which is front-to-back
    # compositing without sorting. Only where the footprints of l and m overlap does m matter.
    def alpha_of(s: _Samples) -> np.ndarray:
        shape = (s.rgb.shape[1], s.window[0].stop - s.window[0].start, s.window[1].stop - s.window[1].start)
        return np.ones(shape) if s.alpha is None else s.alpha

    for k, s in enumerate(samples):
        alpha_k = alpha_of(s)
        depth_k = np.broadcast_to(s.depth, alpha_k.shape)
        through = np.ones((n,) + alpha_k.shape[1:])
        blocked = np.zeros(through.shape, dtype=bool)
        for m, other in enumerate(samples):
            rows = slice(max(s.window[0].start, other.window[0].start), min(s.window[0].stop, other.window[0].stop))
            cols = slice(max(s.window[1].start, other.window[1].start), min(s.window[1].stop, other.window[1].stop))
            if m == k or rows.start >= rows.stop or cols.start >= cols.stop:
                continue
            mine = (slice(None), slice(rows.start - s.window[0].start, rows.stop - s.window[0].start),
                    slice(cols.start - s.window[1].start, cols.stop - s.window[1].start))
            theirs = (slice(None), slice(rows.start - other.window[0].start, rows.stop - other.window[0].start),
                      slice(cols.start - other.window[1].start, cols.stop - other.window[1].start))
            alpha_m = alpha_of(other)[theirs]
            depth_m = np.broadcast_to(other.depth, alpha_of(other).shape)[theirs]
            in_front = (depth_m < depth_k[mine]) | ((depth_m == depth_k[mine]) & (other.index < s.index))
            through[mine] = through[mine] * np.where(in_front, 1.0 - alpha_m, 1.0)
            if buffers:
                blocked[mine] |= in_front & (alpha_m >= VISIBLE_ALPHA)
        win = (slice(None),) + s.window
        color[(slice(None),) + win] += through * s.rgb
        if buffers:
            note_visible(s, (alpha_k >= VISIBLE_ALPHA) & ~blocked)
        transmittance[win] *= 1.0 - alpha_k
    return color, 1.0 - transmittance, visible_depth, visible_layer, visible_source


def render(scene: Scene, t: float = 0.0) -> Frame:
    """The scene at one instant t in [-1, 1] (t = 0 is the sharp frame). See `Frame` for the shapes."""
    t = checks.require_finite_number("t", t)
    color, alpha, depth, layer, source = _composite(scene, np.array([t]), buffers=True)
    return Frame(
        color=np.ascontiguousarray(color[:, 0][None]),
        alpha=alpha[0][None, None],
        depth=depth[0][None, None],
        layer=layer[0][None, None],
        source=np.ascontiguousarray(source[:, 0][None]),
    )


def trace(scene: Scene, t: np.ndarray | float) -> np.ndarray:
    """Where the point visible at each pixel X at t = 0 is at the times t (n,): (n, 2, H, W), pixels.

    The visible point is the front-most layer's with alpha >= 1/2 (FAR_DEPTH pixels, with no such
    layer, stay at X).
    """
    t = np.atleast_1d(np.asarray(t, dtype=np.float64))
    height, width = scene.height, scene.width
    xs = np.broadcast_to(np.arange(width, dtype=np.float64)[None, :], (height, width))
    ys = np.broadcast_to(np.arange(height, dtype=np.float64)[:, None], (height, width))
    _, _, _, visible, _ = _composite(scene, np.zeros(1), buffers=True)
    visible = visible[0]
    out = np.stack([np.broadcast_to(xs, (len(t), height, width)), np.broadcast_to(ys, (len(t), height, width))], axis=1)
    out = out.copy()
    for index in range(len(scene.layers)):
        mask = visible == index
        if not np.any(mask):
            continue
        px, py = _apply(scene.matrices(index, t), xs[mask], ys[mask])
        out[:, 0][:, mask] = px
        out[:, 1][:, mask] = py
    return out


def _support_points(scene: Scene, index: int, limit: int = 4000) -> tuple[np.ndarray, np.ndarray]:
    x, y = scene.layers[index].texture.support()
    if len(x) > limit:
        stride = math.ceil(len(x) / limit)
        x, y = x[::stride], y[::stride]
    return np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)


def _largest_step(scene: Scene, times: np.ndarray) -> float:
    """The largest move (pixels) between consecutive `times` of any layer point seen in the image."""
    largest = 0.0
    for index in range(len(scene.layers)):
        if scene.is_static_layer(index):
            continue
        x, y = _support_points(scene, index)
        if len(x) == 0:
            continue
        px, py = _apply(scene.matrices(index, times), x, y)  # (n, P)
        margin = 2.0
        seen = np.any(
            (px > -margin) & (px < scene.width - 1 + margin) & (py > -margin) & (py < scene.height - 1 + margin),
            axis=0,
        )
        if not np.any(seen):
            continue
        step = np.hypot(np.diff(px[:, seen], axis=0), np.diff(py[:, seen], axis=0))
        largest = max(largest, float(step.max(initial=0.0)))
    return largest


def required_instants(scene: Scene, *, max_step: float = MAX_STEP) -> int:
    """The fewest stratified instants such that consecutive instants move every layer point that is
    in view during the exposure by less than `max_step` pixels (1 for a static scene)."""
    max_step = checks.require_positive_number("max_step", max_step)
    # Speed estimate on a fine grid, then the exact check on the midpoint instants themselves.
    probe = np.linspace(-1.0, 1.0, 129)
    speed = _largest_step(scene, probe) / (probe[1] - probe[0])
    count = max(1, math.ceil(2.0 * speed / max_step))
    while count < _INSTANT_CAP:
        times, _ = shutter_instants("box", count)
        step = _largest_step(scene, times) if count > 1 else 0.0
        if step < max_step:
            return count
        count = math.ceil(count * max(1.1, step / max_step * 1.02))
    raise ValueError(f"scene needs more than {_INSTANT_CAP} instants for steps below {max_step} px")


def accumulate(
    scene: Scene, *, shutter: str | ShutterWindow = "box", instants: int | None = None
) -> tuple[np.ndarray, int]:
    """The exposure's ground truth: sum_k w_k frame(t_k), (1, 3, H, W) float64 linear, and the count.

    instants: number of stratified instants; None takes `required_instants(scene)`. The weights are
    the window's exact integrals over the strata (`shutters.instants`).
    """
    window = get_shutter(shutter)
    count = required_instants(scene) if instants is None else checks.require_positive_int("instants", instants)
    times, weights = shutter_instants(window, count)
    layers = len(scene.layers)
    chunk = max(1, _CHUNK_VALUES // (scene.height * scene.width * (4 + 9 * max(layers, 1))))
    total = np.zeros((3, scene.height, scene.width))
    for start in range(0, count, chunk):
        color, _, _, _, _ = _composite(scene, times[start : start + chunk], buffers=False)
        total += np.tensordot(color, weights[start : start + chunk], axes=(1, 0))
    return total[None], count
