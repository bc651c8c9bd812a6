"""Layered 2.5D scenes with accumulation ground truth, and the buffers of their sharp frame.

`make_scene(name)` renders a preset (`PRESETS`) and returns its sharp frame's buffers in the
project's conventions (NumPy, NCHW, float64) with the accumulated ground truth `target`:

| field | shape | meaning |
|---|---|---|
| color | (1, 3, H, W) | the sharp frame (t = 0), linear |
| depth | (1, 1, H, W) | positive depth of the visible point (front-most layer with alpha >= 1/2) |
| velocity | (1, 2, H, W) | (p(+1) - p(-1)) / 2 of that point, pixels, channel 0 = x |
| offset_prev, offset_next | (1, 2, H, W) | p(-1) - X and p(+1) - X |
| target | (1, 3, H, W) | sum_k w_k frame(t_k): the exposure under the shutter window |
| background | (1, 3, H, W) or None | the static background layer alone, where the scene has one |

Scenes are built from `Layer`s (a texture, a depth, a motion) and a `Camera`; `render`, `trace` and
`accumulate` work on any `Scene`. `orbiting_disk_density` is seed 004's exact time-integrated
orbiting disk, and `orbiting_disk_scene` the same disk as a scene, to check the accumulation against.

The package's private modules hold the parts (`_render`, `_textures`, `_motion`, `_presets`, `_disk`,
`_gallery`); `diffblur.scenes.mitsuba` (the `mitsuba` extra, not imported here) renders 3D scenes
with Mitsuba 3 into the same buffers.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from diffblur import checks
from diffblur.metrics import linear_to_srgb, srgb_to_linear
from diffblur.scenes._disk import orbiting_disk_density, orbiting_disk_scene
from diffblur.scenes._motion import Affine, Camera, CurvedPath, InverseDepthPlane, Motion, Rotation, Static, Translation
from diffblur.scenes._presets import PRESETS, build_preset
from diffblur.scenes._render import FAR_DEPTH, MAX_STEP, Frame, Layer, Scene, accumulate, render, required_instants, trace
from diffblur.scenes._textures import FunctionTexture, ImageTexture, checkers, photo, stripes
from diffblur.shutters import ShutterWindow, get_shutter

__all__ = [
    "FAR_DEPTH",
    "MAX_STEP",
    "PRESETS",
    "Affine",
    "Camera",
    "CurvedPath",
    "Frame",
    "FunctionTexture",
    "ImageTexture",
    "InverseDepthPlane",
    "Layer",
    "Motion",
    "Rotation",
    "Scene",
    "SceneBuffers",
    "Static",
    "Translation",
    "accumulate",
    "checkers",
    "linear_to_srgb",
    "make_scene",
    "orbiting_disk_density",
    "orbiting_disk_scene",
    "photo",
    "preset_scene",
    "render",
    "render_buffers",
    "required_instants",
    "save_preset_gallery",
    "srgb_to_linear",
    "stripes",
    "trace",
]


@dataclass(frozen=True, eq=False)
class SceneBuffers:
    """A rendered scene: the sharp frame's buffers and the ground truth (see the module table).

    Also: name, the shutter window, `instants` (how many were accumulated) and `scene` (the Scene, to
    render more instants or trace points).
    """

    name: str
    color: np.ndarray
    depth: np.ndarray
    velocity: np.ndarray
    offset_prev: np.ndarray
    offset_next: np.ndarray
    target: np.ndarray
    background: np.ndarray | None
    shutter: ShutterWindow
    instants: int
    scene: Scene


def _check_size(height: object, width: object) -> tuple[int, int]:
    height = checks.require_positive_int("height", height)
    width = checks.require_positive_int("width", width)
    # Bilinear sampling and the presets' shapes need a few pixels.
    if height < 8 or width < 8:
        raise ValueError(f"height and width must be >= 8 pixels, got height={height}, width={width}")
    return height, width


def preset_scene(name: str, *, height: int = 128, width: int = 128, seed: int = 0) -> Scene:
    """The Scene (layers, motions, camera) of preset `name`, before rendering."""
    checks.require_choice("name", name, PRESETS)
    height, width = _check_size(height, width)
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool):
        raise TypeError(f"seed must be an integer, got {seed!r}")
    return build_preset(name, height, width, int(seed))


def render_buffers(
    scene: Scene, *, name: str = "", shutter: str | ShutterWindow = "box", instants: int | None = None
) -> SceneBuffers:
    """Render the sharp frame's buffers and the accumulated target of any Scene (module table).

    instants: None takes `required_instants(scene)` (consecutive instants move every visible point by
    less than MAX_STEP = 1/4 pixel); an int takes that many.
    """
    window = get_shutter(shutter)
    frame = render(scene, 0.0)
    positions = trace(scene, np.array([-1.0, 1.0]))  # (2, 2, H, W)
    grid = np.stack(np.meshgrid(np.arange(scene.width), np.arange(scene.height), indexing="xy")).astype(np.float64)
    offset_prev = (positions[0] - grid)[None]
    offset_next = (positions[1] - grid)[None]
    velocity = 0.5 * (positions[1] - positions[0])[None]
    target, count = accumulate(scene, shutter=window, instants=instants)
    background = None
    # The background: the farthest opaque layer of constant depth, given only if it does not move.
    opaque = [i for i, layer in enumerate(scene.layers) if layer.texture.opaque and layer.depth.is_constant]
    if opaque:
        farthest = min(opaque, key=lambda i: scene.layers[i].depth.i0)
        if scene.is_static_layer(farthest):
            only = Scene(scene.height, scene.width, (scene.layers[farthest],), scene.camera)
            background = render(only, 0.0).color
    return SceneBuffers(
        name=name,
        color=frame.color,
        depth=frame.depth,
        velocity=velocity,
        offset_prev=offset_prev,
        offset_next=offset_next,
        target=target,
        background=background,
        shutter=window,
        instants=count,
        scene=scene,
    )


def make_scene(
    name: str,
    *,
    height: int = 128,
    width: int = 128,
    seed: int = 0,
    shutter: str | ShutterWindow = "box",
    instants: int | None = None,
) -> SceneBuffers:
    """Render preset `name` (one of PRESETS) at height x width pixels.

    seed: jitters the preset's positions, speeds and directions (deterministic). shutter: a window
    name or object (`diffblur.shutters`). instants: accumulation count, None for the quarter-pixel rule.

    >>> scene = make_scene("translate", height=32, width=32)
    >>> scene.color.shape, scene.velocity.shape, scene.target.shape
    ((1, 3, 32, 32), (1, 2, 32, 32), (1, 3, 32, 32))
    """
    scene = preset_scene(name, height=height, width=width, seed=seed)
    if instants is not None:
        instants = checks.require_positive_int("instants", instants)
    return render_buffers(scene, name=name, shutter=shutter, instants=instants)


def save_preset_gallery(out_dir: str | os.PathLike, *, height: int = 128, width: int = 128) -> str:
    """Write preset_gallery.png into out_dir: per preset (rows) the sharp frame, the target, the
    velocity as a colour wheel and the depth. Returns the PNG's path."""
    from diffblur.scenes._gallery import save_gallery

    height, width = _check_size(height, width)
    return save_gallery(out_dir, height=height, width=width)
