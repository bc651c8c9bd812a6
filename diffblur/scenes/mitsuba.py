"""Ground truth from a physically based renderer: 3D scenes rendered by Mitsuba 3 (the CPU
`scalar_rgb` variant, the optional extra `diffblur[mitsuba]`), returned as the same
`diffblur.scenes.SceneBuffers` as the project's 2.5D renderer, so that every method is measured on
what a real renderer makes: a perspective camera, textured boxes, spheres and planes tilted to the
view, depth in world units (2 to 12 here), offsets from each pixel's 3D hit point.

| field | how |
|---|---|
| color | the scene at t = 0, `COLOR_SPP` multi-jittered samples per pixel (box pixel filter) |
| depth | distance along the view axis of the point hit by the ray through the pixel centre at t = 0 |
| offset_prev, offset_next | that point moved by its object's motion to t = -1, +1 and projected by the camera at that instant, minus the pixel centre |
| velocity | (offset_next - offset_prev) / 2 |
| target | sum_k w_k render(t_k): `diffblur.shutters.instants`, `TARGET_SPP` samples per instant, enough instants that consecutive ones move every hit point by less than 1/4 px |
| background | the static objects alone at t = 0 when the camera is still (None for a moving camera) |

Lighting is one directional light along the view axis (the camera's "headlight"): faces shade by
their tilt to the view, and shadows fall behind the objects that cast them, so the blur, not a
moving shadow, is what differs between instants. With a delta light and no environment the direct
integrator is deterministic per hit point; the only noise is the pixel filter's sampling.

Motions are rigid and defined in world space: `Motion3D(translation, axis, angle, pivot)` moves a
point P at t = 0 to R(axis, angle t) (P - pivot) + pivot + translation t; the camera translates by
`Camera3D.translation` t, keeping its orientation. Mitsuba 3 has no animated transforms, so each
instant is its own scene, loaded from a dict with the objects placed at that instant.

`projection_check` compares the offsets with the renderer itself: the projection of each t = 0 hit
point lands on its own pixel centre, and the renderer's position buffer at t = -1, +1, read at
X + offset, holds the moved point.

`mitsuba_buffers(name)` renders one of `MITSUBA_SCENES`, cached as .npz files under `cache_dir`
(by default `DIFFBLUR_CACHE` or `.cache/diffblur` in the working directory).
"""

from __future__ import annotations

import hashlib
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from diffblur import checks
from diffblur.scenes import MAX_STEP, SceneBuffers
from diffblur.shutters import ShutterWindow, get_shutter, instants as shutter_instants

__all__ = [
    "COLOR_SPP",
    "MITSUBA_SCENES",
    "TARGET_SPP",
    "Camera3D",
    "Motion3D",
    "Object3D",
    "Scene3D",
    "mitsuba_buffers",
    "mitsuba_scene",
    "projection_check",
    "render_mitsuba",
]

#: Samples per pixel of the sharp frame (t = 0): 8 x 8 multi-jittered.
COLOR_SPP = 64
#: Samples per pixel of each instant of the target (with ~100 instants, ~400 per pixel in all).
TARGET_SPP = 4
#: The four scenes of the ground truth.
MITSUBA_SCENES = ("moving_box", "propeller", "dolly", "crossing")
#: The instant count's ceiling.
_INSTANT_CAP = 4096
#: Instants at which the paths are probed to count the instants the target needs.
_PROBE_TIMES = 65


def _mitsuba() -> Any:
    try:
        import mitsuba as mi
    except ImportError as error:  # pragma: no cover - the extra is part of dev
        raise ImportError("diffblur.scenes.mitsuba needs Mitsuba 3: pip install 'diffblur[mitsuba]'") from error
    if mi.variant() != "scalar_rgb":
        mi.set_variant("scalar_rgb")
    return mi


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """3 x 3 rotation by `angle` radians about the unit `axis` (right-handed, Rodrigues)."""
    x, y, z = axis
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


