"""The preset gallery: one PNG with, per preset, the sharp frame, the target, the velocity and depth."""

from __future__ import annotations

import os
import time

import numpy as np

from diffblur.scenes._presets import PRESETS
from diffblur.metrics import color_wheel, to_display, velocity_to_color

__all__ = ["save_gallery"]


def save_gallery(out_dir: str | os.PathLike, *, height: int, width: int) -> str:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from diffblur.scenes import make_scene

    os.makedirs(out_dir, exist_ok=True)
    rows = len(PRESETS)
    fig = Figure(figsize=(12.5, 2.9 * rows), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, 5, squeeze=False, width_ratios=[1, 1, 1, 1, 0.45])
    for row, name in enumerate(PRESETS):
        start = time.perf_counter()
        scene = make_scene(name, height=height, width=width)
        seconds = time.perf_counter() - start
        speed = np.hypot(scene.velocity[:, 0], scene.velocity[:, 1])
        top = max(float(speed.max()), 1e-9)
        panels = [
            (to_display(scene.color)[0], f"{name}: sharp (t = 0)", {}),
            (to_display(scene.target)[0], f"target, {scene.instants} instants, {seconds:.2f} s", {}),
            (
                velocity_to_color(scene.velocity, max_magnitude=top)[0].transpose(1, 2, 0),
                f"velocity, max {top:.1f} px",
                {},
            ),
            (scene.depth[0, 0], f"depth {scene.depth.min():.3g} .. {scene.depth.max():.3g}", {"cmap": "viridis_r"}),
        ]
        for col, (image, title, kw) in enumerate(panels):
            ax = axes[row, col]
            shown = ax.imshow(image, interpolation="nearest", **kw)
            ax.set_title(title, fontsize=9)
            ax.axis("off")
            if col == 3:
                fig.colorbar(shown, ax=ax, fraction=0.046)
        legend = axes[row, 4]
        legend.imshow(color_wheel(65)[0].transpose(1, 2, 0))
        legend.set_title(f"wheel: radius {top:.1f} px\nred = +x, y down", fontsize=8)
        legend.axis("off")
    path = os.path.join(os.fspath(out_dir), "preset_gallery.png")
    fig.savefig(path, dpi=90)
    return path
