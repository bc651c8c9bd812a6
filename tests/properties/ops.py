"""The ops under property test, one `Op` each: adding an op is adding one entry to OPS.

An entry says how to build the op's inputs from a drawn `Example` (seeded NumPy float64 arrays),
how to call it with a backend's namespace (`torch_impl` or `jax_impl`), and which properties it
promises. Each property test in test_properties.py runs on every entry that declares it:

- bounds: the output lies in [low, high] (for the blurs: per image and channel, within the
  input's colour range, i.e. a convex combination of input colours);
- constant: a constant image stays that constant under any motion;
- identity: with the motion input set to zero the output is `identity(inputs)`;
- parity: with the motion negated the output is the same (+1, a symmetric shutter) or negated (-1);
- shift: translating every spatial input by a multiple of `shift` pixels translates the output,
  away from the borders (the blurs take a global velocity for this one);
- finiteness (every entry): outputs and gradients finite for the extremes of `Example`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

#: Speeds (pixels) the examples mix: zero, below any epsilon, ordinary, far beyond the image.
SPEEDS = {"zero": 0.0, "tiny": 1e-8, "subpixel": 0.3, "normal": 2.5, "huge": 1e4}
#: Depth layouts: all tied, a few layers (ties and pairs within the soft band), all different.
DEPTHS = ("tied", "layers", "random")
#: Soft depth bands: the default and a near-step one.
EXTENTS = (0.1, 1e-9)

IMAGE_SHAPE = (2, 2, 20, 21)  # not a multiple of the reconstruct tile (4); translation needs room
TILE = 4


@dataclass(frozen=True)
class Example:
    """What hypothesis draws; each entry turns it into arrays with `rng()`."""

    seed: int
    speed: str  # a key of SPEEDS, "mixed" (one of them per pixel) or "spread" (mixed times 1 to 1.5)
    depth: str
    extent: float
    global_motion: bool = False  # one velocity for the whole image (the translation property)
    shift: tuple[int, int] = (0, 0)  # (rows, columns), for the translation property

    def rng(self) -> np.random.Generator:
        return np.random.default_rng(self.seed)


def _speeds(example: Example, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    if example.speed == "mixed":
        return rng.choice(np.array(list(SPEEDS.values())), size=shape)
    if example.speed == "spread":  # no two alike: largest-magnitude picks are not decided by rounding
        return rng.choice(np.array(list(SPEEDS.values())), size=shape) * rng.uniform(1.0, 1.5, size=shape)
    return np.full(shape, SPEEDS[example.speed])


def vectors(example: Example, rng: np.random.Generator, batch: int, height: int, width: int) -> np.ndarray:
    """(B, 2, H, W) vectors of the example's speeds in random directions (one per image if global)."""
    spatial = (1, 1) if example.global_motion else (height, width)
    angle = rng.uniform(0, 2 * np.pi, size=(batch, 1, *spatial))
    speed = _speeds(example, rng, (batch, 1, *spatial))
    if example.global_motion:  # keep the whole blur inside the translation test's margin
        speed = np.minimum(speed, 2.0)
    field_ = speed * np.concatenate([np.cos(angle), np.sin(angle)], axis=1)
    return np.broadcast_to(field_, (batch, 2, height, width)).copy()


def depths(example: Example, rng: np.random.Generator, batch: int, height: int, width: int) -> np.ndarray:
    shape = (batch, 1, height, width)
    if example.depth == "tied":
        return np.full(shape, 1.5)
    if example.depth == "layers":  # exact ties, and a pair closer than the default soft band
        return rng.choice(np.array([1.0, 1.05, 2.0]), size=shape)
    return rng.uniform(0.5, 3.0, size=shape)


def image_inputs(example: Example) -> dict[str, np.ndarray]:
    rng = example.rng()
    b, c, h, w = IMAGE_SHAPE
    return {"color": rng.random((b, c, h, w)), "velocity": vectors(example, rng, b, h, w), "depth": depths(example, rng, b, h, w)}


