"""What the two `MotionBlur` modules share: the methods, their inputs, and option checking."""

from __future__ import annotations

import dataclasses
import inspect
import numbers
from collections.abc import Callable, Mapping
from typing import Any

from diffblur import checks
from diffblur.shutters import ShutterWindow, get_shutter

#: The methods of `MotionBlur`, with the inputs each reads besides color.
METHOD_INPUTS: dict[str, tuple[str, ...]] = {
    "reconstruct": ("velocity", "depth"),
    "gather": ("velocity",),
}

__all__ = ["METHOD_INPUTS", "check_method_options", "learnable_shutter_fields", "require_inputs"]


def check_method_options(method: str, op: Callable, options: Mapping[str, Any]) -> dict[str, Any]:
    """The op's keyword-only options, checked by name (a TypeError lists the valid ones)."""
    checks.require_choice("method", method, tuple(METHOD_INPUTS))
    valid = [p.name for p in inspect.signature(op).parameters.values() if p.kind is inspect.Parameter.KEYWORD_ONLY]
    for name in options:
        if name not in valid:
            raise TypeError(f"MotionBlur(method={method!r}) got an unknown option {name!r}; valid options: {', '.join(valid)}")
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
        if given.get(name) is None:
            raise ValueError(f"MotionBlur(method={method!r}) needs {name}; got none")
