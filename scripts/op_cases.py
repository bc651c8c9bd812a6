"""Every op and module with one set of inputs: the cases the measurement scripts share
(`measure_compile_vs_eager.py`, `measure_gpu.py`). Run from the repository root as
`PYTHONPATH=. python scripts/<script>.py`; the scripts' folder is then on the import path."""

from __future__ import annotations

import numpy as np

SHAPE = (1, 3, 8, 9)

#: name -> (op name, inputs it takes, options). Inputs: c colour, v velocity, z depth, p/n offsets.
CASES = {
    "soft_depth_compare": ("soft_depth_compare", "zz", {}),
    "cone": ("cone", "dz", {}),
    "cylinder": ("cylinder", "dz", {}),
    "velocity_from_motion": ("velocity_from_motion", "v", {}),
    "tile_max": ("tile_max", "v", {}),
    "neighbor_max": ("neighbor_max", "v", {}),
    "gather_blur": ("gather_blur", "cv", {"samples": 5}),
    "gather_blur impl='tensor'": ("gather_blur", "cv", {"samples": 5, "impl": "tensor"}),
    "gather_blur adaptive": ("gather_blur", "cv", {"samples": 5, "adaptive": True}),
    "reconstruct": ("reconstruct", "cvz", {"samples": 5, "max_radius": 4.0}),
    "reconstruct impl='tensor'": ("reconstruct", "cvz", {"samples": 5, "max_radius": 4.0, "impl": "tensor"}),
    "bezier_scatter": ("bezier_scatter", "czpn", {"samples": 5, "fill": "color"}),
    "bezier_scatter impl='tensor'": ("bezier_scatter", "czpn", {"samples": 5, "fill": "color", "impl": "tensor"}),
    "warp_blend iterations=1": ("warp_blend", "cv", {"iterations": 1}),
    "warp_blend iterations=2": ("warp_blend", "cv", {"iterations": 2}),
    "warp_blend iterations=3": ("warp_blend", "cv", {"iterations": 3}),
    "accumulate_warps": ("accumulate_warps", "cv", {"instants": 4}),
    "MotionBlur gather": ("MotionBlur", "cv", {"method": "gather", "samples": 5}),
    "MotionBlur reconstruct": ("MotionBlur", "cvz", {"method": "reconstruct", "samples": 5, "max_radius": 4.0}),
}


def inputs(kinds: str, shape: tuple[int, int, int, int] = SHAPE) -> list[np.ndarray]:
    """Seeded float64 inputs, one per letter of `kinds` (CASES' key), of batch and size `shape` (B, 3, H, W)."""
    rng = np.random.default_rng(0)
    b, _, h, w = shape
    made = {
        "c": lambda: rng.random(shape),
        "v": lambda: rng.normal(size=(b, 2, h, w)) * 2.0,
        "z": lambda: rng.uniform(1.0, 2.0, size=(b, 1, h, w)),
        "d": lambda: rng.uniform(0.0, 3.0, size=(b, 1, h, w)),
        "p": lambda: rng.normal(size=(b, 2, h, w)) * 2.0,
        "n": lambda: rng.normal(size=(b, 2, h, w)) * 2.0,
    }
    return [made[k]() for k in kinds]


def call(ops, name: str, kinds: str, options: dict, arrays: list, place=lambda layer: layer):
    """The op on `arrays` (as `kinds` says), with float64 options where the module needs them;
    `place` puts a module where the arrays are (PyTorch: `.to(device)`)."""
    if name == "MotionBlur":
        options = dict(options)
        method = options.pop("method")
        layer = place(ops.MotionBlur(method, **options))
        return layer(*arrays)
    if name in ("soft_depth_compare",):
        return getattr(ops, name)(arrays[0], arrays[1] * 1.1, 0.1)
    if name in ("cone", "cylinder"):
        return getattr(ops, name)(arrays[0], arrays[1] + 0.5)
    if name == "tile_max":
        return ops.tile_max(arrays[0], 4)
    if name == "neighbor_max":
        return ops.neighbor_max(ops.tile_max(arrays[0], 4))
    if name == "bezier_scatter":
        color, depth, prev, nxt = arrays
        return ops.bezier_scatter(color, depth, prev, nxt, **options)
    return getattr(ops, name)(*arrays, **options)


def labels(kinds: str) -> list[str]:
    """The inputs' names in the table: their letters, numbered where one repeats (z1, z2)."""
    return [f"{k}{kinds[:i].count(k) + 1}" if kinds.count(k) > 1 else k for i, k in enumerate(kinds)]


def weights(shape) -> np.ndarray:
    """The fixed weights of the sum whose gradient the scripts compare."""
    return np.random.default_rng(1).random(shape)