def color_range(inputs: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Per image and channel, the input colour's min and max (B, C, 1, 1)."""
    color = inputs["color"]
    return color.min(axis=(2, 3), keepdims=True), color.max(axis=(2, 3), keepdims=True)


def blur_margin(inputs: dict[str, np.ndarray]) -> int:
    """Pixels from the border beyond which a global-velocity blur reads nothing outside the image."""
    return int(math.ceil(float(np.abs(inputs["velocity"]).max()))) + 2


@dataclass(frozen=True)
class Op:
    name: str
    #: fn(ops, inputs, extent) -> output, with `ops` torch_impl or jax_impl and inputs its arrays.
    call: Callable
    #: Example -> dict of NumPy inputs (float64, or integer where the op takes integers).
    make: Callable[[Example], dict[str, np.ndarray]]
    #: Floating inputs the gradient is taken with respect to.
    differentiable: tuple[str, ...]
    #: NumPy inputs -> (low, high), broadcastable to the output.
    bounds: Callable | None = None
    #: The input that carries the motion (set to zero for `identity`, negated for `parity`).
    motion: str | None = None
    identity: Callable | None = None
    parity: int | None = None
    constant: bool = False
    #: Translations by multiples of this many pixels commute with the op (None: not promised).
    shift: int | None = None
    #: NumPy inputs -> pixels to leave out at every border when comparing translated outputs.
    margin: Callable = field(default=lambda inputs: 0)
    #: Inputs with a spatial layout (B, C, H, W) that a translation moves.
    spatial: tuple[str, ...] = ()
    #: Whether the op reads `Example.extent` (the soft depth band); the others ignore it.
    uses_extent: bool = False
    #: The output's spatial grid is the input's divided by this (1: same size).
    output_stride: int = 1
    #: Backends to run on. The JAX layers run on PyTorch only here: each would cost the JAX
    #: suite two more compilations, and tests/equivalence/test_module*.py show that in both
    #: frameworks the layer equals its functional op (to 1e-12) for every option, so it has
    #: the functional op's properties.
    backends: tuple[str, ...] = ("torch", "jax")


BLUR = dict(
    make=image_inputs,
    bounds=color_range,
    motion="velocity",
    identity=lambda inputs: inputs["color"],
    parity=1,
    constant=True,
    shift=1,
    margin=blur_margin,
    spatial=("color", "velocity", "depth"),
)


def _elementwise(rng_inputs: Callable[[Example, np.random.Generator], dict]) -> Callable[[Example], dict]:
    return lambda example: rng_inputs(example, example.rng())


def _depth_pair(example: Example, rng: np.random.Generator) -> dict:
    z_a = depths(example, rng, 2, 5, 6)
    z_b = np.where(rng.random(z_a.shape) < 0.5, z_a, depths(example, rng, 2, 5, 6))  # half of them tie
    return {"z_a": z_a, "z_b": z_b, "extent": np.array(example.extent)}


def _distance_speed(example: Example, rng: np.random.Generator) -> dict:
    speed = _speeds(example, rng, (2, 1, 5, 6))
    distance = speed * rng.choice(np.array([0.0, 0.5, 0.95, 1.0, 1.05, 2.0]), size=speed.shape) + rng.choice(np.array([0.0, 1e-8, 1.0]), size=speed.shape)
    return {"distance": distance, "speed": speed}


def _velocity_field(example: Example, rng: np.random.Generator) -> dict:
    return {"velocity": vectors(example, rng, 2, 21, 26)}


OPS: list[Op] = [
    Op("gather_blur", lambda o, x, e: o.gather_blur(x["color"], x["velocity"], samples=5), differentiable=("color", "velocity"), **BLUR),
    Op(
        "reconstruct",
        lambda o, x, e: o.reconstruct(x["color"], x["velocity"], x["depth"], samples=5, max_radius=float(TILE), jitter="none", soft_z_extent=e),
        differentiable=("color", "velocity", "depth"),
        uses_extent=True,
        **BLUR,
    ),
    Op(
        "bezier_scatter",
        lambda o, x, e: o.bezier_scatter(x["color"], x["depth"], -x["velocity"], x["velocity"], samples=5, soft_z_extent=e),
        differentiable=("color", "velocity", "depth"),
        uses_extent=True,
        **BLUR,
    ),
    Op(
        "MotionBlur-reconstruct",
        lambda o, x, e: o.MotionBlur("reconstruct", exposure=0.75, samples=5, max_radius=float(TILE), jitter="none")(x["color"], x["velocity"], x["depth"]),
        differentiable=("color", "velocity", "depth"),
        backends=("torch",),
        **BLUR,
    ),
    Op(
        "MotionBlur-bezier",
        lambda o, x, e: o.MotionBlur("bezier", exposure=0.75, samples=5)(x["color"], x["velocity"], x["depth"]),
        differentiable=("color", "velocity", "depth"),
        backends=("torch",),
        **BLUR,
    ),
    Op(
        "soft_depth_compare",
        lambda o, x, e: o.soft_depth_compare(x["z_a"], x["z_b"], x["extent"]),
        make=_elementwise(_depth_pair),
        differentiable=("z_a", "z_b", "extent"),
        bounds=lambda inputs: (0.0, 1.0),
        shift=1,
        spatial=("z_a", "z_b"),
    ),
    Op("cone", lambda o, x, e: o.cone(x["distance"], x["speed"]), make=_elementwise(_distance_speed), differentiable=("distance", "speed"), bounds=lambda inputs: (0.0, 1.0)),
    Op("cylinder", lambda o, x, e: o.cylinder(x["distance"], x["speed"]), make=_elementwise(_distance_speed), differentiable=("distance", "speed"), bounds=lambda inputs: (0.0, 1.0)),
    Op(
        "safe_length",
        lambda o, x, e: o.safe_length(x["velocity"]),
        make=_elementwise(_velocity_field),
        differentiable=("velocity",),
        bounds=lambda inputs: (0.0, np.inf),
        motion="velocity",
        identity=lambda inputs: 0.0,
        parity=1,
        shift=1,
        spatial=("velocity",),
    ),
    Op(
        "velocity_from_motion",
        lambda o, x, e: o.velocity_from_motion(x["velocity"], exposure=0.5, max_radius=8.0),
        make=_elementwise(_velocity_field),
        differentiable=("velocity",),
        bounds=lambda inputs: (-8.0, 8.0),
        motion="velocity",
        identity=lambda inputs: 0.0,
        parity=-1,
        shift=1,
        spatial=("velocity",),
    ),
    Op(
        "tile_max",
        lambda o, x, e: o.tile_max(x["velocity"], TILE),
        make=_elementwise(_velocity_field),
        differentiable=("velocity",),
        bounds=lambda inputs: (-np.abs(inputs["velocity"]).max(), np.abs(inputs["velocity"]).max()),
        motion="velocity",
        identity=lambda inputs: 0.0,
        parity=-1,
        shift=TILE,
        margin=lambda inputs: 1,  # the last, partial tile holds other pixels once translated
        spatial=("velocity",),
        output_stride=TILE,
    ),
    Op(
        "neighbor_max",
        lambda o, x, e: o.neighbor_max(x["velocity"]),
        make=_elementwise(_velocity_field),
        differentiable=("velocity",),
        bounds=lambda inputs: (-np.abs(inputs["velocity"]).max(), np.abs(inputs["velocity"]).max()),
        motion="velocity",
        identity=lambda inputs: 0.0,
        parity=-1,
        margin=lambda inputs: 1,
        shift=1,
        spatial=("velocity",),
    ),
]


# Issue 7's ops and options. The adaptive and pyramid options run on PyTorch only here: in JAX
# each costs ~35 s of compilation on the 2-core CI machine (every tap class, every pyramid level,
# float64, float32 and float16); tests/equivalence shows JAX equal to PyTorch on them.
OPS += [
    Op("warp_blend", lambda o, x, e: o.warp_blend(x["color"], x["velocity"], iterations=2), differentiable=("color", "velocity"), **BLUR),
    # PyTorch only here: the same sampling loop as gather_blur (equal for odd counts, tested with
    # JAX == PyTorch in tests/equivalence); JAX would compile it once more per dtype and shape.
    Op("accumulate_warps", lambda o, x, e: o.accumulate_warps(x["color"], x["velocity"], instants=4), differentiable=("color", "velocity"), backends=("torch",), **BLUR),
    Op(
        "reconstruct-adaptive",
        lambda o, x, e: o.reconstruct(x["color"], x["velocity"], x["depth"], samples=7, max_radius=float(TILE), jitter="none", adaptive=True, soft_z_extent=e),
        differentiable=("color", "velocity", "depth"),
        uses_extent=True,
        backends=("torch",),
        **BLUR,
    ),
    Op(
        "gather_blur-pyramid",
        lambda o, x, e: o.gather_blur(x["color"], x["velocity"], samples=5, sampling="pyramid"),
        differentiable=("color", "velocity"),
        backends=("torch",),
        **{**BLUR, "shift": 4},  # the pyramid's 2x2 levels align with the image every 4 px
    ),
]

# The other methods of the PyTorch layer (exposure 0.75 scales the velocity).
OPS += [
    Op(
        f"MotionBlur-{method}",
        lambda o, x, e, method=method, options=options: o.MotionBlur(method, exposure=0.75, **options)(x["color"], x["velocity"]),
        differentiable=("color", "velocity"),
        backends=("torch",),
        **BLUR,
    )
    for method, options in (("gather", {"samples": 5}), ("warp_blend", {"iterations": 2}), ("accumulate", {"instants": 4}))
]


def _motion_ids(example: Example, rng: np.random.Generator) -> dict:
    palette = vectors(example, rng, 2, 4, 1)[..., 0].transpose(0, 2, 1)  # (B, K=4, 2)
    return {"ids": rng.integers(0, 4, size=(2, 1, 7, 9)), "palette": np.ascontiguousarray(palette)}


OPS += [
    Op(
        "interleaved_gradient_noise",
        lambda o, x, e: o.interleaved_gradient_noise(7, 9, dtype=x["like"].dtype),
        make=lambda example: {"like": np.zeros(1)},
        differentiable=(),
        bounds=lambda inputs: (0.0, 1.0 - 2.0**-24),
    ),
    Op(
        "velocity_from_motion_ids",
        lambda o, x, e: o.velocity_from_motion_ids(x["ids"], x["palette"]),
        make=_elementwise(_motion_ids),
        differentiable=("palette",),
        bounds=lambda inputs: (-np.abs(inputs["palette"]).max(), np.abs(inputs["palette"]).max()),
        motion="palette",
        identity=lambda inputs: 0.0,
        parity=-1,
        shift=1,
        spatial=("ids",),
    ),
]

OPS_BY_NAME = {op.name: op for op in OPS}
