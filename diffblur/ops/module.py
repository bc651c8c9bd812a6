"""`MotionBlur`, the layer, for both frameworks: its methods and their inputs, its options checked, and
its call (`blur`). Each backend's module holds the parameters (an `nn.Module`, an `eqx.Module`)."""

from __future__ import annotations

import dataclasses
import inspect
import numbers
from collections.abc import Callable, Mapping
from typing import Any

from diffblur import checks
from diffblur.ops.scatter import MID_PREV_TIME
from diffblur.shutters import ShutterWindow, get_shutter

#: The methods of `MotionBlur`, with the inputs each reads besides color.
METHOD_INPUTS: dict[str, tuple[str, ...]] = {
    "reconstruct": ("velocity", "depth"),
    "gather": ("velocity",),
    "bezier": ("velocity", "depth"),  # velocity, or the offsets or arc of BEZIER_PATHS
    "warp_blend": ("velocity",),
    "accumulate": ("velocity",),
}

#: Arrays a method's op takes as keyword arguments: `MotionBlur`'s forward takes them, not its options.
METHOD_ARRAY_INPUTS: dict[str, tuple[str, ...]] = {
    "bezier": ("offset_mid_prev", "arc_center", "arc_angle"),
    "accumulate": ("offset_prev", "offset_next"),
}

#: The ways to give `MotionBlur(method="bezier")` its paths, in its forward (exposure scales each).
BEZIER_PATHS = {
    "velocity": ("velocity",),
    "offsets": ("offset_prev", "offset_next", "offset_mid_prev"),
    "arc": ("arc_center", "arc_angle"),
}

__all__ = [
    "BEZIER_PATHS",
    "METHOD_ARRAY_INPUTS",
    "METHOD_INPUTS",
    "CALL_DOC",
    "DOC",
    "PATH_INPUTS",
    "bezier_path",
    "blur",
    "bezier_paths",
    "check_method_options",
    "layer_doc",
    "learnable_shutter_fields",
    "require_inputs",
    "shutter_option",
]


def check_method_options(method: str, op: Callable, options: Mapping[str, Any]) -> dict[str, Any]:
    """The op's keyword-only options, checked by name (a TypeError lists the valid ones)."""
    checks.require_choice("method", method, tuple(METHOD_INPUTS))
    valid = [p.name for p in inspect.signature(op).parameters.values() if p.kind is inspect.Parameter.KEYWORD_ONLY]
    arrays = METHOD_ARRAY_INPUTS.get(method, ())
    valid = [name for name in valid if name not in arrays]
    for name in options:
        if name in arrays:
            raise TypeError(f"MotionBlur(method={method!r}): {name} is an array input of the layer's call, not an option")
        if name not in valid:
            raise TypeError(f"MotionBlur(method={method!r}) got an unknown option {name!r}; valid options: {', '.join(valid)}")
    if not isinstance(options.get("fill", ""), str):
        raise TypeError("MotionBlur(method='bezier'): an array fill (the scene behind) is an input of the layer's call, not an option")
    return dict(options)


def learnable_shutter_fields(shutter: str | ShutterWindow) -> dict[str, float]:
    """The numeric fields of a shutter window (its shape parameters), to make learnable."""
    window = get_shutter(shutter)
    fields = {f.name: getattr(window, f.name) for f in dataclasses.fields(window)}
    numeric = {name: float(value) for name, value in fields.items() if isinstance(value, numbers.Real)}
    if not numeric:
        raise ValueError(f"learn_shutter needs a window with a shape parameter (e.g. Tukey, LinearRamp), got {window!r}")
    return numeric


def require_inputs(method: str, given: Mapping[str, object]) -> None:
    """Every input the method reads was passed."""
    for name in METHOD_INPUTS[method]:
        if method == "bezier" and name == "velocity":
            bezier_path(given)  # a velocity, or offsets, or an arc
        elif given.get(name) is None:
            raise ValueError(f"MotionBlur(method={method!r}) needs {name}; got none")


def shutter_option(op: Callable, options: Mapping[str, Any]) -> str | ShutterWindow:
    """The shutter the op will use: the `shutter` option, else the op's default."""
    if "shutter" not in inspect.signature(op).parameters:
        raise ValueError(f"{op.__name__} has no shutter, so no shutter shape to learn")
    return options.get("shutter", inspect.signature(op).parameters["shutter"].default)


def bezier_path(given: Mapping[str, object]) -> str:
    """Which way `MotionBlur(method="bezier")` was given its paths ("velocity", "offsets" or "arc", see
    BEZIER_PATHS) from its call's inputs (None = not given); the op checks the rest (pairs, degree).

    A velocity V alone means the linear path X - V ... X + V (offsets -V, +V)."""
    ways = [way for way, names in BEZIER_PATHS.items() if any(given.get(n) is not None for n in names)]
    if not ways:
        raise ValueError(
            "MotionBlur(method='bezier') needs velocity, or offset_prev and offset_next, or arc_center and arc_angle; got none"
        )
    if len(ways) > 1:
        names = [n for way in ways for n in BEZIER_PATHS[way] if given.get(n) is not None]
        raise ValueError(f"MotionBlur(method='bezier') takes one path: {' or '.join(ways)}, got {', '.join(names)}")
    return ways[0]


