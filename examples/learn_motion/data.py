"""Training and test data from the project's renderer (`diffblur.scenes`), in NumPy.

Each example is a random layered scene rendered at three instants of the normalised exposure
t in [-1, 1]: the two sharp input frames at t = -1 and t = +1, the sharp middle frame (t = 0) that
the blur layer blurs, with its depth buffer, and the ground truth: the exposure accumulated under a
shutter window (`target`). The true motion of the point seen at each pixel of the middle frame
(`offset_prev` = p(-1) - X, `offset_next` = p(+1) - X) is kept for the report only; training never
reads it.

A scene: a textured background at depth 10-20, still or panned by the camera, and 1-3 objects
(disks, rounded boxes; photographs, or checkers or stripes with periods of 14-28 px) at depths 2-6, each moving on a straight
line (`Translation`) or a parabola (`CurvedPath`, bending by up to 0.45 of its speed). Half-spread
speeds are up to `max_speed` pixels (default size / 12). Each example draws its shutter from
`SHUTTERS`: two symmetric windows and two linear ramps (a ramp makes the direction of motion show
in the blur; a symmetric window cannot tell p(-1) from p(+1)).
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from pathlib import Path

import numpy as np

from diffblur.scenes import (
    Camera,
    CurvedPath,
    ImageTexture,
    Layer,
    Scene,
    Static,
    Translation,
    checkers,
    photo,
    render,
    render_buffers,
    stripes,
)
from diffblur.shutters import LinearRamp, get_shutter

__all__ = ["FIELDS", "SHUTTERS", "TEST_SEED", "TRAIN_SEED", "VALIDATION", "dataset", "random_scene", "render_example"]

#: The training scenes' seed, and the test scenes' (used for nothing else in the repository).
TRAIN_SEED = 24_101
TEST_SEED = 24_977_003
#: The validation split that chose the training options (`validate.py`): (start, count) of TRAIN_SEED's
#: examples, after the 768 the training runs read. The test scenes were never used to choose anything.
VALIDATION = (768, 64)
#: Shutter windows the examples are rendered under; the blur layer is given the example's window.
SHUTTERS = ("box", "tent", LinearRamp(0.8), LinearRamp(-0.8))
#: Arrays of a dataset, each (N, C, H, W) float32 but `shutter` (N,) int, an index into SHUTTERS.
FIELDS = ("frames", "color", "depth", "offset_prev", "offset_next", "target", "shutter")
PHOTOS = ("astronaut", "coffee", "chelsea", "rocket", "camera")
_COLORS = ((0.9, 0.75, 0.1), (0.1, 0.2, 0.6), (0.8, 0.15, 0.1), (0.15, 0.6, 0.2), (0.95, 0.95, 0.9), (0.05, 0.05, 0.05))


def _texture(rng: np.random.Generator, height: int, width: int, *, periodic: bool) -> np.ndarray:
    """(height, width, 3) linear colour: a photograph crop, or (periodic=True) sometimes checkers or stripes."""
    kind = rng.integers(4) if periodic else 0
    kind = max(kind - 1, 0)  # periodic=True: a photograph half the time, else checkers or stripes
    if kind == 0:
        name = PHOTOS[rng.integers(len(PHOTOS))]
        return photo(name, height, width, zoom=float(rng.uniform(1.0, 2.5)), focus=(float(rng.uniform(0.3, 0.7)), float(rng.uniform(0.3, 0.7))))
    a, b = rng.choice(len(_COLORS), size=2, replace=False)
    # Periods of 14-28 px: a finer periodic texture matches itself one period away (many minima).
    period = float(rng.uniform(14.0, 28.0))
    draw = checkers if kind == 1 else stripes
    return draw(height, width, period, _COLORS[a], _COLORS[b], angle=float(rng.uniform(0, math.pi)))


def _shape_alpha(rng: np.random.Generator, size: int, supersample: int = 4) -> np.ndarray:
    """(size, size) anti-aliased coverage of a disk or a rounded box filling most of the square."""
    grid = (np.arange(size * supersample) + 0.5) / supersample - size / 2
    x, y = np.meshgrid(grid, grid, indexing="xy")
    half = size / 2 - 1.0
    if rng.random() < 0.5:
        inside = x * x + y * y <= half * half
    else:
        corner = half * float(rng.uniform(0.1, 0.6))
        hx, hy = half * float(rng.uniform(0.6, 1.0)), half * float(rng.uniform(0.6, 1.0))
        qx = np.maximum(np.abs(x) - (hx - corner), 0.0)
        qy = np.maximum(np.abs(y) - (hy - corner), 0.0)
        inside = (qx * qx + qy * qy <= corner * corner) & (np.abs(x) <= hx) & (np.abs(y) <= hy)
    return inside.reshape(size, supersample, size, supersample).mean(axis=(1, 3))


def _motion(rng: np.random.Generator, max_speed: float):
    speed = float(rng.uniform(0.15, 1.0)) * max_speed
    angle = float(rng.uniform(0, 2 * math.pi))
    velocity = (speed * math.cos(angle), speed * math.sin(angle))
    if rng.random() < 0.5:
        return Translation(velocity)
    bend = float(rng.uniform(0.15, 0.45)) * speed * 2
    turn = angle + (math.pi / 2 if rng.random() < 0.5 else -math.pi / 2)
    return CurvedPath(velocity, (bend * math.cos(turn), bend * math.sin(turn)))


def random_scene(rng: np.random.Generator, size: int, *, max_speed: float | None = None) -> Scene:
    """A random layered scene of size x size pixels (module docstring)."""
    max_speed = size / 12 if max_speed is None else float(max_speed)
    depth = float(rng.uniform(10.0, 20.0))
    pan = (0.0, 0.0)
    if rng.random() < 0.35:
        speed, angle = float(rng.uniform(0.2, 0.7)) * max_speed, float(rng.uniform(0, 2 * math.pi))
        pan = (speed * math.cos(angle) * depth, speed * math.sin(angle) * depth)
    margin = int(math.ceil(2 * max_speed)) + 3
    background = ImageTexture(_texture(rng, size + 2 * margin, size + 2 * margin, periodic=False), None, (-margin, -margin))
    layers = [Layer(background, depth, Static(), "background")]
    depths = np.sort(rng.uniform(2.0, 6.0, size=int(rng.integers(1, 4))))[::-1]
    for k, object_depth in enumerate(depths):
        side = int(rng.uniform(0.25, 0.55) * size)
        alpha = np.pad(_shape_alpha(rng, side), 2)
        color = np.pad(_texture(rng, side, side, periodic=True), ((2, 2), (2, 2), (0, 0)), mode="edge")
        corner = (int(rng.integers(-side // 4, size - 3 * side // 4)) - 2, int(rng.integers(-side // 4, size - 3 * side // 4)) - 2)
        layers.append(Layer(ImageTexture(color, alpha, corner), float(object_depth), _motion(rng, max_speed), f"object {k}"))
    return Scene(size, size, tuple(layers), Camera(pan=pan))


def render_example(scene: Scene, shutter) -> dict[str, np.ndarray]:
    """One example's arrays (FIELDS but `shutter`), each (1, C, H, W) float32."""
    buffers = render_buffers(scene, shutter=get_shutter(shutter))
    frames = np.concatenate([render(scene, -1.0).color, render(scene, 1.0).color], axis=1)
    arrays = {
        "frames": frames,
        "color": buffers.color,
        "depth": buffers.depth,
        "offset_prev": buffers.offset_prev,
        "offset_next": buffers.offset_next,
        "target": buffers.target,
    }
    return {name: np.asarray(value, dtype=np.float32) for name, value in arrays.items()}


