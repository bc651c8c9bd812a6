"""How an op's options are taken and shown: `OpOptions`, the base of each op's options dataclass, and
`public`, which gives a backend's function the op's docstring and its full signature."""

from __future__ import annotations

import dataclasses
import functools
import inspect
import textwrap
from collections.abc import Callable, Iterable, Mapping
from typing import Any, TypeVar

from diffblur import checks
from diffblur.conventions import IMPLS

__all__ = ["OpOptions", "impl_option", "option_names", "public", "takes_kernel"]

Options = TypeVar("Options", bound="OpOptions")


@dataclasses.dataclass(frozen=True)
class OpOptions:
    """An op's keyword options, checked in `__post_init__`; derived values are fields with
    init=False, set there with `_resolve`."""

    @classmethod
    def take(cls: type[Options], op: str, given: Mapping[str, Any]) -> Options:
        """The options from a call's keyword arguments; an unknown name raises a TypeError that names
        it and lists the valid ones (Python's own message names only the unknown one)."""
        names = option_names(cls)
        for name in given:
            if name not in names:
                raise TypeError(unknown_option_message(op, name, names))
        return cls(**given)

    def _resolve(self, name: str, value: Any) -> None:
        object.__setattr__(self, name, value)


def option_names(options: type[OpOptions]) -> list[str]:
    """The keyword options a call takes, in the dataclass's order. Read off `__dataclass_fields__`
    (what `dataclasses.fields` reads), which torch.compile can trace: it does not trace
    `dataclasses.fields` of a class."""
    return [name for name, f in options.__dataclass_fields__.items() if f.init]


def _option_parameters(options: type[OpOptions]) -> list[inspect.Parameter]:
    hints = {f.name: f.type for f in dataclasses.fields(options)}
    parameters = []
    for f in dataclasses.fields(options):
        if f.init:
            default = f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore[misc]
            parameters.append(inspect.Parameter(f.name, inspect.Parameter.KEYWORD_ONLY, default=default, annotation=hints[f.name]))
    return parameters


def public(doc: str, options: type[OpOptions] | None = None, *, example: str = "") -> Callable[[Callable], Callable]:
    """Decorate a backend's public function: its docstring becomes `doc` followed by the backend's
    `example` (a doctest). With `options`, its signature shows the function's own array parameters
    followed by every option, keyword-only with its default (the function itself takes them as
    **options and hands them to `options.take`, which names the valid ones for an unknown one).
    Without, the function is wrapped so that an unknown keyword raises a TypeError listing its
    keyword-only parameters (Python's own message names only the unknown one)."""

    def decorate(function: Callable) -> Callable:
        if options is None:
            function = _listing_keywords(function)
        text = inspect.cleandoc(doc)
        if example:
            text += "\n\n" + textwrap.dedent(example).strip("\n")
        function.__doc__ = text
        if options is not None:
            signature = inspect.signature(function)
            own = [p for p in signature.parameters.values() if p.kind is not inspect.Parameter.VAR_KEYWORD]
            function.__signature__ = signature.replace(parameters=[*own, *_option_parameters(options)])  # type: ignore[attr-defined]
        return function

    return decorate


def unknown_option_message(op: str, name: str, valid: Iterable[str]) -> str:
    """The TypeError's message for an unknown keyword `name` of `op`, listing the valid ones."""
    return f"{op}() got an unknown option {name!r}; valid options: {', '.join(valid)}"


def _listing_keywords(function: Callable) -> Callable:
    parameters = inspect.signature(function).parameters
    known = frozenset(parameters)
    keywords = [p.name for p in parameters.values() if p.kind is inspect.Parameter.KEYWORD_ONLY]

    @functools.wraps(function)
    def checked(*args: Any, **kwargs: Any) -> Any:
        for name in kwargs:
            if name not in known:
                raise TypeError(unknown_option_message(function.__name__, name, keywords))
        return function(*args, **kwargs)

    return checked


def impl_option(impl: object) -> str:
    """Check `impl` ("auto", "fused" or "tensor", `diffblur.conventions.IMPLS`)."""
    return checks.require_choice("impl", impl, IMPLS)


def takes_kernel(op: str, impl: str, reason: str | None) -> bool:
    """Whether `op` runs on its fused kernel, given `impl` and why the kernel cannot run these inputs
    (`reason`, None when it can): "auto" takes the kernel where it can, "fused" insists (ValueError
    naming the reason), "tensor" never takes it."""
    if impl == "tensor":
        return False
    if reason is not None and impl == "fused":
        raise ValueError(f"{op}(impl='fused') cannot run: {reason}; impl='auto' or 'tensor' runs the tensor ops")
    return reason is None