@dataclass(frozen=True)
class Motion3D:
    """A rigid motion in world units: P(t) = R(axis, angle t) (P - pivot) + pivot + translation t."""

    translation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    angle: float = 0.0
    pivot: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def matrix(self, t: float) -> np.ndarray:
        """4 x 4 world-to-world matrix from t = 0 to t."""
        axis = np.asarray(self.axis, dtype=np.float64)
        rotation = _rotation(axis / np.linalg.norm(axis), self.angle * t)
        pivot = np.asarray(self.pivot, dtype=np.float64)
        out = np.eye(4)
        out[:3, :3] = rotation
        out[:3, 3] = pivot - rotation @ pivot + np.asarray(self.translation, dtype=np.float64) * t
        return out

    @property
    def still(self) -> bool:
        return self.angle == 0.0 and not any(self.translation)


@dataclass(frozen=True)
class Object3D:
    """A Mitsuba shape: `shape` is its dict without `to_world` (type, bsdf, ...), placed at t = 0 by
    `to_world` (4 x 4) and moved by `motion`."""

    name: str
    shape: dict
    to_world: np.ndarray
    motion: Motion3D = field(default_factory=Motion3D)


@dataclass(frozen=True)
class Camera3D:
    """A perspective camera at `origin` looking at `target` (world units), `fov` degrees across the
    image width, translating by `translation` t."""

    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    target: tuple[float, float, float] = (0.0, 0.0, -1.0)
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    fov: float = 40.0
    translation: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def to_world(self, t: float) -> np.ndarray:
        """4 x 4 camera-to-world matrix at t, as Mitsuba's look_at builds it (camera +z forward,
        +y up, +x to the image's left)."""
        shift = np.asarray(self.translation, dtype=np.float64) * t
        origin = np.asarray(self.origin, dtype=np.float64) + shift
        forward = np.asarray(self.target, dtype=np.float64) - np.asarray(self.origin, dtype=np.float64)
        forward /= np.linalg.norm(forward)
        left = np.cross(np.asarray(self.up, dtype=np.float64), forward)
        left /= np.linalg.norm(left)
        up = np.cross(forward, left)
        out = np.eye(4)
        out[:3, 0], out[:3, 1], out[:3, 2], out[:3, 3] = left, up, forward, origin
        return out


@dataclass(frozen=True)
class Scene3D:
    """Objects seen by a camera, rendered at height x width pixels."""

    height: int
    width: int
    objects: tuple[Object3D, ...]
    camera: Camera3D = field(default_factory=Camera3D)
    name: str = ""


