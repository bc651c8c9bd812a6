"""Measure seed 002's warp_blend and accumulate_warps and seed 001's adaptive
tiles and pyramid against the scenes' ground truth, time them in PyTorch and JAX, compare adaptive
with full-rate sampling on a 90 %-still scene, and draw accumulate_warps' ghosting.

    PYTHONPATH=. python scripts/measure_warps_adaptive_pyramid.py --out docs          # everything
    PYTHONPATH=. python scripts/measure_warps_adaptive_pyramid.py --only ghosting     # just the picture

Importable: `accuracy_table`, `adaptive_speed`, `save_ghosting_picture` (tests may call them small).
Timings are the median of `repeats` runs after one warm-up, forward only, float32, one image; JAX
full-image ops are jit-compiled, JAX adaptive runs eagerly (its classes are sized on the host).
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from diffblur.metrics import psnr, ssim, to_display
from diffblur.scenes import make_scene
from diffblur.app.timing import median_ms

PRESETS = ("translate", "crossing", "propeller", "gears")

#: (label, op name, options, inputs): inputs "v" = color, velocity; "vd" = + depth; "o" = offsets.
METHODS = [
    ("accumulate N=2", "accumulate_warps", dict(instants=2), "v"),
    ("accumulate N=4", "accumulate_warps", dict(instants=4), "v"),
    ("accumulate N=8", "accumulate_warps", dict(instants=8), "v"),
    ("accumulate N=32", "accumulate_warps", dict(instants=32), "v"),
    ("accumulate N=32 offsets", "accumulate_warps", dict(instants=32), "o"),
    ("warp_blend n=2", "warp_blend", dict(iterations=2), "v"),
    ("warp_blend n=3", "warp_blend", dict(iterations=3), "v"),
    ("warp_blend n=3 doc (b=0.5, a=0.5..0.8)", "warp_blend", dict(iterations=3, backward_scale=0.5, alpha=(0.5, 0.8)), "v"),
    ("gather S=15", "gather_blur", dict(samples=15), "v"),
    ("gather S=15 adaptive", "gather_blur", dict(samples=15, adaptive=True), "v"),
    ("gather S=5", "gather_blur", dict(samples=5), "v"),
    ("gather S=5 pyramid", "gather_blur", dict(samples=5, sampling="pyramid"), "v"),
    ("reconstruct S=15", "reconstruct", dict(samples=15), "vd"),
    ("reconstruct S=15 adaptive", "reconstruct", dict(samples=15, adaptive=True), "vd"),
    ("reconstruct S=5", "reconstruct", dict(samples=5), "vd"),
    ("reconstruct S=5 pyramid", "reconstruct", dict(samples=5, sampling="pyramid"), "vd"),
]


def _torch_runner(name, options, inputs, scene):
    import torch

    import torch_impl

    op = getattr(torch_impl, name)
    arrays = {k: torch.tensor(getattr(scene, k), dtype=torch.float32) for k in ("color", "velocity", "depth", "offset_prev", "offset_next")}
    if inputs == "o":
        args, extra = (arrays["color"], None), dict(offset_prev=arrays["offset_prev"], offset_next=arrays["offset_next"])
    else:
        args, extra = (arrays["color"], arrays["velocity"]) + ((arrays["depth"],) if inputs == "vd" else ()), {}

    def run():
        with torch.no_grad():
            return op(*args, **options, **extra).numpy()

    return run


def _jax_runner(name, options, inputs, scene):
    import jax
    import jax.numpy as jnp

    import jax_impl

    op = getattr(jax_impl, name)
    arrays = {k: jnp.asarray(getattr(scene, k), dtype=jnp.float32) for k in ("color", "velocity", "depth", "offset_prev", "offset_next")}
    if inputs == "o":
        fn = lambda c, p, n: op(c, None, offset_prev=p, offset_next=n, **options)  # noqa: E731
        args = (arrays["color"], arrays["offset_prev"], arrays["offset_next"])
    else:
        fn = lambda *a: op(*a, **options)  # noqa: E731
        args = (arrays["color"], arrays["velocity"]) + ((arrays["depth"],) if inputs == "vd" else ())
    if not options.get("adaptive"):
        fn = jax.jit(fn)
    return lambda: np.asarray(fn(*args).block_until_ready())


def accuracy_table(presets=PRESETS, *, size: int = 128, repeats: int = 3, methods=METHODS, backends=("torch", "jax")) -> list[dict]:
    """Per preset and method: PSNR and SSIM of the PyTorch output against the ground truth, the
    largest difference between the backends, and the forward time of each backend (seconds)."""
    rows = []
    for preset in presets:
        scene = make_scene(preset, height=size, width=size)
        target = scene.target.astype(np.float32)
        for label, name, options, inputs in methods:
            row = {"preset": preset, "method": label}
            outputs = {}
            for backend in backends:
                runner = (_torch_runner if backend == "torch" else _jax_runner)(name, options, inputs, scene)
                outputs[backend] = runner()
                row[f"{backend}_s"] = median_ms(runner, repeats) / 1e3
            first = outputs[backends[0]]
            row["psnr"] = float(psnr(first, target))
            row["ssim"] = float(ssim(first, target))
            if len(backends) > 1:
                row["backend_max_diff"] = float(np.abs(outputs[backends[0]] - outputs[backends[1]]).max())
            rows.append(row)
    return rows


def still_scene(size: int = 512, *, moving_fraction: float = 0.1, speed=(8.0, 3.0), seed: int = 0):
    """A textured image, still except for one block of moving pixels covering `moving_fraction` of
    the image (aligned to 16 px tiles), moving uniformly; depth 1 (still) and 0.5 (moving)."""
    rng = np.random.default_rng(seed)
    color = rng.random((1, 3, size, size)).astype(np.float32)
    side = int(round(np.sqrt(moving_fraction) * size / 16)) * 16
    velocity = np.zeros((1, 2, size, size), np.float32)
    start = size // 8 // 16 * 16
    velocity[:, 0, start : start + side, start : start + side] = speed[0]
    velocity[:, 1, start : start + side, start : start + side] = speed[1]
    depth = np.ones((1, 1, size, size), np.float32)
    depth[:, :, start : start + side, start : start + side] = 0.5
    return color, velocity, depth


def adaptive_speed(size: int = 512, *, samples: int = 15, max_radius: float = 16.0, repeats: int = 5, backends=("torch", "jax")) -> list[dict]:
    """Adaptive against full-rate sampling on `still_scene`, both ops and both frameworks, in the
    same run: the times, their ratio, the fraction of pixels the adaptive filter processed, and the
    largest difference from the full-rate output on still tiles and on full-rate-class tiles."""
    import jax
    import jax.numpy as jnp
    import torch

    import jax_impl
    import torch_impl
    from diffblur.ops.adaptive import ADAPTIVE_TILE, adaptive_classes, still_speed, tile_sample_counts

    color, velocity, depth = still_scene(size)
    classes = adaptive_classes(True, samples)
    rows = []
    for op in ("gather_blur", "reconstruct"):
        if op == "gather_blur":
            tile, options = ADAPTIVE_TILE, dict(samples=samples)
            tiles = torch_impl.tile_max(torch.tensor(velocity), tile).numpy()
        else:
            tile, options = int(np.ceil(max_radius)), dict(samples=samples, max_radius=max_radius)
            tiles = torch_impl.neighbor_max(torch_impl.tile_max(torch.tensor(velocity), tile)).numpy()
        counts = tile_sample_counts(np.hypot(tiles[:, 0], tiles[:, 1]), classes, still_speed(False), np)
        pixel_counts = np.repeat(np.repeat(counts, tile, axis=1), tile, axis=2)[:, None, :size, :size]
        pixel_counts = np.broadcast_to(pixel_counts, color.shape)
        for backend in backends:
            if backend == "torch":
                arrays = [torch.tensor(a) for a in (color, velocity, depth)][: 2 if op == "gather_blur" else 3]
                fn = getattr(torch_impl, op)

                def full(fn=fn, arrays=arrays):
                    with torch.no_grad():
                        return fn(*arrays, **options).numpy()

                def adaptive(fn=fn, arrays=arrays):
                    with torch.no_grad():
                        return fn(*arrays, **options, adaptive=True).numpy()
            else:
                arrays = [jnp.asarray(a) for a in (color, velocity, depth)][: 2 if op == "gather_blur" else 3]
                fn = getattr(jax_impl, op)
                jitted = jax.jit(lambda *a, fn=fn: fn(*a, **options))
                full = lambda jitted=jitted, arrays=arrays: np.asarray(jitted(*arrays).block_until_ready())  # noqa: E731
                adaptive = lambda fn=fn, arrays=arrays: np.asarray(fn(*arrays, **options, adaptive=True).block_until_ready())  # noqa: E731
            full_out, adaptive_out = full(), adaptive()
            full_s, adaptive_s = median_ms(full, repeats) / 1e3, median_ms(adaptive, repeats) / 1e3
            rows.append(
                {
                    "op": op,
                    "backend": backend,
                    "full_s": full_s,
                    "adaptive_s": adaptive_s,
                    "speedup": full_s / adaptive_s,
                    "processed_fraction": float((pixel_counts > 0).mean()),
                    "still_max_diff": float(np.abs(adaptive_out - full_out)[pixel_counts == 0].max()),
                    "full_rate_tiles_max_diff": float(np.abs(adaptive_out - full_out)[pixel_counts == samples].max())
                    if (pixel_counts == samples).any()
                    else None,
                }
            )
    return rows


def save_ghosting_picture(path: str = "docs/accumulate_ghosting.png", *, preset: str = "translate", size: int = 128, counts=(2, 4, 8, 32)) -> str:
    """accumulate_warps (PyTorch) at few and many instants next to the sharp frame and the ground
    truth: the separate copies of seed 002 Figure 1 at small N."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import torch

    import torch_impl

    scene = make_scene(preset, height=size, width=size)
    color, velocity = torch.tensor(scene.color), torch.tensor(scene.velocity)
    panels = [("sharp frame", scene.color)]
    for count in counts:
        out = torch_impl.accumulate_warps(color, velocity, instants=count).numpy()
        panels.append((f"accumulate_warps N={count}\nPSNR {psnr(out, scene.target):.1f} dB", out))
    panels.append(("ground truth", scene.target))
    figure, axes = plt.subplots(1, len(panels), figsize=(2.6 * len(panels), 3.0))
    for axis, (title, image) in zip(axes, panels):
        axis.imshow(to_display(image)[0])
        axis.set_title(title, fontsize=9)
        axis.axis("off")
    figure.tight_layout()
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path


