"""The `diffblur fit` command: fit a motion model to a blurred image, write its parameters (JSON)
and a picture (target, re-blurred, residual, fitted velocity field).

`fit_files` is the importable body; `add_fit_parser` adds the subcommand to `diffblur`'s parser; run
alone as `python -m fitting.cli SHARP TARGET --model global`.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Any

import numpy as np

from fitting._models import MODELS

#: Every default the command uses, printed by --help.
DEFAULTS = {"model": "global", "backend": "torch", "method": "the model's default", "levels": "from the image size", "samples": 9, "out": "fit_out"}


def load_image(path: str, *, channels: int | None = None) -> np.ndarray:
    """A (1, C, H, W) float64 array from .npy (NCHW, CHW or HW, linear values) or an image file (sRGB,
    converted to linear)."""
    if path.endswith(".npy"):
        x = np.load(path).astype(np.float64)
        while x.ndim < 4:
            x = x[None]
        return x
    from diffblur.app.blur_image import read_picture
    from diffblur.scenes import srgb_to_linear

    x = srgb_to_linear(read_picture(path).transpose(2, 0, 1)[None])
    return x[:, :1] if channels == 1 else x


def save_picture(path: str, target: np.ndarray, blurred: np.ndarray, velocity: np.ndarray, title: str) -> str:
    """target, re-blurred, |residual| and the fitted velocity field (colour wheel) side by side."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from diffblur.metrics import psnr, to_display, velocity_to_color

    fig = Figure(figsize=(12, 3.4), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 4)
    residual = np.abs(blurred - target).mean(axis=1)[0]
    panels = [
        (to_display(target)[0], "target"),
        (to_display(np.clip(blurred, 0.0, None))[0], f"re-blurred (PSNR {psnr(np.clip(blurred, 0, 1), np.clip(target, 0, 1)):.1f} dB)"),
        (residual, "|residual|"),
        (velocity_to_color(velocity)[0].transpose(1, 2, 0), f"velocity (max {np.hypot(*velocity[0]).max():.2f} px)"),
    ]
    for ax, (image, label) in zip(axes, panels):
        ax.imshow(image.squeeze(), cmap="magma" if image.ndim == 2 else None)
        ax.set_title(label)
        ax.axis("off")
    fig.suptitle(title)
    fig.savefig(path, dpi=90)
    return path


def fit_files(
    sharp: str,
    target: str,
    *,
    depth: str | None = None,
    ids: str | None = None,
    velocity: tuple[float, float] | None = None,
    boundary: float | None = None,
    out: str = DEFAULTS["out"],
    progress: bool = True,
    **options: Any,
) -> dict[str, Any]:
    """Load the images, run `fitting.recover(..., **options)` with a progress bar, write
    params.json and fit.png into `out`. Returns the JSON's content."""
    from fitting._recover import recover

    sharp_image = load_image(sharp)
    target_image = load_image(target)
    from fitting import _models

    kwargs = dict(options)
    name = kwargs.pop("model", DEFAULTS["model"])
    if depth is not None:
        kwargs["depth"] = load_image(depth, channels=1)
    # The model object carries the data its name needs: a known motion, an ID map.
    model_options: dict[str, Any] = {}
    if velocity is not None:
        if name not in ("exposure", "shutter"):
            raise ValueError(f"--velocity is the known motion of models exposure and shutter, not of {name!r}")
        model_options["velocity"] = tuple(velocity)
    if ids is not None:
        if name not in ("motion_ids", "layers"):
            raise ValueError(f"--ids is the ID map of models motion_ids and layers, not of {name!r}")
        model_options["ids"] = np.load(ids).astype(np.int64).reshape(1, 1, *sharp_image.shape[2:])
    if boundary is not None:
        if name not in ("motion_ids", "layers"):
            raise ValueError(f"--boundary is an option of models motion_ids and layers, not of {name!r}")
        model_options["boundary"] = boundary
    kwargs["model"] = _models.MODEL_TYPES[name](**model_options)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(desc=f"fit {name}", unit="step", file=sys.stderr)
        kwargs["on_step"] = lambda step, loss: (bar.update(1), bar.set_postfix(loss=f"{loss:.3e}"))
    try:
        result = recover(sharp_image, target_image, **kwargs)
    finally:
        if bar is not None:
            bar.close()
    os.makedirs(out, exist_ok=True)
    summary = {
        "model": result.model,
        "backend": result.backend,
        "solver": result.solver,
        "params": result.params,
        "loss": result.loss,
        "converged": result.converged,
        "explained": result.explained,
        "method": result.method,
        "steps": len(result.history),
        "seconds": result.seconds,
    }
    with open(os.path.join(out, "params.json"), "w") as f:
        json.dump(summary, f, indent=2)
    save_picture(os.path.join(out, "fit.png"), target_image, result.blurred, result.velocity, f"{result.model} ({result.backend}, {result.solver}): loss {result.loss:.3e}")
    return summary