def project(camera: Camera3D, t: float, points: np.ndarray, height: int, width: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Image coordinates (x, y) in the project's pixel convention (centres at integers) and the depth
    along the view axis of world points (..., 3) seen by the camera at t."""
    inverse = np.linalg.inv(camera.to_world(t))
    local = points @ inverse[:3, :3].T + inverse[:3, 3]
    tan_x = math.tan(math.radians(camera.fov) / 2.0)
    tan_y = tan_x * height / width
    z = local[..., 2]
    u = 0.5 - local[..., 0] / (2.0 * tan_x * z)
    v = 0.5 - local[..., 1] / (2.0 * tan_y * z)
    return u * width - 0.5, v * height - 0.5, z


def _matrix(mi: Any, m: np.ndarray) -> Any:
    return mi.ScalarTransform4f(m.tolist())


def _scene_dict(mi: Any, scene: Scene3D, t: float, *, integrator: dict, spp: int, objects: tuple[Object3D, ...] | None = None) -> dict:
    camera = scene.camera
    view = camera.to_world(0.0)[:3, 2]
    d: dict[str, Any] = {
        "type": "scene",
        "integrator": integrator,
        "sensor": {
            "type": "perspective",
            "fov": camera.fov,
            "fov_axis": "x",
            "near_clip": 0.01,
            "far_clip": 1000.0,
            "to_world": _matrix(mi, camera.to_world(t)),
            "film": {"type": "hdrfilm", "width": scene.width, "height": scene.height, "rfilter": {"type": "box"}, "pixel_format": "rgb"},
            "sampler": {"type": "multijitter", "sample_count": spp},
        },
        "light": {"type": "directional", "direction": view.tolist(), "irradiance": 3.0},
    }
    for o in scene.objects if objects is None else objects:
        d[o.name] = dict(o.shape, to_world=_matrix(mi, o.motion.matrix(t) @ o.to_world))
    return d


def _render(mi: Any, scene: Scene3D, t: float, *, spp: int, seed: int, aov: str | None = None, objects=None) -> np.ndarray:
    integrator = {"type": "direct"} if aov is None else {"type": "aov", "aovs": f"a:{aov}"}
    image = mi.render(mi.load_dict(_scene_dict(mi, scene, t, integrator=integrator, spp=spp, objects=objects)), spp=spp, seed=seed)
    return np.array(image, dtype=np.float64)


def _hits(mi: Any, scene: Scene3D, t: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """World points (H, W, 3) hit at t by the rays through the pixel centres, and the index of the
    object hit (H, W), -1 where the ray misses."""
    loaded = mi.load_dict(_scene_dict(mi, scene, t, integrator={"type": "direct"}, spp=1))
    sensor = loaded.sensors()[0]
    names = [o.name for o in scene.objects]
    height, width = scene.height, scene.width
    points = np.zeros((height, width, 3))
    index = np.full((height, width), -1, dtype=np.int64)
    for i in range(height):
        for j in range(width):
            ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f((j + 0.5) / width, (i + 0.5) / height), mi.Point2f(0.5, 0.5))
            hit = loaded.ray_intersect(ray)
            if hit.is_valid():
                points[i, j] = (hit.p[0], hit.p[1], hit.p[2])
                index[i, j] = names.index(hit.shape.id())
    return points, index


def _moved(scene: Scene3D, points: np.ndarray, index: np.ndarray, t: float) -> np.ndarray:
    """The hit points (H, W, 3) moved by their objects' motions from t = 0 to t."""
    out = points.copy()
    for k, o in enumerate(scene.objects):
        mine = index == k
        m = o.motion.matrix(t)
        out[mine] = points[mine] @ m[:3, :3].T + m[:3, 3]
    return out


def _paths(scene: Scene3D, points: np.ndarray, index: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Image positions (T, 2, H, W) of the hit points at the times."""
    out = []
    for t in times:
        x, y, _ = project(scene.camera, float(t), _moved(scene, points, index, float(t)), scene.height, scene.width)
        out.append(np.stack([x, y]))
    return np.stack(out)


def _required_instants(path: np.ndarray) -> int:
    """Fewest stratified instants such that consecutive ones move every hit point < MAX_STEP px,
    from positions on `_PROBE_TIMES` even instants (the speed is smooth at this resolution)."""
    steps = np.hypot(*(path[1:] - path[:-1]).transpose(1, 0, 2, 3))
    speed = float(steps.max()) * (_PROBE_TIMES - 1) / 2.0  # px per unit t
    return int(min(max(1, math.ceil(2.0 * speed / MAX_STEP)), _INSTANT_CAP))


def render_mitsuba(scene: Scene3D, *, shutter: str | ShutterWindow = "box", instants: int | None = None, seed: int = 0) -> SceneBuffers:
    """Render the sharp frame's buffers and the accumulated target of a Scene3D (module table)."""
    mi = _mitsuba()
    window = get_shutter(shutter)
    points, index = _hits(mi, scene)
    if np.any(index < 0):
        raise ValueError(f"scene {scene.name!r}: {int(np.sum(index < 0))} pixel rays hit nothing; add a wall behind the objects")
    height, width = scene.height, scene.width
    _, _, depth = project(scene.camera, 0.0, points, height, width)
    ends = _paths(scene, points, index, np.array([-1.0, 1.0]))
    centre = np.stack(np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64), indexing="xy"))
    offset_prev, offset_next = ends[0] - centre, ends[1] - centre
    if instants is None:
        instants = _required_instants(_paths(scene, points, index, np.linspace(-1.0, 1.0, _PROBE_TIMES)))
    count = checks.require_positive_int("instants", instants)
    times, weights = shutter_instants(window, count)
    target = np.zeros((height, width, 3))
    for k, (t, w) in enumerate(zip(times, weights)):
        target += w * _render(mi, scene, float(t), spp=TARGET_SPP, seed=seed * _INSTANT_CAP + k + 1)
    color = _render(mi, scene, 0.0, spp=COLOR_SPP, seed=seed * _INSTANT_CAP)
    background = None
    if not any(scene.camera.translation):
        still = tuple(o for o in scene.objects if o.motion.still)
        background = _render(mi, scene, 0.0, spp=COLOR_SPP, seed=seed * _INSTANT_CAP, objects=still).transpose(2, 0, 1)[None]
    return SceneBuffers(
        name=scene.name,
        color=color.transpose(2, 0, 1)[None],
        depth=depth[None, None],
        velocity=(0.5 * (offset_next - offset_prev))[None],
        offset_prev=offset_prev[None],
        offset_next=offset_next[None],
        target=target.transpose(2, 0, 1)[None],
        background=background,
        shutter=window,
        instants=count,
        scene=scene,  # type: ignore[arg-type]  # a Scene3D: render more instants with render_mitsuba
    )


