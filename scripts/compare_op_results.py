"""Every public op's outputs and gradients on a few presets, saved, and two such runs compared: run it
on the code before a change and after it, then compare.

    PYTHONPATH=. python scripts/compare_op_results.py save before.npz     # on the old code
    PYTHONPATH=. python scripts/compare_op_results.py save after.npz      # on the new code
    python scripts/compare_op_results.py compare before.npz after.npz

Each case runs an op with a set of options in PyTorch and in JAX, float32 and float64, and keeps the
output and the gradients of <output, cotangent> w.r.t. every floating input (a fixed random
cotangent). Cases on the fused CPU kernels (impl="fused") must be bit-identical; the tensor ops
(impl="tensor" and the ops without a kernel) must agree to float rounding: |a - b| <= tolerance x
max(1, max |a|), the tolerance 1e-12 for float64 and 2e-5 for float32. Run both sides with numba's
kernel cache in the same state (both compiling fresh, or both loading it): the fused reconstruct's
float64 bits differ by an ulp between a freshly compiled kernel and one loaded from the cache.

Only public names are used, written in the current API; `_old_api` translates them for code from
before the options became one choice each (`fused=` for `impl=`, `pyramid=True` for
`sampling="pyramid"`, `background=` for an array `fill=`), so the script runs on either side.
"""

from __future__ import annotations

import argparse
import inspect
import sys

import numpy as np

PRESETS = ("translate", "crossing", "propeller", "zoom")
HEIGHT, WIDTH = 40, 150  # wider than the kernels' block of 128 pixels
TOLERANCE = {"float64": 1e-12, "float32": 2e-5}

RECONSTRUCT = ("color", "velocity", "depth")
GATHER = ("color", "velocity")
SCATTER = ("color", "depth", "offset_prev", "offset_next")


def _cases():
    """(name, op, options, positional inputs, keyword inputs) for every op and option set compared.
    Keyword inputs name scene arrays passed as options (e.g. the background as `fill`)."""
    return [
        ("reconstruct", "reconstruct", {"impl": "fused"}, RECONSTRUCT, {}),
        ("reconstruct_adaptive", "reconstruct", {"impl": "fused", "adaptive": True}, RECONSTRUCT, {}),
        ("reconstruct_own", "reconstruct", {"impl": "fused", "directions": "neighbor_and_own", "samples": 9}, RECONSTRUCT, {}),
        ("reconstruct_tensor", "reconstruct", {"impl": "tensor", "samples": 7}, RECONSTRUCT, {}),
        ("reconstruct_tensor_tent", "reconstruct", {"impl": "tensor", "samples": 5, "shutter": "tent", "jitter": "none"}, RECONSTRUCT, {}),
        ("reconstruct_tensor_adaptive", "reconstruct", {"impl": "tensor", "adaptive": True, "samples": 7}, RECONSTRUCT, {}),
        ("reconstruct_tensor_own", "reconstruct", {"impl": "tensor", "directions": "neighbor_and_own", "samples": 5, "soft_z_extent": 0.2}, RECONSTRUCT, {}),
        ("reconstruct_nearest", "reconstruct", {"sampling": "nearest", "samples": 5}, RECONSTRUCT, {}),
        ("reconstruct_pyramid", "reconstruct", {"sampling": "pyramid", "samples": 5, "max_radius": 8.0}, RECONSTRUCT, {}),
        ("gather", "gather_blur", {"impl": "fused"}, GATHER, {}),
        ("gather_adaptive_tent", "gather_blur", {"impl": "fused", "adaptive": True, "shutter": "tent"}, GATHER, {}),
        ("gather_tensor", "gather_blur", {"impl": "tensor", "samples": 7, "shutter": "raised_cosine"}, GATHER, {}),
        ("gather_tensor_adaptive", "gather_blur", {"impl": "tensor", "adaptive": True}, GATHER, {}),
        ("gather_nearest", "gather_blur", {"sampling": "nearest", "samples": 5}, GATHER, {}),
        ("gather_pyramid", "gather_blur", {"sampling": "pyramid", "samples": 5}, GATHER, {}),
        ("scatter", "bezier_scatter", {"impl": "fused"}, SCATTER, {}),
        ("scatter_linear", "bezier_scatter", {"impl": "fused", "degree": 1, "samples": 12}, SCATTER, {}),
        ("scatter_tensor", "bezier_scatter", {"impl": "tensor", "samples": 9}, SCATTER, {}),
        ("scatter_tensor_sum_color", "bezier_scatter", {"impl": "tensor", "samples": 9, "composite": "sum", "fill": "color"}, SCATTER, {}),
        ("scatter_tensor_paper", "bezier_scatter", {"impl": "tensor", "samples": 9, "normalization": "paper", "soft_z_extent": 0.5}, SCATTER, {}),
        ("scatter_background", "bezier_scatter", {"samples": 9}, SCATTER, {"fill": "background"}),
        ("scatter_cubic", "bezier_scatter", {"degree": 3, "samples": 9}, SCATTER, {"offset_mid_prev": "offset_mid_prev"}),
        ("warp_blend", "warp_blend", {"iterations": 2, "alpha": (0.5, 0.8)}, GATHER, {}),
        ("accumulate", "accumulate_warps", {"instants": 6, "shutter": "trapezoid"}, GATHER, {}),
        ("accumulate_curved", "accumulate_warps", {"instants": 5, "sampling": "nearest"}, ("color", None), {"offset_prev": "offset_prev", "offset_next": "offset_next"}),
        ("velocity_from_motion", "velocity_from_motion", {"exposure": 0.7, "max_radius": 6.0}, ("velocity",), {}),
        ("tile_max", "tile_max", {}, ("velocity", 8), {}),
        ("soft_depth_compare", "soft_depth_compare", {}, ("depth", "depth_shifted", 0.3), {}),
        ("cone", "cone", {}, ("speed", "speed_shifted"), {}),
        ("cylinder", "cylinder", {}, ("speed", "speed_shifted"), {}),
        ("safe_length", "safe_length", {}, ("velocity",), {}),
    ]