def _print_accuracy(rows: list[dict]) -> None:
    print("| preset | method | PSNR dB | SSIM | torch ms | jax ms | max |torch - jax| |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['preset']} | {r['method']} | {r['psnr']:.2f} | {r['ssim']:.4f} | {1e3 * r['torch_s']:.1f} | "
            f"{1e3 * r.get('jax_s', float('nan')):.1f} | {r.get('backend_max_diff', float('nan')):.1e} |"
        )


def _print_adaptive(rows: list[dict]) -> None:
    print("| op | backend | full-rate ms | adaptive ms | speed-up | pixels processed | max diff still | max diff full-rate tiles |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['op']} | {r['backend']} | {1e3 * r['full_s']:.1f} | {1e3 * r['adaptive_s']:.1f} | {r['speedup']:.2f}x | "
            f"{100 * r['processed_fraction']:.1f} % | {r['still_max_diff']:.1e} | {r['full_rate_tiles_max_diff']:.1e} |"
        )


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs", help="folder for accumulate_ghosting.png")
    parser.add_argument("--only", choices=("accuracy", "adaptive", "ghosting"), default=None)
    parser.add_argument("--size", type=int, default=128, help="preset size for the accuracy table")
    parser.add_argument("--adaptive-size", type=int, default=512)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--backends", nargs="+", default=["torch", "jax"], choices=["torch", "jax"], help="for --only adaptive")
    args = parser.parse_args(argv)
    print(f"# {time.strftime('%Y-%m-%d %H:%M')} {platform.machine()} {os.cpu_count()} CPUs, load {os.getloadavg()[0]:.1f}")
    if args.only in (None, "ghosting"):
        print("picture:", save_ghosting_picture(os.path.join(args.out, "accumulate_ghosting.png")))
    if args.only in (None, "adaptive"):
        _print_adaptive(adaptive_speed(args.adaptive_size, repeats=args.repeats, backends=tuple(args.backends)))
    if args.only in (None, "accuracy"):
        _print_accuracy(accuracy_table(size=args.size, repeats=args.repeats))
    print(f"# load at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