def projection_check(scene: Scene3D, buffers: SceneBuffers, *, spp: int = 16) -> dict[str, float]:
    """How well the buffers agree with the renderer, in pixels.

    center_px: the largest distance from a pixel centre to the projection of its t = 0 hit point
    (by `project`, the camera model the offsets use). offset_px: the median and 90th percentile,
    over pixels whose 3 x 3 neighbourhood sees one object at t = 0 and at the instant, of the
    distance between the moved hit point and the renderer's own position buffer at t = -1 and +1
    read bilinearly at X + offset, measured in pixels at the point's depth, over the points that
    move more than half a pixel (offset_pixels of them, both ends counted)."""
    mi = _mitsuba()
    points, index = _hits(mi, scene)
    height, width = scene.height, scene.width
    x, y, depth = project(scene.camera, 0.0, points, height, width)
    cx, cy = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64), indexing="xy")
    report = {"center_px": float(np.max(np.hypot(x - cx, y - cy)))}
    pixel = 2.0 * math.tan(math.radians(scene.camera.fov) / 2.0) / width  # world size of a pixel per unit depth
    errors = []
    for t, offset in ((-1.0, buffers.offset_prev[0]), (1.0, buffers.offset_next[0])):
        rendered = _render(mi, scene, t, spp=spp, seed=7, aov="position")[..., :3]
        _, ids = _hits(mi, scene, t)
        moved = _moved(scene, points, index, t)
        px, py = cx + offset[0], cy + offset[1]
        inside = (px >= 1) & (px <= width - 2) & (py >= 1) & (py <= height - 2)
        x0 = np.clip(np.floor(px).astype(int), 0, width - 2)
        y0 = np.clip(np.floor(py).astype(int), 0, height - 2)
        fx, fy = (px - x0)[..., None], (py - y0)[..., None]
        read = (
            rendered[y0, x0] * (1 - fx) * (1 - fy) + rendered[y0, x0 + 1] * fx * (1 - fy)
            + rendered[y0 + 1, x0] * (1 - fx) * fy + rendered[y0 + 1, x0 + 1] * fx * fy
        )
        # The renderer's rays at t hit the point's own object around the bilinear footprint (4 x 4
        # pixel centres: the position buffer averages its pixels' samples, which mix objects at a
        # silhouette), and X's 3 x 3 neighbours hit that object at t = 0.
        window = np.stack([ids[np.clip(y0 + a, 0, height - 1), np.clip(x0 + b, 0, width - 1)] for a in (-1, 0, 1, 2) for b in (-1, 0, 1, 2)])
        clean = inside & np.all(window == index, axis=0)
        own = np.stack([index[np.clip(np.arange(height)[:, None] + a, 0, height - 1), np.clip(np.arange(width)[None] + b, 0, width - 1)] for a in (-1, 0, 1) for b in (-1, 0, 1)])
        clean &= (np.ptp(own, axis=0) == 0) & (np.hypot(offset[0], offset[1]) > 0.5)  # moving points only
        errors.append((np.linalg.norm(read - moved, axis=-1) / (pixel * depth))[clean])
    error = np.concatenate(errors)
    report.update(offset_px_median=float(np.median(error)), offset_px_90=float(np.percentile(error, 90)), offset_pixels=int(error.size))
    return report


