"""The held-out family of scenes that `fitting.evaluate` measures recovery on, frozen before tuning.

`family()` builds `count` cases (default 30) at `size` x `size` pixels (default 64) from
`HELDOUT_SEED`, a seed used for nothing else in the repository. Case k draws everything (kind,
textures, shapes, depths, motions, shutter parameters, noise) from its own child generator
(`SeedSequence(seed, spawn_key=(k,))`, what `default_rng(seed).spawn(count)[k]` gives), so case k
does not depend on `count`. The kinds cycle through a 15-long pattern, so 30 cases hold 10 "objects",
8 "pan", 6 "rotation" and 6 "zoom"; even cases use the box shutter and odd ones cycle through tent,
raised cosine, a trapezoid and a linear ramp (the pattern's odd length gives every kind both):

- objects: 1-3 opaque objects (box, rounded box or disk, 12-40 % of the side) at distinct depths in
  [2, 6], each translating by its own half-spread velocity of 2-15 px in a random direction and kept
  at least `EDGE` px inside the image over the exposure, over a still textured background at depth
  10-20. Each object stays at least 60 % visible. Truth: every layer's depth and velocity in the order
  of the scene's layers (the background first, velocity 0), which is also the ID of
  `fitting.scenes.layer_ids`.
- pan: a camera pan over a background at depth Z in [8, 20] (and, in half the cases, a card at the
  same depth, ahead of it in the layer order, which wins the depth ties): every pixel moves by one
  velocity of 2-15 px. Truth: that velocity.
- rotation: a textured disk or propeller turning about its centre by `angle` (rad at t = 1) with
  angle * radius (the rim's speed) in [2, 15] px, over a still background. Truth: centre and angle.
- zoom: a dolly (`Camera(advance=...)`) towards a background at depth Z in [10, 20], in half the
  cases with a still card in front; the fastest image point (a corner, or the card's far corner) moves
  2-15 px. Truth: the camera's advance, Z, and `advance_first_order`, the advance of the first-order
  model `fitting`'s "camera" fits (v = advance (X - c) / Z) whose half-spread equals the background's
  exact one, advance Z^2 / (Z^2 - advance^2) (the dolly's image motion is a homography: at
  advance / Z = 0.3 the two differ by 10 %).

Textures are photographs (scikit-image's, random zoom and focus) or checkers/stripes with periods of
14-30 px (a fine periodic texture would give the loss a minimum per period; no stripes on backgrounds,
whose motion along the stripes would not show), drawn again while nearly flat. Every case also
holds a gaussian noise field of sigma `NOISE_SIGMA` drawn from its generator (`Case.noisy_target`).

`docs/heldout_family.json` freezes the family: per case its name, kind, shutter, truth and the
SHA-256 of its color, target and depth rounded to 1e-9 (so that platform rounding does not change it);
`python -m fitting.heldout --write` regenerates it, and the tests check `family()` against it.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from diffblur.scenes._presets import _disk, _propeller, _rounded_box, _spoked
from diffblur.scenes._textures import PHOTOS, coverage, pad
from diffblur.scenes import Camera, ImageTexture, Layer, Rotation, Scene, SceneBuffers, Static, Translation, checkers, photo, render_buffers, stripes
from diffblur.shutters import LinearRamp, ShutterWindow, Trapezoid
from fitting.scenes import layer_ids

__all__ = ["DEVELOPMENT_SEED", "HELDOUT_SEED", "KINDS", "NOISE_SIGMA", "Case", "case_hash", "family", "frozen", "manifest"]

#: The family's seed: used for nothing else in the repository.
HELDOUT_SEED = 7_340_021
#: The development family's seed (`python -m fitting.evaluate --family development`): the same
#: kinds of scene, drawn apart from the held-out ones, to tune on. Used for nothing else either.
DEVELOPMENT_SEED = 5_550_123
#: The noise every case carries for the noisy evaluation.
NOISE_SIGMA = 0.01
#: Kinds in the order case k takes them (k modulo 15): 5 objects, 4 pan, 3 rotation, 3 zoom.
PATTERN = ("objects", "pan", "rotation", "zoom", "objects", "pan", "objects", "rotation", "pan", "zoom", "objects", "pan", "rotation", "objects", "zoom")
KINDS = ("objects", "pan", "rotation", "zoom")
#: Object motion: half-spread speeds (pixels) of every moving point, the fastest included.
SPEED_RANGE = (2.0, 15.0)
#: Objects stay this many pixels inside the image over the whole exposure.
EDGE = 3
#: Least standard deviation of a texture's linear luminance.
MIN_CONTRAST = 0.06
#: Where the frozen manifest lives, relative to the repository root.
FROZEN_PATH = Path(__file__).resolve().parent.parent / "docs" / "heldout_family.json"


@dataclass(frozen=True, eq=False)
class Case:
    """One held-out scene.

    name ("objects-03"), kind (one of KINDS), shutter (a window name or a `diffblur.shutters` window,
    what the target was rendered with and what a fit should assume), shutter_label (a printable name
    with its parameter), buffers (`diffblur.scenes.SceneBuffers`), ids ((1, 1, H, W) int64 layer index
    seen at each pixel, `fitting.scenes.layer_ids`), truth (plain numbers, see the module docstring),
    noise ((1, 3, H, W) gaussian, sigma NOISE_SIGMA, from the case's own generator).
    """

    name: str
    kind: str
    shutter: str | ShutterWindow
    shutter_label: str
    buffers: SceneBuffers
    ids: np.ndarray
    truth: dict[str, Any]
    noise: np.ndarray

    @property
    def noisy_target(self) -> np.ndarray:
        """The target with the case's noise (sigma NOISE_SIGMA) added."""
        return self.buffers.target + self.noise

    def target(self, sigma: float) -> np.ndarray:
        """The target with the case's noise scaled to standard deviation `sigma` (0: noise-free)."""
        if sigma == 0:
            return self.buffers.target
        return self.buffers.target + self.noise * (sigma / NOISE_SIGMA)


def _child(seed: int, k: int) -> np.random.Generator:
    """Case k's generator: default_rng(seed).spawn(n)[k] for any n > k."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(k,)))


def _colour(rng: np.random.Generator) -> tuple[float, float, float]:
    return tuple(float(c) for c in rng.uniform(0.03, 0.95, 3))


def _pattern(rng: np.random.Generator, height: int, width: int, origin: tuple[int, int], *, stripes_ok: bool = True) -> np.ndarray:
    """A random texture of (height, width) texels whose texel (0, 0) sits at `origin`: a photograph
    (65 %) or checkers (or stripes, when `stripes_ok`) of period 14-30 px in two contrasting colours.
    Drawn again while its luminance is nearly flat (a crop of sky would hide any motion)."""
    for _attempt in range(20):
        if rng.random() < 0.65:
            name = PHOTOS[int(rng.integers(len(PHOTOS)))]
            zoom = float(rng.uniform(1.0, 2.5))
            focus = (float(rng.uniform(0.3, 0.7)), float(rng.uniform(0.3, 0.7)))
            texels = photo(name, height, width, zoom=zoom, focus=focus)
        else:
            a = _colour(rng)
            b = tuple(float(np.clip(1.0 - c + rng.uniform(-0.1, 0.1), 0.02, 0.98)) for c in a)  # contrast
            period = float(rng.uniform(14.0, 30.0))
            angle = float(rng.uniform(0.0, math.pi))
            make = stripes if stripes_ok and rng.random() < 0.4 else checkers
            texels = make(height, width, period, a, b, angle=angle, origin=origin)
        if np.std(texels @ np.array([0.2126, 0.7152, 0.0722])) >= MIN_CONTRAST:
            return texels
    return texels


def _background(rng: np.random.Generator, size: int, margin: float, depth: float, name: str = "background") -> Layer:
    """An opaque still textured layer covering the image plus `margin` px on every side."""
    m = int(math.ceil(margin)) + 2
    # No stripes: a background moving along its stripes would hide that component of the motion.
    texels = _pattern(rng, size + 2 * m, size + 2 * m, (-m, -m), stripes_ok=False)
    return Layer(ImageTexture(texels, None, (-m, -m)), depth, Static(), name)


def _shape(rng: np.random.Generator, half: float) -> tuple[str, tuple[float, float], float]:
    """A random box, rounded box or disk of largest half extent `half`: (kind, half extents, corner
    radius)."""
    kind = ("box", "rounded_box", "disk")[int(rng.integers(3))]
    if kind == "disk":
        return kind, (half, half), half
    aspect = float(rng.uniform(0.7, 1.0))
    halves = (half, half * aspect) if rng.random() < 0.5 else (half * aspect, half)
    radius = float(rng.uniform(0.2, 0.5)) * min(halves) if kind == "rounded_box" else 1e-6
    return kind, halves, radius


def _inside(kind: str, center: tuple[float, float], halves: tuple[float, float], radius: float):
    """inside(x, y) of a shape from `_shape`, centred at `center`."""
    if kind == "disk":
        return _disk(center, halves[0])
    return _rounded_box(center, halves, radius)


def _box(center: tuple[float, float], halves: tuple[float, float]) -> tuple[float, float, float, float]:
    return (center[0] - halves[0], center[1] - halves[1], center[0] + halves[0], center[1] + halves[1])


def _card(rng: np.random.Generator, kind: str, center: tuple[float, float], halves: tuple[float, float], radius: float) -> ImageTexture:
    """A textured shape with a random texture."""
    return _object_texture(_inside(kind, center, halves, radius), _box(center, halves), lambda h, w, o: _pattern(rng, h, w, o))


def _object_texture(inside, box: tuple[float, float, float, float], paint) -> ImageTexture:
    """A textured shape with a transparent border (`diffblur.scenes._presets._object` without its frame)."""
    x0, y0 = int(math.floor(box[0])) - 1, int(math.floor(box[1])) - 1
    x1, y1 = int(math.ceil(box[2])) + 1, int(math.ceil(box[3])) + 1
    h, w = y1 - y0 + 1, x1 - x0 + 1
    alpha = coverage(inside, h, w, origin=(x0, y0))
    return pad(paint(h, w, (x0, y0)), alpha, (x0, y0))


def _direction(rng: np.random.Generator, speed: float) -> tuple[float, float]:
    angle = float(rng.uniform(0.0, 2.0 * math.pi))
    return (round(speed * math.cos(angle), 4), round(speed * math.sin(angle), 4))


def _speed(rng: np.random.Generator) -> float:
    return round(float(rng.uniform(*SPEED_RANGE)), 4)


def _shutter(k: int, rng: np.random.Generator) -> tuple[str | ShutterWindow, str]:
    """Box for even k; odd k cycle through tent, raised cosine, trapezoid and linear ramp."""
    if k % 2 == 0:
        return "box", "box"
    which = (k // 2) % 4
    if which == 0:
        return "tent", "tent"
    if which == 1:
        return "raised_cosine", "raised_cosine"
    if which == 2:
        ramp = round(float(rng.uniform(0.3, 0.7)), 2)
        return Trapezoid(ramp=ramp), f"trapezoid(ramp={ramp})"
    slope = round(float(rng.uniform(0.5, 0.9)) * (1 if rng.random() < 0.5 else -1), 2)
    return LinearRamp(slope=slope), f"linear_ramp(slope={slope})"


def _objects(rng: np.random.Generator, size: int) -> tuple[Scene, dict]:
    bg_depth = round(float(rng.uniform(10.0, 20.0)), 3)
    background = _background(rng, size, 0.0, bg_depth)
    count = int(rng.integers(1, 4))
    # Distinct depths: one per equal slice of [2, 6], in random order.
    edges = np.linspace(2.0, 6.0, count + 1)
    depths = [round(float(rng.uniform(edges[i] + 0.1, edges[i + 1] - 0.1)), 3) for i in range(count)]
    rng.shuffle(depths)
    for _attempt in range(100):
        specs = []
        for depth in depths:
            half = float(rng.uniform(0.12, 0.40)) * size / 2.0
            velocity = _direction(rng, _speed(rng))
            kind, halves, radius = _shape(rng, half)
            # The shape's box plus its motion stays EDGE px inside the image.
            lo = [halves[i] + abs(velocity[i]) + EDGE for i in (0, 1)]
            hi = [size - 1 - lo[i] for i in (0, 1)]
            if lo[0] > hi[0] or lo[1] > hi[1]:
                break
            center = (round(float(rng.uniform(lo[0], hi[0])), 3), round(float(rng.uniform(lo[1], hi[1])), 3))
            specs.append((depth, velocity, kind, halves, radius, center))
        if len(specs) < count:
            continue
        layers = [background]
        for depth, velocity, kind, halves, radius, center in specs:
            layers.append(Layer(_card(rng, kind, center, halves, radius), depth, Translation(velocity), f"{kind} at depth {depth}"))
        scene = Scene(size, size, tuple(layers))
        if _visible_enough(scene):
            truth = {"layers": [{"depth": bg_depth, "velocity": [0.0, 0.0]}] + [{"depth": d, "velocity": list(v)} for d, v, *_ in specs]}
            return scene, truth
    raise RuntimeError("could not place the objects")  # pragma: no cover - 100 tries always suffice


def _visible_enough(scene: Scene, fraction: float = 0.6) -> bool:
    """Every object layer shows at least `fraction` of its own area at t = 0 (and 40 pixels)."""
    from diffblur.scenes import render

    seen = render(scene, 0.0).layer[0, 0]
    for index in range(1, len(scene.layers)):
        alone = render(Scene(scene.height, scene.width, (scene.layers[index],)), 0.0).layer[0, 0]
        own = int(np.sum(alone == 0))
        if own == 0 or np.sum(seen == index) < max(40, fraction * own):
            return False
    return True


def _pan(rng: np.random.Generator, size: int) -> tuple[Scene, dict]:
    depth = round(float(rng.uniform(8.0, 20.0)), 3)
    velocity = _direction(rng, _speed(rng))
    margin = math.hypot(*velocity) + 4
    background = _background(rng, size, margin, depth)
    layers = [background]
    if rng.random() < 0.5:
        # A card at the same depth, listed first so that it wins the ties: it moves with the pan.
        half = float(rng.uniform(0.15, 0.3)) * size
        center = (float(rng.uniform(0.35, 0.65)) * (size - 1), float(rng.uniform(0.35, 0.65)) * (size - 1))
        kind, halves, radius = _shape(rng, half)
        layers.insert(0, Layer(_card(rng, kind, center, halves, radius), depth, Static(), f"{kind} card"))
    camera = Camera(pan=(velocity[0] * depth, velocity[1] * depth))
    return Scene(size, size, tuple(layers), camera), {"velocity": list(velocity), "depth": depth}


def _rotation(rng: np.random.Generator, size: int) -> tuple[Scene, dict]:
    bg_depth = round(float(rng.uniform(10.0, 20.0)), 3)
    background = _background(rng, size, 0.0, bg_depth)
    radius = float(rng.uniform(0.28, 0.40)) * size
    lo, hi = radius + EDGE, size - 1 - radius - EDGE
    center = (round(float(rng.uniform(lo, hi)), 3), round(float(rng.uniform(lo, hi)), 3))
    rim_speed = _speed(rng)
    angle = round(rim_speed / radius * (1 if rng.random() < 0.5 else -1), 5)
    depth = round(float(rng.uniform(2.0, 6.0)), 3)
    base = lambda h, w, o: _pattern(rng, h, w, o)  # noqa: E731
    paint = _spoked(base, center, int(rng.integers(5, 13)))  # radial shading: the turn shows on smooth texture
    if rng.random() < 0.5:
        inside, shape = _disk(center, radius), "disk"
    else:
        blades = int(rng.integers(2, 5))
        inside = _propeller(center, radius, 0.18 * radius, blades, 0.25 * radius, turn=float(rng.uniform(0, 2 * math.pi)))
        shape = f"propeller ({blades} blades)"
    tex = _object_texture(inside, _box(center, (radius, radius)), paint)
    layers = (background, Layer(tex, depth, Rotation(center, angle), shape))
    return Scene(size, size, layers), {"center": list(center), "angle": angle, "radius": round(radius, 4)}


def _exact_speed(distance: float, depth: float, advance: float) -> float:
    """Half-spread of a dolly's image motion at `distance` px from the centre, at `depth`."""
    return distance * advance * depth / (depth * depth - advance * advance)


def _zoom(rng: np.random.Generator, size: int) -> tuple[Scene, dict]:
    depth = round(float(rng.uniform(10.0, 20.0)), 3)
    c = (size - 1) / 2.0
    corner = math.hypot(c, c)
    points = [(corner, depth)]  # (distance from the centre, depth) of the fastest point per layer
    card = None
    if rng.random() < 0.5:
        card_depth = round(float(rng.uniform(0.5, 0.8)) * depth, 3)
        half = float(rng.uniform(0.12, 0.25)) * size
        center = (float(rng.uniform(0.3, 0.7)) * (size - 1), float(rng.uniform(0.3, 0.7)) * (size - 1))
        kind, halves, radius = _shape(rng, half)
        far = math.hypot(abs(center[0] - c) + halves[0], abs(center[1] - c) + halves[1])
        points.append((far, card_depth))
        card = (kind, halves, radius, center, card_depth)
    top = _speed(rng)
    # The advance whose fastest point moves `top` px (bisection on the exact dolly motion).
    low, high = 0.0, 0.9 * min(d for _, d in points)
    for _ in range(80):
        mid = 0.5 * (low + high)
        if max(_exact_speed(r, d, mid) for r, d in points) < top:
            low = mid
        else:
            high = mid
    advance = round(low, 5) * (1 if rng.random() < 0.5 else -1)
    # At the instant the layer is farthest (t = -sign), it shows (1 + |advance| / depth) times more.
    margin = 0.5 * size * abs(advance) / (depth - abs(advance)) * 1.2 + 2
    layers = [_background(rng, size, margin, depth)]
    if card is not None:
        kind, halves, radius, center, card_depth = card
        layers.append(Layer(_card(rng, kind, center, halves, radius), card_depth, Static(), f"{kind} card"))
    scene = Scene(size, size, tuple(layers), Camera(advance=advance, center=(c, c)))
    first_order = advance * depth * depth / (depth * depth - advance * advance)
    return scene, {"advance": advance, "depth": depth, "advance_first_order": round(first_order, 8)}


_BUILDERS = {"objects": _objects, "pan": _pan, "rotation": _rotation, "zoom": _zoom}


def make_case(k: int, *, size: int = 64, seed: int = HELDOUT_SEED) -> Case:
    """Case k of the family (it depends on k, size and seed only)."""
    rng = _child(seed, k)
    kind = PATTERN[k % len(PATTERN)]
    scene, truth = _BUILDERS[kind](rng, size)
    shutter, label = _shutter(k, rng)
    buffers = render_buffers(scene, name=f"{kind}-{k:02d}", shutter=shutter)
    noise = rng.normal(0.0, NOISE_SIGMA, size=buffers.target.shape)
    return Case(f"{kind}-{k:02d}", kind, shutter, label, buffers, layer_ids(buffers), truth, noise)


def family(count: int = 30, size: int = 64, seed: int = HELDOUT_SEED) -> list[Case]:
    """The held-out cases 0 .. count - 1 (see the module docstring)."""
    return [make_case(k, size=size, seed=seed) for k in range(count)]


def _quantised(x: np.ndarray) -> bytes:
    """x rounded to 1e-9 as little-endian int64 (no -0.0, no platform's last-bit rounding)."""
    return np.rint(np.asarray(x, dtype=np.float64) * 1e9).astype("<i8").tobytes()


def case_hash(case: Case) -> str:
    """SHA-256 of the case's color, target and depth, rounded to 1e-9."""
    digest = hashlib.sha256()
    for name in ("color", "target", "depth"):
        array = getattr(case.buffers, name)
        digest.update(name.encode() + str(array.shape).encode())
        digest.update(_quantised(array))
    return digest.hexdigest()


def noise_hash(case: Case) -> str:
    return hashlib.sha256(_quantised(case.noise)).hexdigest()


def manifest(cases: list[Case], *, size: int = 64, seed: int = HELDOUT_SEED) -> dict[str, Any]:
    """The frozen description of `cases` (what docs/heldout_family.json holds)."""
    return {
        "seed": seed,
        "size": size,
        "count": len(cases),
        "noise_sigma": NOISE_SIGMA,
        "regenerate": "python -m fitting.heldout --write",
        "cases": [
            {"name": c.name, "kind": c.kind, "shutter": c.shutter_label, "truth": c.truth, "instants": c.buffers.instants, "sha256": case_hash(c), "noise_sha256": noise_hash(c)}
            for c in cases
        ],
    }


def frozen(path: str | Path = FROZEN_PATH) -> dict[str, Any]:
    """The manifest stored in docs/heldout_family.json."""
    with open(path) as f:
        return json.load(f)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Render the held-out family; with --write, freeze it into docs/heldout_family.json.")
    parser.add_argument("--write", action="store_true", help=f"write the manifest to {FROZEN_PATH}")
    parser.add_argument("--check", action="store_true", help="compare family() with the frozen manifest")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    cases = family()
    seconds = time.perf_counter() - start
    data = manifest(cases)
    for c in data["cases"]:
        print(f"{c['name']:12s} {c['shutter']:24s} instants {c['instants']:4d}  {json.dumps(c['truth'])}")
    print(f"{len(cases)} cases rendered in {seconds:.1f} s")
    if args.write:
        FROZEN_PATH.write_text(json.dumps(data, indent=1) + "\n")
        print(f"wrote {FROZEN_PATH}")
    if args.check:
        stored = frozen()
        if stored != json.loads(json.dumps(data)):
            print("family() differs from the frozen manifest")
            return 1
        print("family() matches the frozen manifest")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
