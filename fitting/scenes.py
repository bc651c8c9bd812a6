"""Ground-truth scenes for the fitting tests and measurements, with the answers they hide.

Each returns (SceneBuffers, ids, truth): the rendered scene (`diffblur.scenes`), the (1, 1, H, W)
ID map of its sharp frame (the index of the visible layer, a stand-in for seed 001's vector motion
IDs), and the parameters that made it, in the names `fitting.recover` reports.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from diffblur.scenes._textures import pad
from diffblur.scenes import (
    Camera,
    ImageTexture,
    Layer,
    Rotation,
    Scene,
    SceneBuffers,
    Static,
    Translation,
    checkers,
    photo,
    preset_scene,
    render,
    render_buffers,
    stripes,
)

__all__ = ["layer_ids", "pan", "propeller", "translation", "two_objects"]


def layer_ids(buffers: SceneBuffers) -> np.ndarray:
    """Motion IDs (B, 1, H, W) int64: the index of the layer seen at each pixel at mid-exposure."""
    return np.maximum(render(buffers.scene, 0.0).layer, 0).astype(np.int64)


def translation(size: int = 48, velocity: tuple[float, float] = (3.0, -1.5), *, shutter="box", margin: int = 40) -> tuple[SceneBuffers, np.ndarray, dict]:
    """A photograph translating by `velocity` (half-spread, pixels) as a whole: one global velocity."""
    tex = ImageTexture(photo("coffee", size + 2 * margin, size + 2 * margin), origin=(-margin, -margin))
    buffers = render_buffers(Scene(size, size, (Layer(tex, 5.0, Translation(velocity)),)), shutter=shutter)
    return buffers, layer_ids(buffers), {"velocity": list(velocity)}


def _card(size: int, center: tuple[float, float], half: float, paint: np.ndarray) -> ImageTexture:
    """An opaque square texture `paint` with its top-left texel near center - half (a transparent
    border around it)."""
    return pad(paint, np.ones(paint.shape[:2]), (int(round(center[0] - half)), int(round(center[1] - half))))


def pan(size: int = 48, velocity: tuple[float, float] = (2.5, 1.0)) -> tuple[SceneBuffers, np.ndarray, dict]:
    """A camera pan over a background and an object at (almost) the same depth: every pixel moves by
    `velocity`, though the ID map has two IDs."""
    depth = 10.0
    margin = int(math.ceil(math.hypot(*velocity))) + 4
    background = ImageTexture(photo("astronaut", size + 2 * margin, size + 2 * margin), origin=(-margin, -margin))
    half = size * 0.2
    card = _card(size, (size * 0.45, size * 0.5), half, checkers(int(2 * half) + 1, int(2 * half) + 1, 4.0, (0.9, 0.8, 0.1), (0.1, 0.1, 0.5)))
    layers = (Layer(background, depth, Static(), "background"), Layer(card, depth * 0.999, Static(), "card"))
    camera = Camera(pan=(velocity[0] * depth, velocity[1] * depth))
    buffers = render_buffers(Scene(size, size, layers, camera), shutter="box")
    return buffers, layer_ids(buffers), {"velocity": list(velocity)}


def two_objects(size: int = 48, first: tuple[float, float] = (2.5, 1.0), second: tuple[float, float] = (-1.0, 2.0)) -> tuple[SceneBuffers, np.ndarray, dict]:
    """Two independently translating objects: a photograph moving by `first` behind a large card
    moving by `second` (IDs 0 and 1). Both are smooth photographs (a fine periodic texture would give
    the loss a minimum per period) and the card is large, so its edges (where the filters only
    approximate occlusion) are a small part of the image."""
    margin = int(math.ceil(max(math.hypot(*first), math.hypot(*second)))) + 4
    background = ImageTexture(photo("coffee", size + 2 * margin, size + 2 * margin), origin=(-margin, -margin))
    n = int(0.55 * size)
    card = pad(photo("chelsea", n, n, zoom=1.3, focus=(0.45, 0.4)), np.ones((n, n)), (int(0.3 * size), int(0.25 * size)))
    layers = (Layer(background, 20.0, Translation(first), "background"), Layer(card, 5.0, Translation(second), "card"))
    buffers = render_buffers(Scene(size, size, layers), shutter="box")
    return buffers, layer_ids(buffers), {"palette": [list(first), list(second)]}


def propeller(size: int = 48, angle: float = 0.5) -> tuple[SceneBuffers, np.ndarray, dict]:
    """The `propeller` preset turning `angle` rad at t = 1 about its centre (box shutter)."""
    base = preset_scene("propeller", height=size, width=size, seed=0)
    layers = tuple(dataclasses.replace(layer, motion=Rotation(layer.motion.center, angle)) if isinstance(layer.motion, Rotation) else layer for layer in base.layers)
    center = next(layer.motion.center for layer in base.layers if isinstance(layer.motion, Rotation))
    buffers = render_buffers(Scene(base.height, base.width, layers, base.camera), shutter="box")
    return buffers, layer_ids(buffers), {"center": list(center), "angle": angle}