def _material(mi: Any, color0: tuple, color1: tuple, scale: float) -> dict:
    return {
        "type": "diffuse",
        "reflectance": {
            "type": "checkerboard",
            "color0": {"type": "rgb", "value": list(color0)},
            "color1": {"type": "rgb", "value": list(color1)},
            "to_uv": mi.ScalarTransform4f().scale([scale, scale, 1.0]),
        },
    }


def _place(translate=(0.0, 0.0, 0.0), scale=(1.0, 1.0, 1.0), rotations=()) -> np.ndarray:
    """4 x 4: scale, then the rotations ((axis, degrees), ...) in order, then translate."""
    m = np.diag([*scale, 1.0]).astype(np.float64)
    for axis, degrees in rotations:
        r = np.eye(4)
        axis = np.asarray(axis, dtype=np.float64)
        r[:3, :3] = _rotation(axis / np.linalg.norm(axis), math.radians(degrees))
        m = r @ m
    m[:3, 3] += np.asarray(translate, dtype=np.float64)
    return m


def _wall(mi: Any, depth: float, half: float, colors=((0.75, 0.7, 0.6), (0.25, 0.3, 0.4)), scale: float = 8.0) -> Object3D:
    """A textured rectangle facing the camera at `depth` along -z, 2 half wide."""
    return Object3D("wall", {"type": "rectangle", "bsdf": _material(mi, colors[0], colors[1], scale)}, _place((0.0, 0.0, -depth), (half, half, 1.0)))


def mitsuba_scene(name: str, *, height: int = 64, width: int = 64) -> Scene3D:
    """One of `MITSUBA_SCENES` (camera at the origin looking along -z, 40 degrees across; depth in
    world units):

    - moving_box: a box tilted to the view, 6 away, moving right behind a still post (4 away), before a
      wall at 10;
    - propeller: three blades on a hub 4 away, turning 0.35 rad each way in a plane tilted 30 degrees
      to the view, before a wall at 8;
    - dolly: the camera moving sideways over a floor tilted to the view (2 to 12 away), a sphere at 3,
      a box at 5 and a wall at 10;
    - crossing: a box 4 away moving right and a sphere 6 away moving left, crossing before a wall at 10.
    """
    checks.require_choice("name", name, MITSUBA_SCENES)
    height = checks.require_positive_int("height", height)
    width = checks.require_positive_int("width", width)
    mi = _mitsuba()
    camera = Camera3D()
    if name == "moving_box":
        objects = (
            _wall(mi, 10.0, 6.0),
            Object3D("post", {"type": "cube", "bsdf": _material(mi, (0.8, 0.2, 0.2), (0.9, 0.8, 0.3), 6.0)}, _place((0.15, 0.0, -4.0), (0.12, 2.0, 0.12))),
            Object3D(
                "box",
                {"type": "cube", "bsdf": _material(mi, (0.2, 0.5, 0.9), (0.9, 0.9, 0.9), 4.0)},
                _place((-0.2, 0.1, -6.0), (0.45, 0.45, 0.45), (((0, 1, 0), 35.0), ((1, 0, 0), 25.0))),
                Motion3D(translation=(0.55, 0.0, 0.0)),
            ),
        )
    elif name == "propeller":
        tilt = ((1, 0, 0), -30.0)
        axis = _place(rotations=(tilt,))[:3, 2]
        blades = tuple(
            Object3D(
                f"blade{k}",
                # A colour per blade: Mitsuba merges meshes that share a material into one shape.
                {"type": "cube", "bsdf": _material(mi, (0.9, 0.6 - 0.1 * k, 0.1 + 0.1 * k), (0.3, 0.2, 0.6), 3.0)},
                _place((0.0, 0.0, -4.0), (0.6, 0.1, 0.03), (((0, 0, 1), 120.0 * k + 15.0), tilt)) @ _place((1.0, 0.0, 0.0)),
                Motion3D(axis=tuple(axis), angle=0.35, pivot=(0.0, 0.0, -4.0)),
            )
            for k in range(3)
        )
        hub = Object3D(
            "hub",
            {"type": "sphere", "bsdf": _material(mi, (0.8, 0.8, 0.8), (0.2, 0.2, 0.2), 6.0)},
            _place((0.0, 0.0, -4.0), (0.16, 0.16, 0.16)),
            Motion3D(axis=tuple(axis), angle=0.35, pivot=(0.0, 0.0, -4.0)),
        )
        objects = (_wall(mi, 8.0, 5.0), *blades, hub)
    elif name == "dolly":
        camera = Camera3D(translation=(0.3, 0.0, 0.0))
        objects = (
            _wall(mi, 10.0, 6.0),
            Object3D("floor", {"type": "rectangle", "bsdf": _material(mi, (0.5, 0.6, 0.4), (0.2, 0.25, 0.15), 10.0)}, _place((0.0, -1.0, -6.0), (6.0, 6.0, 1.0), (((1, 0, 0), -80.0),))),
            Object3D("ball", {"type": "sphere", "bsdf": _material(mi, (0.9, 0.3, 0.3), (0.95, 0.9, 0.85), 8.0)}, _place((-0.4, -0.2, -3.0), (0.35, 0.35, 0.35), (((0, 1, 0), 30.0),))),
            Object3D("box", {"type": "cube", "bsdf": _material(mi, (0.3, 0.4, 0.9), (0.9, 0.9, 0.5), 4.0)}, _place((0.8, 0.1, -5.0), (0.5, 0.5, 0.5), (((0, 1, 0), 40.0), ((1, 0, 0), 20.0)))),
        )
    else:  # crossing
        objects = (
            _wall(mi, 10.0, 6.0),
            Object3D(
                "box",
                {"type": "cube", "bsdf": _material(mi, (0.2, 0.7, 0.4), (0.95, 0.95, 0.8), 4.0)},
                _place((-0.15, 0.15, -4.0), (0.35, 0.35, 0.35), (((0, 1, 0), 30.0), ((1, 0, 0), 20.0))),
                Motion3D(translation=(0.3, 0.0, 0.0)),
            ),
            Object3D(
                "ball",
                {"type": "sphere", "bsdf": _material(mi, (0.9, 0.4, 0.2), (0.3, 0.2, 0.7), 8.0)},
                _place((0.3, -0.2, -6.0), (0.6, 0.6, 0.6), (((1, 0, 0), 60.0),)),
                Motion3D(translation=(-0.45, 0.0, 0.0)),
            ),
        )
    return Scene3D(height, width, objects, camera, name)


