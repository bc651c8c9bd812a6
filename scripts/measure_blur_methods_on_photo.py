"""How close each `diffblur blur` method, with the command's defaults, comes to the exact box blur of
a photograph by one velocity (the CLI's `--velocity VX VY` without a depth): the measurement behind
the command's default method.

    PYTHONPATH=. python scripts/measure_blur_methods_on_photo.py [--size 120] [--backend torch]

The reference integrates the bilinear image along the path, X + t V for t in [-1, 1] under the box
shutter, with 1001 instants (`accumulate_warps`; with 2001, the gather, reconstruct and warp_blend PSNRs at (10, 3) and
(-7, 18) moved by less than 0.01 dB). Every
method reads the image with the same bilinear sampling and border clamp, so the difference is the
method's own error. PSNR in dB over the linear image (peak 1), the astronaut photograph at 120x160.
Depth is 1 everywhere, as the command gives it when none is passed.
"""

from __future__ import annotations

import argparse

import numpy as np

from diffblur.scenes._textures import photo
from diffblur.app.blur_image import BlurInputs, blur_image
from diffblur.metrics import psnr
from diffblur.ops.module import METHOD_INPUTS

VELOCITIES = ((4.0, 0.0), (10.0, 3.0), (-7.0, 18.0))
REFERENCE_INSTANTS = 1001


def measure(size: int = 120, backend: str = "torch", velocities=VELOCITIES) -> dict[tuple[float, float], dict[str, float]]:
    """{velocity: {method: PSNR of the method's default blur against the exact box blur}}."""
    color = photo("astronaut", size, size * 4 // 3).transpose(2, 0, 1)[None].astype(np.float32)
    height, width = color.shape[2:]
    table = {}
    for v in velocities:
        field = np.broadcast_to(np.asarray(v, np.float32)[None, :, None, None], (1, 2, height, width)).copy()
        inputs = BlurInputs(color, field, np.ones((1, 1, height, width), np.float32))
        exact = blur_image(inputs, method="accumulate", backend=backend, instants=REFERENCE_INSTANTS)
        table[v] = {m: psnr(blur_image(inputs, method=m, backend=backend), exact) for m in METHOD_INPUTS}
    return table


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=120, help="image height (width 4/3 of it)")
    parser.add_argument("--backend", default="torch", choices=("torch", "jax"))
    args = parser.parse_args()
    table = measure(args.size, args.backend)
    methods = list(METHOD_INPUTS)
    print("| velocity (px) | " + " | ".join(methods) + " |")
    print("|---|" + "---:|" * len(methods))
    for v, row in table.items():
        print(f"| ({v[0]:g}, {v[1]:g}) | " + " | ".join(f"{row[m]:.1f}" for m in methods) + " |")


if __name__ == "__main__":
    main()
