"""`MotionBlur`, the PyTorch layer: options stored, the functional op does the work."""

from __future__ import annotations

import dataclasses

import torch
from jaxtyping import Float
from torch import Tensor, nn

from diffblur import checks
from diffblur.modules import check_method_options, learnable_shutter_fields, require_inputs
from diffblur.shutters import get_shutter
from torch_impl._gather import gather_blur
from torch_impl._reconstruct import reconstruct

_OPS = {"reconstruct": reconstruct, "gather": gather_blur}


class MotionBlur(nn.Module):
    """Motion blur as a layer, with a learnable exposure (a scale on the velocity).

    Args:
        method: "reconstruct" (seed 000, needs velocity and depth) or "gather" (seed 001).
        exposure: initial exposure, the factor applied to the velocity (1 = as given).
        learn_exposure: make the exposure an `nn.Parameter` (else a buffer).
        learn_shutter: make the shutter window's shape parameters (e.g. Tukey's taper)
            parameters too; the window comes from the `shutter` option.
        **options: the method's keyword options (samples, sampling, shutter, ...), checked by name.

    >>> import torch
    >>> layer = MotionBlur("gather", samples=5)
    >>> color, velocity = torch.rand(2, 3, 16, 16), torch.randn(2, 2, 16, 16)
    >>> layer(color, velocity).shape
    torch.Size([2, 3, 16, 16])
    """

    def __init__(self, method: str = "reconstruct", *, exposure: float = 1.0, learn_exposure: bool = True, learn_shutter: bool = False, **options):
        super().__init__()
        self.method = method
        self.options = check_method_options(method, _OPS.get(method, reconstruct), options)
        exposure = torch.tensor(float(checks.require_positive_number("exposure", exposure)))
        if learn_exposure:
            self.exposure = nn.Parameter(exposure)
        else:
            self.register_buffer("exposure", exposure)
        self.shutter_shape = nn.ParameterDict()
        if learn_shutter:
            for name, value in learnable_shutter_fields(self.options.get("shutter", "box")).items():
                self.shutter_shape[name] = nn.Parameter(torch.tensor(value))

    def forward(
        self,
        color: Float[Tensor, "b c h w"],
        velocity: Float[Tensor, "b 2 h w"] | None = None,
        depth: Float[Tensor, "b 1 h w"] | None = None,
    ) -> Float[Tensor, "b c h w"]:
        """Blur `color` (B, C, H, W) by `velocity` (B, 2, H, W) x exposure, with `depth` (B, 1, H, W)
        where the method reads it."""
        require_inputs(self.method, {"velocity": velocity, "depth": depth})
        options = dict(self.options)
        if len(self.shutter_shape):
            window = get_shutter(options.get("shutter", "box"))
            options["shutter"] = dataclasses.replace(window, **{k: v.to(color.dtype) for k, v in self.shutter_shape.items()})
        scaled = velocity * self.exposure.to(velocity.dtype)
        if self.method == "reconstruct":
            return reconstruct(color, scaled, depth, **options)
        return gather_blur(color, scaled, **options)

    def extra_repr(self) -> str:
        return f"method={self.method!r}, options={self.options}"