def _cache_dir(cache_dir: str | os.PathLike | None) -> Path:
    if cache_dir is not None:
        return Path(cache_dir)
    return Path(os.environ.get("DIFFBLUR_CACHE", Path.cwd() / ".cache" / "diffblur"))


def mitsuba_buffers(name: str, *, height: int = 64, width: int = 64, shutter: str = "box", cache_dir: str | os.PathLike | None = None) -> SceneBuffers:
    """`render_mitsuba(mitsuba_scene(name, ...))`, cached on disk (one .npz per scene, size, shutter
    and version of this module's scene definitions and Mitsuba)."""
    mi = _mitsuba()
    scene = mitsuba_scene(name, height=height, width=width)
    key = hashlib.sha256(f"{Path(__file__).read_bytes()!r}{mi.__version__}{shutter}".encode()).hexdigest()[:12]
    path = _cache_dir(cache_dir) / "mitsuba" / f"{name}_{height}x{width}_{shutter}_{key}.npz"
    fields = ("color", "depth", "velocity", "offset_prev", "offset_next", "target")
    if path.exists():
        data = np.load(path)
        background = data["background"] if data["background"].size else None
        return SceneBuffers(name, *(data[f] for f in fields), background, get_shutter(shutter), int(data["instants"]), scene)  # type: ignore[arg-type]
    buffers = render_mitsuba(scene, shutter=shutter)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix(".partial.npz")
    background = buffers.background if buffers.background is not None else np.zeros(0)
    np.savez_compressed(partial, **{f: getattr(buffers, f) for f in fields}, background=background, instants=buffers.instants)
    partial.replace(path)
    return buffers
