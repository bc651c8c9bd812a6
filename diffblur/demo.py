"""The main job: blur a built-in scene with every method of both backends and compare with the
ground truth, in one picture and one table.

The backends are imported here, inside the functions, so `diffblur` itself stays free of them.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass

import numpy as np

from diffblur import metrics
from diffblur.scenes import make_scene


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


def _median_ms(fn, repeats: int = 3) -> float:
    fn()  # warm-up (JAX traces on the first call)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


def _methods():
    """(name, torch function, jax function) for each method, each taking NumPy scene buffers."""
    import jax
    import jax.numpy as jnp
    import torch

    import jax_impl
    import torch_impl

    def torch_call(op, with_depth, **options):
        def run(scene):
            inputs = [torch.from_numpy(scene.color), torch.from_numpy(scene.velocity)]
            if with_depth:
                inputs.append(torch.from_numpy(scene.depth))
            with torch.no_grad():
                return op(*inputs, **options).numpy()

        return run

    def jax_call(op, with_depth, **options):
        jitted = jax.jit(lambda *inputs: op(*inputs, **options))

        def run(scene):
            inputs = [jnp.asarray(scene.color), jnp.asarray(scene.velocity)]
            if with_depth:
                inputs.append(jnp.asarray(scene.depth))
            return np.asarray(jax.block_until_ready(jitted(*inputs)))

        return run

    methods = [
        ("gather, S=15", torch_impl.gather_blur, jax_impl.gather_blur, False, dict(samples=15)),
        ("reconstruct, S=15, nearest", torch_impl.reconstruct, jax_impl.reconstruct, True, dict(samples=15, sampling="nearest")),
        ("reconstruct, S=15, bilinear", torch_impl.reconstruct, jax_impl.reconstruct, True, dict(samples=15)),
    ]
    return [(name, torch_call(t, depth, **o), jax_call(j, depth, **o)) for name, t, j, depth, o in methods]


def run_demo(out_dir: str | os.PathLike, *, scene_name: str = "crossing", size: int = 160) -> tuple[str, list[DemoResult]]:
    """Render `scene_name` at size x size, blur it with every method on both backends, write
    demo.png into out_dir and return (its path, the results)."""
    from tqdm import tqdm

    os.makedirs(out_dir, exist_ok=True)
    scene = make_scene(scene_name, height=size, width=size)
    results = []
    methods = _methods()
    with tqdm(total=2 * len(methods), desc="blurring", unit="run") as progress:
        for name, torch_run, jax_run in methods:
            for backend, run in (("torch", torch_run), ("jax", jax_run)):
                output = run(scene)
                ms = _median_ms(lambda: run(scene))
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
    path = os.path.join(os.fspath(out_dir), "demo.png")
    _save_picture(path, scene, results)
    return path, results


def _save_picture(path: str, scene, results: list[DemoResult]) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    torch_results = [r for r in results if r.backend == "torch"]
    jax_by_method = {r.method: r for r in results if r.backend == "jax"}
    columns = 2 + len(torch_results)
    fig = Figure(figsize=(3.2 * columns, 6.8), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, columns)
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
    for ax in axes.flat:
        ax.axis("off")
    fig.suptitle(f"diffblur demo: scene '{scene.name}', {scene.color.shape[3]}x{scene.color.shape[2]}")
    fig.savefig(path, dpi=90)


def format_table(results: list[DemoResult]) -> str:
    lines = [f"{'method':<28} {'backend':<7} {'PSNR dB':>8} {'SSIM':>7} {'ms':>8}"]
    for r in results:
        lines.append(f"{r.method:<28} {r.backend:<7} {r.psnr:>8.2f} {r.ssim:>7.4f} {r.milliseconds:>8.1f}")
    return "\n".join(lines)
