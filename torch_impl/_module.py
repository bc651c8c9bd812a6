"""`MotionBlur`, the PyTorch layer: options stored, the functional op does the work."""

from __future__ import annotations

import torch
from jaxtyping import Float
from torch import Tensor, nn

from diffblur import checks
from diffblur.ops.module import blur, check_method_options, learnable_shutter_fields, shutter_option
from torch_impl._backend import TORCH
from torch_impl._gather import gather_blur
from torch_impl._reconstruct import reconstruct
from torch_impl._scatter import bezier_scatter
from torch_impl._warp import accumulate_warps, warp_blend

_OPS = {"reconstruct": reconstruct, "gather": gather_blur, "bezier": bezier_scatter, "warp_blend": warp_blend, "accumulate": accumulate_warps}


class MotionBlur(nn.Module):
    """Motion blur as a layer, optionally with a learnable exposure (a scale on the velocity) and
    shutter shape.

    Args:
        method: "reconstruct" (seed 000, needs velocity and depth), "gather" (seed 001) or "bezier"
            (seed 003's curve scatter, `bezier_scatter`: needs depth and a path, see `forward`).
            "warp_blend" (seed 002, `warp_blend`) and "accumulate" (`accumulate_warps`, the
            accumulation baseline) read velocity only.
        exposure: initial exposure, the factor applied to the velocity (1 = as given); with "bezier",
            to the offsets (the path scaled about each pixel) or to the arc's angle.
        learn_exposure: make the exposure an `nn.Parameter` (else a buffer, the default). Off by
            default: where a network predicts the velocity, a learnable exposure is a second scale on
            it, which the optimiser can trade against the network's output; turn it on to fit an
            exposure to a known motion.
        learn_shutter: make the shutter window's shape parameters (e.g. Tukey's taper)
            parameters too; the window comes from the `shutter` option.
        **options: the method's keyword options (samples, sampling, shutter, ...), checked by name.

    >>> import torch
    >>> layer = MotionBlur("gather", samples=5)
    >>> color, velocity = torch.rand(2, 3, 16, 16), torch.randn(2, 2, 16, 16)
    >>> layer(color, velocity).shape
    torch.Size([2, 3, 16, 16])
    """

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
        self,
        color: Float[Tensor, "b c h w"],
        velocity: Float[Tensor, "b 2 h w"] | None = None,
        depth: Float[Tensor, "b 1 h w"] | None = None,
        *,
        offset_prev: Float[Tensor, "b 2 h w"] | None = None,
        offset_next: Float[Tensor, "b 2 h w"] | None = None,
        offset_mid_prev: Float[Tensor, "b 2 h w"] | None = None,
        arc_center: Float[Tensor, "b 2 h w"] | None = None,
        arc_angle: Float[Tensor, "b 1 h w"] | None = None,
        fill: Float[Tensor, "b c h w"] | None = None,
    ) -> Float[Tensor, "b c h w"]:
        """Blur `color` (B, C, H, W) by `velocity` (B, 2, H, W) x exposure, with `depth` (B, 1, H, W)
        where the method reads it.

        "bezier" takes one path: a velocity V (the segment from X - V to X + V), or offset_prev and
        offset_next (and offset_mid_prev with degree=3), or arc_center and arc_angle, as
        `bezier_scatter` does; and optionally the scene behind the moving objects as `fill` (an array;
        a fill of "still" or "color" is an option of the layer)."""
        paths = {"offset_prev": offset_prev, "offset_next": offset_next, "offset_mid_prev": offset_mid_prev, "arc_center": arc_center, "arc_angle": arc_angle}
        return blur(TORCH, _OPS, self.method, self.options, self.exposure, dict(self.shutter_shape), color, velocity, depth, paths, fill)

    def extra_repr(self) -> str:
        return f"method={self.method!r}, options={self.options}"
