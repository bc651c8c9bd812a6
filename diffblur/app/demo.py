"""The main job: blur a built-in scene with every method of both backends and compare with the
ground truth, in one picture and one table.

The backends are imported here, inside the functions, so `diffblur` itself stays free of them.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from diffblur import metrics
from diffblur.scenes import make_scene
from diffblur.app.timing import median_ms


@dataclass(frozen=True)
class DemoResult:
    """One method on one backend: its output (1, C, H, W), PSNR and SSIM against the target, and
    the median wall time of a forward pass in milliseconds."""

    method: str
    backend: str
    output: np.ndarray
    psnr: float
    ssim: float
    milliseconds: float


#: The demo's methods: (label, MotionBlur method, its options, the scene buffers its forward reads).
DEMO_METHODS: tuple[tuple[str, str, dict, tuple[str, ...]], ...] = (
    ("reconstruct S=15 nearest", "reconstruct", dict(samples=15, sampling="nearest"), ("velocity", "depth")),
    ("reconstruct S=15", "reconstruct", dict(samples=15), ("velocity", "depth")),
    ("gather S=15", "gather", dict(samples=15), ("velocity",)),
    ("bezier d2, 16 points", "bezier", dict(samples=16, shutter="box"), ("depth", "offset_prev", "offset_next")),
    ("warp_blend 3 iterations", "warp_blend", dict(iterations=3), ("velocity",)),
    ("accumulate 8 instants", "accumulate", dict(instants=8), ("velocity",)),
)


def _methods():
    """(label, torch function, jax function) for each of DEMO_METHODS, each taking the scene."""
    import jax
    import jax.numpy as jnp
    import torch

    import jax_impl
    import torch_impl

    def torch_call(method, options, inputs):
        layer = torch_impl.MotionBlur(method, learn_exposure=False, **options)

        def run(scene):
            with torch.no_grad():
                arrays = {name: torch.from_numpy(getattr(scene, name)) for name in inputs}
                return layer(torch.from_numpy(scene.color), **arrays).numpy()

        return run

    def jax_call(method, options, inputs):
        layer = jax_impl.MotionBlur(method, learn_exposure=False, **options)
        jitted = jax.jit(lambda color, arrays: layer(color, **arrays))

        def run(scene):
            arrays = {name: jnp.asarray(getattr(scene, name)) for name in inputs}
            return np.asarray(jax.block_until_ready(jitted(jnp.asarray(scene.color), arrays)))

        return run

    return [(label, torch_call(m, o, i), jax_call(m, o, i)) for label, m, o, i in DEMO_METHODS]


@dataclass(frozen=True)
class DemoFit:
    """The motion recovered on one backend: per motion ID the true mean velocity of its pixels and
    the fitted one (in the true one's sign: a box shutter cannot tell v from -v), the fitted field
    (1, 2, h, w) and the seconds the fit took (JAX: with compilation)."""

    backend: str
    true_palette: np.ndarray
    fitted_palette: np.ndarray
    velocity: np.ndarray
    seconds: float


#: Size of the scene's render the demo fits (smaller than the blurred one, so the demo stays short).
FIT_SIZE = 64


def fit_motion(scene_name: str, *, size: int = FIT_SIZE) -> tuple[object, list[DemoFit]]:
    """Recover a velocity per motion ID (the scene's layers, seed 001's vector motion IDs) from the
    sharp frame and the ground-truth blur, on both backends: gather with 9 taps, L-BFGS, 3 levels
    coarse to fine, the 3 px around ID changes left out of the residual (mutual occlusion)."""
    import fitting
    from fitting.scenes import layer_ids

    scene = make_scene(scene_name, height=size, width=size)
    ids = layer_ids(scene)
    true_palette = np.stack([scene.velocity[0][:, ids[0, 0] == i].mean(axis=1) for i in range(int(ids.max()) + 1)])
    fits = []
    for backend in ("torch", "jax"):
        result = fitting.recover(
            scene.color, scene.target, model=fitting.MotionIds(ids, boundary=3), depth=scene.depth, backend=backend, method="gather", samples=9, solver="lbfgs", iterations=15, levels=3
        )
        fitted = np.asarray(result.params["palette"], dtype=np.float64)
        flip = np.sum(fitted * true_palette, axis=1, keepdims=True) < 0
        fits.append(DemoFit(backend, true_palette, np.where(flip, -fitted, fitted), np.asarray(result.velocity), result.seconds))
    return scene, fits


def run_demo(out_dir: str | os.PathLike, *, scene_name: str = "translate", size: int = 160, fit: bool = True) -> tuple[str, list[DemoResult], list[DemoFit]]:
    """Render `scene_name` at size x size, blur it with every method on both backends, recover its
    motion by fitting (`fit_motion`, unless fit=False), write demo.png into out_dir and return (its
    path, the blur results, the fits)."""
    from tqdm import tqdm

    os.makedirs(out_dir, exist_ok=True)
    scene = make_scene(scene_name, height=size, width=size)
    results = []
    methods = _methods()
    with tqdm(total=2 * len(methods), desc="blurring", unit="run") as progress:
        for name, torch_run, jax_run in methods:
            for backend, run in (("torch", torch_run), ("jax", jax_run)):
                output = run(scene)
                ms = median_ms(lambda: run(scene), 3)
                results.append(
                    DemoResult(
                        name,
                        backend,
                        output,
                        metrics.psnr(output, scene.target),
                        metrics.ssim(output, scene.target),
                        ms,
                    )
                )
                progress.update()
    fit_scene, fits = fit_motion(scene_name) if fit else (None, [])
    path = os.path.join(os.fspath(out_dir), "demo.png")
    _save_picture(path, scene, results, fit_scene, fits)
    return path, results, fits


def _save_picture(path: str, scene, results: list[DemoResult], fit_scene=None, fits: list[DemoFit] = ()) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    torch_results = [r for r in results if r.backend == "torch"]
    jax_by_method = {r.method: r for r in results if r.backend == "jax"}
    columns = 2 + len(torch_results)
    rows = 3 if fits else 2
    fig = Figure(figsize=(3.2 * columns, 3.4 * rows), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, columns)
    sharp_psnr = metrics.psnr(scene.color, scene.target)
    panels_top = [
        (metrics.to_display(scene.color)[0], f"sharp input ({sharp_psnr:.1f} dB)"),
        (metrics.to_display(scene.target)[0], f"ground truth ({scene.instants} instants)"),
    ] + [(metrics.to_display(r.output)[0], f"{r.method}\n{r.psnr:.2f} dB, SSIM {r.ssim:.3f}") for r in torch_results]
    for ax, (image, title) in zip(axes[0], panels_top):
        ax.imshow(np.clip(image, 0, 1))
        ax.set_title(title, fontsize=9)
    speed = np.hypot(*scene.velocity[0])
    axes[1, 0].imshow(metrics.velocity_to_color(scene.velocity)[0].transpose(1, 2, 0))
    axes[1, 0].set_title(f"velocity (hue = direction, max {speed.max():.1f} px)", fontsize=9)
    axes[1, 1].imshow(np.abs(scene.color - scene.target).mean(axis=1)[0], cmap="magma", vmin=0, vmax=0.3)
    axes[1, 1].set_title("|sharp - truth|", fontsize=9)
    for ax, r in zip(axes[1, 2:], torch_results):
        error = np.abs(r.output - scene.target).mean(axis=1)[0]
        difference = np.abs(r.output - jax_by_method[r.method].output).max()
        ax.imshow(error, cmap="magma", vmin=0, vmax=0.3)
        ax.set_title(f"|error| (0..0.3)\nmax |torch - jax| = {difference:.1e}", fontsize=9)
    if fits:
        scale = max(float(np.hypot(*fit_scene.velocity[0]).max()), 1e-6)
        fields = [(fit_scene.velocity, f"true velocity ({fit_scene.color.shape[3]} px render)")]
        fields += [(f.velocity, f"recovered, {f.backend} ({f.seconds:.0f} s)\nworst ID error {np.abs(f.fitted_palette - f.true_palette).max():.2f} px") for f in fits]
        for ax, (field, title) in zip(axes[2], fields):
            ax.imshow(metrics.velocity_to_color(field, max_magnitude=scale)[0].transpose(1, 2, 0))
            ax.set_title(title, fontsize=9)
        text = ["motion IDs fitted (gather, L-BFGS, coarse to fine)", "", "ID   true (px)        torch            jax"]
        for i, true in enumerate(fits[0].true_palette):
            text.append(f"{i}   ({true[0]:+5.2f},{true[1]:+5.2f})  " + "  ".join(f"({f.fitted_palette[i][0]:+5.2f},{f.fitted_palette[i][1]:+5.2f})" for f in fits))
        axes[2, len(fields)].text(0, 0.5, "\n".join(text), family="monospace", fontsize=8, va="center")
    for ax in axes.flat:
        ax.axis("off")
    fig.suptitle(f"diffblur demo: scene '{scene.name}', {scene.color.shape[3]}x{scene.color.shape[2]}")
    fig.savefig(path, dpi=90)


def format_table(results: list[DemoResult], fits: list[DemoFit] = ()) -> str:
    lines = [f"{'method':<28} {'backend':<7} {'PSNR dB':>8} {'SSIM':>7} {'ms':>8}"]
    for r in results:
        lines.append(f"{r.method:<28} {r.backend:<7} {r.psnr:>8.2f} {r.ssim:>7.4f} {r.milliseconds:>8.1f}")
    if fits:
        lines += ["", f"motion recovered per motion ID ({FIT_SIZE} px render; velocities in px, up to sign):"]
        lines.append(f"{'fit':<28} {'backend':<7} {'ID':>3} {'true':>16} {'fitted':>16} {'error':>6}")
        for f in fits:
            for i, (true, found) in enumerate(zip(f.true_palette, f.fitted_palette)):
                error = np.abs(found - true).max()
                lines.append(f"{'motion_ids':<28} {f.backend:<7} {i:>3} {f'({true[0]:+.2f}, {true[1]:+.2f})':>16} {f'({found[0]:+.2f}, {found[1]:+.2f})':>16} {error:>6.2f}")
    return "\n".join(lines)