def _generate(seed: int, count: int, size: int, max_speed: float | None, start: int = 0) -> dict[str, np.ndarray]:
    # Example k draws from its own child generator: example k does not depend on `count`.
    children = np.random.SeedSequence(seed).spawn(start + count)[start:]
    parts: dict[str, list[np.ndarray]] = {name: [] for name in FIELDS}
    for child in children:
        rng = np.random.default_rng(child)
        scene = random_scene(rng, size, max_speed=max_speed)
        shutter = int(rng.integers(len(SHUTTERS)))
        for name, value in render_example(scene, SHUTTERS[shutter]).items():
            parts[name].append(value)
        parts["shutter"].append(np.array([shutter]))
    return {name: np.concatenate(values) for name, values in parts.items()}


def dataset(seed: int, count: int, size: int, *, start: int = 0, max_speed: float | None = None, cache: str | Path | None = None, log=print) -> dict[str, np.ndarray]:
    """`count` examples at size x size drawn from `seed` (FIELDS): examples start ... start + count - 1
    of that seed (`start` > 0 skips the first ones: the validation split, `VALIDATION`, is examples 768
    on of TRAIN_SEED, which no training run reads). With `cache` (a folder), the arrays are kept there
    in an .npz named by the arguments and read back on the next call."""
    fields = {"seed": seed, "count": count, "size": size, "max_speed": max_speed, "version": 2}
    key = json.dumps(fields | ({"start": start} if start else {}), sort_keys=True)
    path = None
    if cache is not None:
        path = Path(cache) / f"learn_motion_{hashlib.sha256(key.encode()).hexdigest()[:16]}.npz"
        if path.exists():
            with np.load(path) as stored:
                return {name: stored[name] for name in FIELDS}
    started = time.perf_counter()
    arrays = _generate(seed, count, size, max_speed, start)
    if log is not None:
        log(f"rendered {count} scenes at {size}x{size} (seed {seed}) in {time.perf_counter() - started:.1f} s")
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path.with_suffix(".tmp.npz"), **arrays)
        path.with_suffix(".tmp.npz").replace(path)
    return arrays
