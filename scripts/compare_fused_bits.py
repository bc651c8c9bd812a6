"""The fused CPU paths' outputs and gradients on a few presets, saved, and two such runs compared bit
for bit: run it on the code before a change and after it, then compare.

    PYTHONPATH=. python scripts/compare_fused_bits.py save before.npz     # on the old code
    PYTHONPATH=. python scripts/compare_fused_bits.py save after.npz      # on the new code
    python scripts/compare_fused_bits.py compare before.npz after.npz

Each case runs `reconstruct`, `gather_blur` and `bezier_scatter` with impl="fused" in PyTorch and in
JAX, float32 and float64, and keeps the output and the gradients of <output, cotangent> w.r.t. every
floating input (a fixed random cotangent). Only public names are used, so the script runs on either
side of a reorganisation. `compare` passes when every array is identical (NaNs in the same places).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

PRESETS = ("translate", "crossing", "propeller", "zoom")
HEIGHT, WIDTH = 40, 150  # wider than the kernels' block of 128 pixels


def _cases():
    """(name, op name, options, inputs' names) for every op and option set compared."""
    return [
        ("reconstruct", "reconstruct", {}, ("color", "velocity", "depth")),
        ("reconstruct_adaptive", "reconstruct", {"adaptive": True}, ("color", "velocity", "depth")),
        ("reconstruct_own", "reconstruct", {"directions": "neighbor_and_own", "samples": 9}, ("color", "velocity", "depth")),
        ("gather", "gather_blur", {}, ("color", "velocity")),
        ("gather_adaptive_tent", "gather_blur", {"adaptive": True, "shutter": "tent"}, ("color", "velocity")),
        ("scatter", "bezier_scatter", {}, ("color", "depth", "offset_prev", "offset_next")),
        ("scatter_linear", "bezier_scatter", {"degree": 1, "samples": 12}, ("color", "depth", "offset_prev", "offset_next")),
    ]


def _inputs(preset: str, dtype: str) -> dict[str, np.ndarray]:
    from diffblur.scenes import make_scene

    scene = make_scene(preset, height=HEIGHT, width=WIDTH)
    names = ("color", "velocity", "depth", "offset_prev", "offset_next")
    return {name: np.ascontiguousarray(getattr(scene, name), dtype=dtype) for name in names}


def _torch_run(op: str, options: dict, arrays: dict, inputs: tuple, cotangent: np.ndarray) -> list[np.ndarray]:
    import torch

    import torch_impl

    tensors = {name: torch.tensor(arrays[name], requires_grad=name in inputs) for name in arrays}
    args = [tensors[name] for name in inputs]
    out = getattr(torch_impl, op)(*args, impl="fused", **options)
    grads = torch.autograd.grad(out, args, torch.tensor(cotangent))
    return [out.detach().numpy(), *(g.numpy() for g in grads)]


def _jax_run(op: str, options: dict, arrays: dict, inputs: tuple, cotangent: np.ndarray) -> list[np.ndarray]:
    import jax
    import jax.numpy as jnp

    import jax_impl

    function = getattr(jax_impl, op)
    out, vjp = jax.vjp(lambda *a: function(*a, impl="fused", **options), *(jnp.asarray(arrays[name]) for name in inputs))
    return [np.asarray(out), *(np.asarray(g) for g in vjp(jnp.asarray(cotangent)))]


def save(path: str) -> None:
    import jax

    jax.config.update("jax_enable_x64", True)
    results = {}
    for preset in PRESETS:
        for dtype in ("float32", "float64"):
            arrays = _inputs(preset, dtype)
            cotangent = np.random.default_rng(0).normal(size=arrays["color"].shape).astype(dtype)
            for name, op, options, inputs in _cases():
                for backend, run in (("torch", _torch_run), ("jax", _jax_run)):
                    values = run(op, options, arrays, inputs, cotangent)
                    for label, value in zip(("out", *(f"grad_{i}" for i in inputs)), values):
                        results[f"{preset}/{dtype}/{name}/{backend}/{label}"] = value
                print(f"{preset} {dtype} {name}", flush=True)
    np.savez(path, **results)
    print(f"{len(results)} arrays in {path}")


def compare(before: str, after: str) -> int:
    old, new = np.load(before), np.load(after)
    differ = []
    if set(old.files) != set(new.files):
        differ.append(f"keys differ: {sorted(set(old.files) ^ set(new.files))}")
    for key in sorted(set(old.files) & set(new.files)):
        a, b = old[key], new[key]
        same = a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a.view(np.uint8), b.view(np.uint8))
        if not same:
            gap = np.nanmax(np.abs(a.astype(np.float64) - b.astype(np.float64))) if a.shape == b.shape else "shape"
            differ.append(f"{key}: max |difference| {gap}")
    for line in differ:
        print(line)
    print(f"{len(old.files)} arrays compared: " + ("bit-identical" if not differ else f"{len(differ)} differ"))
    return 1 if differ else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    commands.add_parser("save").add_argument("path")
    compared = commands.add_parser("compare")
    compared.add_argument("before")
    compared.add_argument("after")
    args = parser.parse_args(argv)
    if args.command == "save":
        save(args.path)
        return 0
    return compare(args.before, args.after)


if __name__ == "__main__":
    sys.exit(main())