def bezier_paths(given: Mapping[str, Any], exposure: Any, degree: int) -> dict[str, Any]:
    """`bezier_scatter`'s path arguments from the layer's inputs, scaled by the exposure (arithmetic
    only, so either backend's arrays work): a velocity V gives the segment's offsets (-e V, +e V) (and,
    with degree 3, its point at t = -1/2); given offsets are multiplied by e (the path scaled about X,
    exact for linear motion); an arc keeps its centre and turns e times its angle."""
    way = bezier_path(given)
    if way == "velocity":
        scaled = given["velocity"] * exposure
        mid = scaled * MID_PREV_TIME if degree == 3 else None
        return {"offset_prev": -scaled, "offset_next": scaled, "offset_mid_prev": mid}
    if way == "offsets":
        return {n: None if given.get(n) is None else given[n] * exposure for n in BEZIER_PATHS["offsets"]}
    return {"offset_prev": None, "offset_next": None, "arc_center": given["arc_center"], "arc_angle": given["arc_angle"] * exposure}


DOC = """Motion blur as a layer, optionally with a learnable exposure (a scale on the velocity) and
    shutter shape.

    Args:
        method: "reconstruct" (seed 000, needs velocity and depth), "gather" (seed 001) or "bezier"
            (seed 003's curve scatter, `bezier_scatter`: needs depth and a path, see the call).
            "warp_blend" (seed 002, `warp_blend`) and "accumulate" (`accumulate_warps`, the
            accumulation baseline) read velocity only.
        exposure: initial exposure, the factor applied to the velocity (1 = as given); with "bezier",
            to the offsets (the path scaled about each pixel) or to the arc's angle.
        learn_exposure: make the exposure trainable (PyTorch: an `nn.Parameter`, else a buffer; JAX:
            an array field, trainable under `eqx.filter`, else a static float). Off by default: where
            a network predicts the velocity, a learnable exposure is a second scale on it, which the
            optimiser can trade against the network's output; turn it on to fit an exposure to a
            known motion.
        learn_shutter: make the shutter window's shape parameters (e.g. Tukey's taper) trainable
            too; the window comes from the `shutter` option.
        **options: the method's keyword options (samples, sampling, shutter, impl, ...), checked by
            name; bezier's `fill` here is "still" or "color" (an array fill goes to the call).
"""

CALL_DOC = """Blur `color` (B, C, H, W) by `velocity` (B, 2, H, W) x exposure, with `depth` (B, 1, H, W)
        where the method reads it.

        "bezier" takes one path: a velocity V (the segment from X - V to X + V), or offset_prev and
        offset_next (and offset_mid_prev with degree=3), or arc_center and arc_angle, as
        `bezier_scatter` does; and optionally the scene behind the moving objects as `fill` (an
        array; a fill of "still" or "color" is an option of the layer)."""


def layer_doc(example: str) -> str:
    """The layer's docstring followed by a backend's example (a doctest)."""
    return DOC + "\n" + example


#: The path arrays the layer's call takes besides velocity and depth (method="bezier" only).
PATH_INPUTS = ("offset_prev", "offset_next", "offset_mid_prev", "arc_center", "arc_angle")


def blur(
    be: Any, ops: Mapping[str, Callable], method: str, options: Mapping[str, Any], exposure: Any, shutter_shape: Mapping[str, Any], color: Any, velocity: Any, depth: Any, paths: Mapping[str, Any], fill: Any
) -> Any:
    """The layer's call, for a backend: `ops` maps each method to the backend's public op; exposure
    (a number or a 0-d array) scales the velocity (or the bezier path); `shutter_shape` holds the
    shutter's learnt shape parameters (empty when none); `fill`, method="bezier"'s scene behind (an
    array) or None."""
    if method != "bezier":
        for name, value in (*paths.items(), ("fill", fill)):
            if value is not None:
                raise TypeError(f"MotionBlur(method={method!r}) takes {name} only with method='bezier'")
    require_inputs(method, {"velocity": velocity, "depth": depth, **paths})
    options = dict(options)
    if shutter_shape:
        window = get_shutter(shutter_option(ops[method], options))
        options["shutter"] = dataclasses.replace(window, **{k: be.astype(v, color.dtype) for k, v in shutter_shape.items()})
    exposure = be.asarray(exposure, color.dtype, color)
    if method == "bezier":
        if fill is not None:
            options["fill"] = fill
        given = bezier_paths({"velocity": velocity, **paths}, exposure, options.get("degree", 2))
        return ops[method](color, depth, **given, **options)
    scaled = velocity * be.astype(exposure, velocity.dtype)
    if method == "reconstruct":
        return ops[method](color, scaled, depth, **options)
    return ops[method](color, scaled, **options)
