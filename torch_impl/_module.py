"""`MotionBlur`, the PyTorch layer: options stored, the functional op does the work."""

from __future__ import annotations

import torch
from jaxtyping import Float
from torch import Tensor, nn

from diffblur import checks
from diffblur.ops.module import CALL_DOC, blur, check_method_options, layer_doc, learnable_shutter_fields, shutter_option
from torch_impl._backend import TORCH
from torch_impl._gather import gather_blur
from torch_impl._reconstruct import reconstruct
from torch_impl._scatter import bezier_scatter
from torch_impl._warp import accumulate_warps, warp_blend

_OPS = {"reconstruct": reconstruct, "gather": gather_blur, "bezier": bezier_scatter, "warp_blend": warp_blend, "accumulate": accumulate_warps}


class MotionBlur(nn.Module):
    __doc__ = layer_doc("""
    >>> import torch
    >>> layer = MotionBlur("gather", samples=5)
    >>> color, velocity = torch.rand(2, 3, 16, 16), torch.randn(2, 2, 16, 16)
    >>> layer(color, velocity).shape
    torch.Size([2, 3, 16, 16])
""")

    def __init__(self, method: str = "reconstruct", *, exposure: float = 1.0, learn_exposure: bool = False, learn_shutter: bool = False, **options):
        super().__init__()
        self.method = method
        op = _OPS.get(method, reconstruct)
        self.options = check_method_options(method, op, options)
        exposure = torch.tensor(float(checks.require_positive_number("exposure", exposure)))
        if learn_exposure:
            self.exposure = nn.Parameter(exposure)
        else:
            self.register_buffer("exposure", exposure)
        self.shutter_shape = nn.ParameterDict()
        if learn_shutter:
            for name, value in learnable_shutter_fields(shutter_option(op, self.options)).items():
                self.shutter_shape[name] = nn.Parameter(torch.tensor(value))

    def forward(
        self, color: Float[Tensor, "b c h w"], velocity: Float[Tensor, "b 2 h w"] | None = None, depth: Float[Tensor, "b 1 h w"] | None = None, *,
        offset_prev: Float[Tensor, "b 2 h w"] | None = None, offset_next: Float[Tensor, "b 2 h w"] | None = None, offset_mid_prev: Float[Tensor, "b 2 h w"] | None = None,
        arc_center: Float[Tensor, "b 2 h w"] | None = None, arc_angle: Float[Tensor, "b 1 h w"] | None = None, fill: Float[Tensor, "b c h w"] | None = None,
    ) -> Float[Tensor, "b c h w"]:
        paths = {"offset_prev": offset_prev, "offset_next": offset_next, "offset_mid_prev": offset_mid_prev, "arc_center": arc_center, "arc_angle": arc_angle}
        return blur(TORCH, _OPS, self.method, self.options, self.exposure, dict(self.shutter_shape), color, velocity, depth, paths, fill)

    forward.__doc__ = CALL_DOC

    def extra_repr(self) -> str:
        return f"method={self.method!r}, options={self.options}"