def _inputs(preset: str, dtype: str) -> dict[str, np.ndarray]:
    from diffblur.scenes import make_scene

    scene = make_scene(preset, height=HEIGHT, width=WIDTH)
    names = ("color", "velocity", "depth", "offset_prev", "offset_next")
    arrays = {name: np.ascontiguousarray(getattr(scene, name), dtype=dtype) for name in names}
    background = scene.background if scene.background is not None else 0.5 * scene.color
    arrays["background"] = np.ascontiguousarray(background, dtype=dtype)
    arrays["offset_mid_prev"] = (0.5 * arrays["offset_prev"] + 0.05).astype(dtype)
    speed = np.sqrt((arrays["velocity"] ** 2).sum(1, keepdims=True))
    arrays["speed"] = speed.astype(dtype)
    arrays["speed_shifted"] = (np.roll(speed, 3, axis=3) + 0.25).astype(dtype)
    arrays["depth_shifted"] = np.roll(arrays["depth"], 5, axis=3)
    return arrays


def _old_api(function, options: dict) -> dict:
    """The options for an op from before impl= (fused=), sampling="pyramid" (pyramid=True) and an
    array fill (background=); unchanged for current code."""
    parameters = inspect.signature(function).parameters
    if "impl" in parameters or "fused" not in parameters and "pyramid" not in parameters and "background" not in parameters:
        return options
    options = dict(options)
    if "impl" in options:
        options["fused"] = {"auto": None, "fused": True, "tensor": False}[options.pop("impl")]
    if options.get("sampling") == "pyramid":
        options["sampling"], options["pyramid"] = "bilinear", True
    if "fill" in options and not isinstance(options["fill"], str):
        options["background"] = options.pop("fill")
    return options


def _arguments(arrays: dict, positional: tuple, keyword: dict, to_array) -> tuple[list, dict, list]:
    """The op's positional and keyword arguments, and the names of the differentiated inputs."""
    args, kwargs, differentiated = [], {}, []
    for item in positional:
        if isinstance(item, str):
            args.append(to_array(arrays[item]))
            differentiated.append(item)
        else:
            args.append(item)
    for option, name in keyword.items():
        kwargs[option] = to_array(arrays[name])
        differentiated.append(name)
    return args, kwargs, differentiated


def _torch_run(op: str, options: dict, arrays: dict, positional: tuple, keyword: dict, cotangent: np.ndarray) -> dict:
    import torch

    import torch_impl

    function = getattr(torch_impl, op)
    args, kwargs, names = _arguments(arrays, positional, keyword, lambda a: torch.tensor(a, requires_grad=True))
    tensors = [a for a in args if isinstance(a, torch.Tensor)] + list(kwargs.values())
    out = function(*args, **_old_api(function, {**options, **kwargs}))
    grads = torch.autograd.grad(out, tensors, torch.tensor(cotangent), allow_unused=True)
    return {"out": out.detach().numpy(), **{f"grad_{n}": (np.zeros(1) if g is None else g.numpy()) for n, g in zip(names, grads)}}