def add_fit_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add `fit` to a subparsers object (diffblur's CLI)."""
    parser = subparsers.add_parser(
        "fit",
        help="recover motion parameters from a sharp image and a blurred target; writes params.json and fit.png",
        description="Fit a motion model by gradient descent; defaults: " + ", ".join(f"{k}={v}" for k, v in DEFAULTS.items()),
    )
    parser.add_argument("sharp", help="sharp image: .npy (NCHW/CHW/HW, linear) or an image file (sRGB)")
    parser.add_argument("target", help="blurred image, same size")
    parser.add_argument("--depth", help="depth .npy (H, W), positive")
    parser.add_argument("--ids", help="motion ID map .npy (H, W) of integers (model motion_ids)")
    parser.add_argument("--velocity", type=float, nargs=2, metavar=("VX", "VY"), help="known half-spread velocity (models exposure, shutter)")
    parser.add_argument("--boundary", type=float, help="leave out pixels within this many px of a change of ID or layer (models motion_ids, layers; default 0)")
    parser.add_argument("--model", default=DEFAULTS["model"], choices=MODELS, help=f"default: {DEFAULTS['model']}")
    parser.add_argument("--backend", default=DEFAULTS["backend"], choices=("torch", "jax"), help=f"default: {DEFAULTS['backend']}")
    parser.add_argument("--solver", help="lbfgs (default, both backends), torch adam; jax lm, dogleg, bfgs, adam")
    parser.add_argument("--method", choices=("reconstruct", "gather", "scatter"), help=f"default: {DEFAULTS['method']}")
    parser.add_argument("--iterations", type=int, help="solver steps per level (default 200 for lbfgs, 60 for adam, else 20)")
    parser.add_argument("--levels", type=int, help=f"coarse-to-fine pyramid levels (default: {DEFAULTS['levels']})")
    parser.add_argument("--samples", type=int, default=DEFAULTS["samples"], help="taps of the blur, odd (default: 9)")
    parser.add_argument("--out", default=DEFAULTS["out"], help=f"output folder (default: {DEFAULTS['out']})")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(run=run)
    return parser


def run(args: argparse.Namespace) -> int:
    options = {k: getattr(args, k) for k in ("model", "backend", "solver", "method", "iterations", "levels", "samples") if getattr(args, k) is not None}
    summary = fit_files(args.sharp, args.target, depth=args.depth, ids=args.ids, velocity=args.velocity, boundary=args.boundary, out=args.out, progress=not args.no_progress, **options)
    print(json.dumps(summary["params"]))
    print(f"loss {summary['loss']:.4e} after {summary['steps']} steps ({summary['seconds']:.1f} s), converged: {summary['converged']}, explains {summary['explained']:.1%} of the blur; wrote {os.path.join(args.out, 'params.json')} and fit.png")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m fitting.cli")
    add_fit_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["fit", *(sys.argv[1:] if argv is None else argv)])
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
