"""A set of Mitsuba scenes nothing was tuned on: the four `diffblur.scenes.mitsuba` scenes with their
moving objects moved, their speeds and the camera's scaled, drawn from `UNTUNED_SEED` (used for
nothing else), rendered at 64x64 and cached under .cache/diffblur/untuned.

    PYTHONPATH=. python scripts/mitsuba_untuned.py [--size 64] [--variants 2] [--seed 20261202]

`HELDOUT_SEED` draws a second such set (`--sets heldout` in scripts/compare_variants.py).

`untuned_scenes(size, variants)` returns {name: SceneBuffers}; the command renders them (the cache
makes a second call cheap) and prints each method's PSNR with defaults.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
from pathlib import Path

import numpy as np

#: Draws the untuned variants; used for nothing else in the repository.
UNTUNED_SEED = 20261202
#: Draws a second untuned set, rendered only after composite="instants" was built and its constants
#: chosen (on the tuned scenes), to report it; used for nothing else.
HELDOUT_SEED = 20261203


def _variant(scene, rng):
    """The scene with each moving object shifted (up to 0.25 world units in x and y at t = 0) and its
    motion scaled by 0.6 to 1.4, the camera's translation scaled the same way."""
    from diffblur.scenes.mitsuba import Motion3D

    objects = []
    shift = rng.uniform(-0.25, 0.25, size=2)  # one shift for the scene's moving objects (keeps a propeller whole)
    for o in scene.objects:
        if o.motion.still:
            objects.append(o)
            continue
        scale = rng.uniform(0.6, 1.4)
        to_world = o.to_world.copy()
        to_world[:2, 3] += shift
        m = o.motion
        pivot = tuple(np.asarray(m.pivot) + np.array([*shift, 0.0]))
        motion = Motion3D(tuple(scale * np.asarray(m.translation)), m.axis, scale * m.angle, pivot)
        objects.append(dataclasses.replace(o, to_world=to_world, motion=motion))
    camera = scene.camera
    if any(camera.translation):
        camera = dataclasses.replace(camera, translation=tuple(rng.uniform(0.6, 1.4) * np.asarray(camera.translation)))
    return dataclasses.replace(scene, objects=tuple(objects), camera=camera)


def untuned_scenes(size: int = 64, variants: int = 2, seed: int = UNTUNED_SEED) -> dict:
    from diffblur.scenes.mitsuba import MITSUBA_SCENES, mitsuba_scene, render_mitsuba
    from diffblur.scenes import SceneBuffers
    from diffblur.shutters import get_shutter

    cache = Path(os.environ.get("DIFFBLUR_CACHE", Path.cwd() / ".cache" / "diffblur")) / ("untuned" if seed == UNTUNED_SEED else f"untuned_{seed}")
    cache.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    out = {}
    fields = ("color", "depth", "velocity", "offset_prev", "offset_next", "target")
    for k in range(variants):
        for name in MITSUBA_SCENES:
            scene = _variant(mitsuba_scene(name, height=size, width=size), rng)
            label = f"{name}-{k}"
            path = cache / f"{label}_{size}.npz"
            if path.exists():
                d = np.load(path)
                bg = d["background"] if d["background"].size else None
                out[label] = SceneBuffers(label, *(d[f] for f in fields), bg, get_shutter("box"), int(d["instants"]), scene)
                continue
            b = render_mitsuba(scene)
            np.savez_compressed(path, **{f: getattr(b, f) for f in fields}, background=b.background if b.background is not None else np.zeros(0), instants=b.instants)
            out[label] = b
    return out


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--variants", type=int, default=2)
    parser.add_argument("--seed", type=int, default=UNTUNED_SEED, help=f"{UNTUNED_SEED} (default) or {HELDOUT_SEED}")
    args = parser.parse_args()
    scenes = untuned_scenes(args.size, args.variants, args.seed)
    for label, b in scenes.items():
        print(label, b.instants, float(np.abs(b.velocity).max()))


if __name__ == "__main__":
    main()