def _jax_run(op: str, options: dict, arrays: dict, positional: tuple, keyword: dict, cotangent: np.ndarray) -> dict:
    import jax
    import jax.numpy as jnp

    import jax_impl

    function = getattr(jax_impl, op)
    args, kwargs, names = _arguments(arrays, positional, keyword, jnp.asarray)
    slots = [i for i, a in enumerate(args) if isinstance(a, jax.Array)]

    def run(*differentiated):
        full = list(args)
        for i, value in zip(slots, differentiated[: len(slots)]):
            full[i] = value
        given = dict(zip(kwargs, differentiated[len(slots) :]))
        return function(*full, **_old_api(function, {**options, **given}))

    out, vjp = jax.vjp(run, *(args[i] for i in slots), *kwargs.values())
    grads = vjp(jnp.asarray(cotangent, dtype=out.dtype))
    return {"out": np.asarray(out), **{f"grad_{n}": np.asarray(g) for n, g in zip(names, grads)}}


def _cotangent(op: str, arrays: dict, dtype: str) -> np.ndarray:
    rng = np.random.default_rng(0)
    shape = {"tile_max": (1, 2, -(-HEIGHT // 8), -(-WIDTH // 8)), "velocity_from_motion": (1, 2, HEIGHT, WIDTH)}.get(op)
    if op in ("soft_depth_compare", "cone", "cylinder", "safe_length"):
        shape = (1, 1, HEIGHT, WIDTH)
    return rng.normal(size=shape or arrays["color"].shape).astype(dtype)


def save(path: str) -> None:
    import warnings

    import jax

    jax.config.update("jax_enable_x64", True)
    warnings.simplefilter("ignore", UserWarning)  # fill="still" on scenes with no still pixel
    results = {}
    for preset in PRESETS:
        for dtype in ("float32", "float64"):
            arrays = _inputs(preset, dtype)
            for name, op, options, positional, keyword in _cases():
                cotangent = _cotangent(op, arrays, dtype)
                for backend, run in (("torch", _torch_run), ("jax", _jax_run)):
                    for label, value in run(op, options, arrays, positional, keyword, cotangent).items():
                        results[f"{preset}/{dtype}/{name}/{backend}/{label}"] = value
            print(f"{preset} {dtype}", flush=True)
    np.savez(path, **results)
    print(f"{len(results)} arrays in {path}")


def _fused(key: str) -> bool:
    name = key.split("/")[2]
    return dict((case[0], case[2].get("impl") == "fused") for case in _cases())[name]


def compare(before: str, after: str) -> int:
    old, new = np.load(before), np.load(after)
    failures, identical, within = [], 0, 0
    if set(old.files) != set(new.files):
        failures.append(f"keys differ: {sorted(set(old.files) ^ set(new.files))}")
    worst = {}
    for key in sorted(set(old.files) & set(new.files)):
        a, b = old[key], new[key]
        if a.shape != b.shape or a.dtype != b.dtype:
            failures.append(f"{key}: {a.dtype}{a.shape} against {b.dtype}{b.shape}")
            continue
        if np.array_equal(a.view(np.uint8), b.view(np.uint8)):
            identical += 1
            continue
        gap = float(np.nanmax(np.abs(a.astype(np.float64) - b.astype(np.float64)))) if a.size else 0.0
        same_nans = np.array_equal(np.isnan(a), np.isnan(b))
        scale = max(1.0, float(np.nanmax(np.abs(a)))) if a.size else 1.0
        case = key.split("/", 2)[2]
        worst[case] = max(worst.get(case, 0.0), gap / scale)
        if _fused(key):
            failures.append(f"{key}: fused path not bit-identical, max |difference| {gap:.3g}")
        elif not same_nans or gap > TOLERANCE[str(a.dtype)] * scale:
            failures.append(f"{key}: max |difference| {gap:.3g} (scale {scale:.3g}), NaNs in the same places: {same_nans}")
        else:
            within += 1
    for line in failures:
        print(line)
    for case, gap in sorted(worst.items(), key=lambda item: -item[1])[:12]:
        print(f"largest relative difference {gap:.3g}: {case}")
    total = len(set(old.files) & set(new.files))
    print(f"{total} arrays compared: {identical} bit-identical, {within} within float rounding, {len(failures)} failures")
    return 1 if failures else 0


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
