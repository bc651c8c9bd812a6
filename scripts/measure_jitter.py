"""What reconstruct's per-pixel jitter buys (issue 23, "Measure first").

Two measurements, PyTorch on the CPU, float64, 128x128 unless `--size` says otherwise:

1. Accuracy. `torch_impl.reconstruct` with `jitter="noise"` (interleaved gradient noise, the
   default) against `jitter="none"`, S = 5, 9, 15, 21, 31, `sampling="bilinear"` and
   `sampling="pyramid"`, every other option at its default and the scene's own shutter passed;
   PSNR and SSIM (`diffblur.metrics`) against the accumulated ground truth, on every preset
   (`diffblur.scenes.PRESETS`), the benchmark's "uniform" pan (`diffblur.app.bench.uniform_scene`)
   and, when Mitsuba 3 is installed, the four scenes of `diffblur.scenes.mitsuba` (rendered once,
   then read from its cache).

2. The loss surface of a fit. On a few presets the true velocity is scaled by s (0.5 .. 1.5, and a
   fine window 0.9 .. 1.1), the loss is the MSE of reconstruct(color, s V, depth) against the
   target, bilinear, for each jitter. Reported: where the minimum lies (the grid's best point refined
   by a parabola through it and its neighbours), the roughness of the curve (RMS of its second
   difference over the curve's range, the interior local minima, the sign changes of the autograd
   gradient along the grid), and d loss / d s from autograd at a few points against the central
   difference of the curve (step of the grid) and a fine central difference (step 1e-4).

    PYTHONPATH=. python scripts/measure_jitter.py [--size 128] [--no-mitsuba] [--write] [--plot docs/jitter_loss.png]

`--write` puts the section "## Reconstruct's jitter" into BENCHMARKS.md (replacing an older one, or
appended at the end); `--plot` saves the loss curves as a PNG.
"""

from __future__ import annotations

import argparse
import os
import platform
import shlex
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import torch  # noqa: E402

import torch_impl  # noqa: E402
from diffblur.metrics import psnr, ssim  # noqa: E402
from diffblur.scenes import PRESETS, make_scene  # noqa: E402

HEADING = "## Reconstruct's jitter"
SAMPLES = (5, 9, 15, 21, 31)
SAMPLINGS = ("bilinear", "pyramid")
JITTERS = ("noise", "none")
#: The presets and tap counts of the loss-surface measurement.
SURFACE_SCENES = ("translate", "pan")
SURFACE_SAMPLES = (5, 15)
COARSE = np.linspace(0.5, 1.5, 41)
#: The fine window: 41 points on +-0.1 around the mean of the two jitters' coarse minima (step 0.005).
FINE_HALF_WIDTH = 0.1
#: Where autograd's d loss / d s is compared with the finite differences (points of COARSE).
GRADIENT_POINTS = (0.8, 1.0, 1.2)
FINE_STEP = 1e-4


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def scenes(size: int, mitsuba: bool) -> tuple[list[tuple[str, object]], str]:
    """[(label, SceneBuffers)], and a note on the Mitsuba scenes."""
    out = [(name, make_scene(name, height=size, width=size)) for name in PRESETS]
    from diffblur.app.bench import uniform_scene

    out.append(("uniform", uniform_scene(height=size, width=size)))
    note = ""
    if mitsuba:
        try:
            from diffblur.scenes.mitsuba import MITSUBA_SCENES, mitsuba_buffers

            for name in MITSUBA_SCENES:
                log(f"  mitsuba {name}: rendering or reading the cache")
                out.append((f"mitsuba {name}", mitsuba_buffers(name, height=size, width=size)))
        except ImportError as error:
            note = f"the Mitsuba scenes are absent: {error}"
    else:
        note = "the Mitsuba scenes were not run (--no-mitsuba)"
    return out, note


def tensors(buffers) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, np.ndarray]:
    color, velocity, depth = (torch.from_numpy(np.ascontiguousarray(a, dtype=np.float64)) for a in (buffers.color, buffers.velocity, buffers.depth))
    return color, velocity, depth, np.asarray(buffers.target, dtype=np.float64)


def accuracy(all_scenes) -> list[dict]:
    rows = []
    for label, buffers in all_scenes:
        t0 = time.perf_counter()
        color, velocity, depth, target = tensors(buffers)
        for samples in SAMPLES:
            row = {"scene": label, "samples": samples}
            for sampling in SAMPLINGS:
                for jitter in JITTERS:
                    with torch.no_grad():
                        out = torch_impl.reconstruct(color, velocity, depth, samples=samples, jitter=jitter, sampling=sampling, shutter=buffers.shutter)
                    out = out.numpy()
                    row[(sampling, jitter, "psnr")] = psnr(out, target)
                    row[(sampling, jitter, "ssim")] = ssim(out, target)
            rows.append(row)
        log(f"  accuracy {label}: {time.perf_counter() - t0:.1f} s")
    return rows


def _loss(color, velocity, depth, target, s, samples, jitter):
    out = torch_impl.reconstruct(color, velocity * s, depth, samples=samples, jitter=jitter, shutter="box")
    return ((out - target) ** 2).mean()


def _curve(color, velocity, depth, target, grid, samples, jitter):
    """Loss and autograd d loss / d s at each point of grid."""
    losses, grads = [], []
    for s in grid:
        st = torch.tensor(float(s), dtype=torch.float64, requires_grad=True)
        loss = _loss(color, velocity, depth, target, st, samples, jitter)
        (g,) = torch.autograd.grad(loss, st)
        losses.append(float(loss.detach()))
        grads.append(float(g))
    return np.array(losses), np.array(grads)


def _argmin(grid, losses) -> float:
    """The grid's best point refined by the vertex of the parabola through it and its neighbours."""
    i = int(np.argmin(losses))
    if i == 0 or i == len(grid) - 1:
        return float(grid[i])
    y0, y1, y2 = losses[i - 1 : i + 2]
    h = grid[1] - grid[0]
    denominator = y0 - 2 * y1 + y2
    return float(grid[i] + (0.5 * h * (y0 - y2) / denominator if denominator > 0 else 0.0))


def _roughness(grid, losses, grads) -> dict:
    second = np.diff(losses, 2)
    h = grid[1] - grid[0]
    curve_fd = (losses[2:] - losses[:-2]) / (2 * h)
    inner = grads[1:-1]
    span = float(losses.max() - losses.min())
    interior = losses[1:-1]
    minima = int(np.sum((interior < losses[:-2]) & (interior < losses[2:])))
    signs = np.sign(grads[grads != 0])
    return {
        "rms_second_over_range": float(np.sqrt(np.mean(second**2)) / span) if span > 0 else float("nan"),
        "local_minima": minima,
        "grad_sign_changes": int(np.sum(signs[1:] != signs[:-1])),
        "fd_sign_agreement": float(np.mean(np.sign(inner) == np.sign(curve_fd))),
        "fd_relative_rms": float(np.sqrt(np.mean((inner - curve_fd) ** 2)) / np.sqrt(np.mean(curve_fd**2))),
    }


def surface(size: int) -> tuple[list[dict], list[dict], dict]:
    """(summary rows, gradient rows, curves for the plot)."""
    summary, gradients, curves = [], [], {}
    for name in SURFACE_SCENES:
        t0 = time.perf_counter()
        buffers = make_scene(name, height=size, width=size)
        assert buffers.shutter.__class__.__name__ == "Box", buffers.shutter  # the loss passes shutter="box"
        color, velocity, depth, target = tensors(buffers)
        target_t = torch.from_numpy(target)
        for samples in SURFACE_SAMPLES:
            rows = {jitter: {"scene": name, "samples": samples, "jitter": jitter} for jitter in JITTERS}
            for jitter in JITTERS:
                losses, grads = _curve(color, velocity, depth, target_t, COARSE, samples, jitter)
                curves[(name, samples, jitter, "coarse")] = (COARSE, losses, grads)
                rows[jitter]["coarse"] = {"argmin": _argmin(COARSE, losses), **_roughness(COARSE, losses, grads), "min_loss": float(losses.min()), "window": (float(COARSE[0]), float(COARSE[-1]))}
                h = COARSE[1] - COARSE[0]
                for s in GRADIENT_POINTS:
                    i = int(np.argmin(np.abs(COARSE - s)))
                    curve_fd = (losses[i + 1] - losses[i - 1]) / (2 * h)
                    with torch.no_grad():
                        plus = float(_loss(color, velocity, depth, target_t, COARSE[i] + FINE_STEP, samples, jitter))
                        minus = float(_loss(color, velocity, depth, target_t, COARSE[i] - FINE_STEP, samples, jitter))
                    gradients.append(
                        {"scene": name, "samples": samples, "jitter": jitter, "s": float(COARSE[i]), "autograd": grads[i], "curve_fd": curve_fd, "fine_fd": (plus - minus) / (2 * FINE_STEP)}
                    )
            center = round(np.mean([rows[j]["coarse"]["argmin"] for j in JITTERS]) / 0.005) * 0.005
            fine = np.linspace(center - FINE_HALF_WIDTH, center + FINE_HALF_WIDTH, 41)
            for jitter in JITTERS:
                losses, grads = _curve(color, velocity, depth, target_t, fine, samples, jitter)
                curves[(name, samples, jitter, "fine")] = (fine, losses, grads)
                rows[jitter]["fine"] = {"argmin": _argmin(fine, losses), **_roughness(fine, losses, grads), "min_loss": float(losses.min()), "window": (float(fine[0]), float(fine[-1]))}
            summary += [rows[j] for j in JITTERS]
        log(f"  loss surface {name}: {time.perf_counter() - t0:.1f} s")
    return summary, gradients, curves


def plot(path: str, curves: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = [(n, s) for n in SURFACE_SCENES for s in SURFACE_SAMPLES]
    fig, axes = plt.subplots(2, len(keys), figsize=(3.2 * len(keys), 5.2), squeeze=False)
    for col, (name, samples) in enumerate(keys):
        for row, window in enumerate(("coarse", "fine")):
            ax = axes[row][col]
            for jitter, style in zip(JITTERS, ("-", "--")):
                grid, losses, _ = curves[(name, samples, jitter, window)]
                ax.plot(grid, losses, style, marker=".", markersize=3, label=f'jitter="{jitter}"')
            ax.axvline((samples + 1) / samples, color="grey", linewidth=0.8)
            ax.set_title(f"{name}, S={samples}", fontsize=9)
            ax.set_xlabel("velocity scale s", fontsize=8)
            ax.tick_params(labelsize=7)
            if col == 0:
                ax.set_ylabel("MSE", fontsize=8)
    axes[0][0].legend(fontsize=7)
    fig.suptitle("reconstruct (bilinear): MSE against the target for velocity s V (grey: (S + 1) / S)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def _f(x: float, digits: int = 2) -> str:
    return "inf" if x == float("inf") else f"{x:.{digits}f}"


def tables(rows: list[dict], summary: list[dict], gradients: list[dict]) -> str:
    lines = [
        "| scene | S | bilinear noise dB | bilinear none dB | none - noise dB | bilinear noise SSIM | bilinear none SSIM | pyramid noise dB | pyramid none dB | none - noise dB | pyramid noise SSIM | pyramid none SSIM |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        cells = [r["scene"], str(r["samples"])]
        for sampling in SAMPLINGS:
            a, b = r[(sampling, "noise", "psnr")], r[(sampling, "none", "psnr")]
            cells += [_f(a), _f(b), _f(b - a) if np.isfinite(a) and np.isfinite(b) else "-", _f(r[(sampling, "noise", "ssim")], 4), _f(r[(sampling, "none", "ssim")], 4)]
        lines.append("| " + " | ".join(cells) + " |")
    accuracy_table = "\n".join(lines)

    moving = [r for r in rows if r["scene"] != "static"]
    lines = [
        "| sampling | S | none - noise dB: min | median | max | none - noise SSIM: min | median | max | scenes where none is better (PSNR) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for sampling in SAMPLINGS:
        for samples in SAMPLES:
            sel = [r for r in moving if r["samples"] == samples]
            d = np.array([r[(sampling, "none", "psnr")] - r[(sampling, "noise", "psnr")] for r in sel])
            e = np.array([r[(sampling, "none", "ssim")] - r[(sampling, "noise", "ssim")] for r in sel])
            lines.append(
                f"| {sampling} | {samples} | {d.min():+.2f} | {np.median(d):+.2f} | {d.max():+.2f} | {e.min():+.4f} | {np.median(e):+.4f} | {e.max():+.4f} | {int(np.sum(d > 0))} of {len(d)} |"
            )
    summary_table = "\n".join(lines)

    lines = [
        "| scene | S | jitter | window of s | argmin s | (S+1)/S | RMS 2nd diff / range | local minima | autograd sign changes | sign(autograd) = sign(curve diff.) | autograd - curve diff., relative RMS | min MSE |",
        "|---|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for window in ("coarse", "fine"):
        for r in summary:
            w = r[window]
            lines.append(
                f"| {r['scene']} | {r['samples']} | {r['jitter']} | {w['window'][0]:.3f}-{w['window'][1]:.3f} | {w['argmin']:.4f}{' (edge)' if w['argmin'] in w['window'] else ''} | {(r['samples'] + 1) / r['samples']:.4f} | {w['rms_second_over_range']:.2e} "
                f"| {w['local_minima']} | {w['grad_sign_changes']} | {100 * w['fd_sign_agreement']:.0f} % | {w['fd_relative_rms']:.2f} | {w['min_loss']:.3e} |"
            )
    surface_table = "\n".join(lines)

    lines = [
        "| scene | S | jitter | s | autograd d loss/d s | central diff., step 0.025 | central diff., step 1e-4 | autograd / step-1e-4 |",
        "|---|---:|---|---:|---:|---:|---:|---:|",
    ]
    for g in gradients:
        ratio = g["autograd"] / g["fine_fd"] if g["fine_fd"] != 0 else float("nan")
        lines.append(f"| {g['scene']} | {g['samples']} | {g['jitter']} | {g['s']:.3f} | {g['autograd']:.4e} | {g['curve_fd']:.4e} | {g['fine_fd']:.4e} | {ratio:.4f} |")
    gradient_table = "\n".join(lines)
    return accuracy_table, summary_table, surface_table, gradient_table


def _span(values, fmt="{:+.2f}") -> str:
    lo, hi = min(values), max(values)
    return fmt.format(lo) if fmt.format(lo) == fmt.format(hi) else f"{fmt.format(lo)} to {fmt.format(hi)}"


def conclusion(rows: list[dict], summary: list[dict], gradients: list[dict]) -> str:
    """The section's closing sentences, from this run's numbers."""
    moving = [r for r in rows if r["scene"] != "static"]

    def delta(r, sampling, metric="psnr"):
        return r[(sampling, "none", metric)] - r[(sampling, "noise", metric)]

    high = [r for r in moving if r["samples"] >= 15]
    low = [r for r in moving if r["samples"] <= 9]
    d_high = [delta(r, "bilinear") for r in high]
    d_high_pyramid = [delta(r, "pyramid") for r in high]
    helps = [r for r in high if delta(r, "bilinear") < -0.3]
    if helps:
        where = ", ".join(f"{r['scene']} at S={r['samples']} ({-delta(r, 'bilinear'):.2f} dB)" for r in helps)
        helps_text = f'the jitter is worth more than 0.3 dB there only on {where}'
    else:
        helps_text = "the jitter is worth more than 0.3 dB on none of them"
    best_low = max(low, key=lambda r: delta(r, "bilinear"))
    ssim_better = sum(delta(r, "bilinear", "ssim") >= 0 for r in moving)
    first = (
        f'On the bilinear path at S >= 15, jitter="none" scores {_span(d_high)} dB against "noise" on every moving scene '
        f"(median {np.median(d_high):+.2f} dB) and {helps_text}; at S = 5-9 \"none\" is {_span([delta(r, 'bilinear') for r in low])} dB "
        f"(best +{delta(best_low, 'bilinear'):.2f} dB, {best_low['scene']} at S={best_low['samples']}), its SSIM is as high or higher in "
        f"{ssim_better} of {len(moving)} rows, and with sampling=\"pyramid\" at S >= 15 \"none\" scores {_span(d_high_pyramid)} dB."
    )

    def by(jitter, window, key):
        return [r[window][key] for r in summary if r["jitter"] == jitter]

    ratio = [n["coarse"]["rms_second_over_range"] for n in summary if n["jitter"] == "none"]
    ratio = [a / b["coarse"]["rms_second_over_range"] for a, b in zip(ratio, [r for r in summary if r["jitter"] == "noise"])]
    if min(ratio) > 1:
        smoother = f"What the jitter does buy is a smoother loss in s ({', '.join(SURFACE_SCENES)}; S = {', '.join(map(str, SURFACE_SAMPLES))}): over 0.5-1.5 its curve's RMS second difference is {min(ratio):.1f}-{max(ratio):.1f} times smaller"
    else:
        smoother = f"On the loss in s ({', '.join(SURFACE_SCENES)}; S = {', '.join(map(str, SURFACE_SAMPLES))}), over 0.5-1.5 the RMS second difference without the jitter is {min(ratio):.1f}-{max(ratio):.1f} times the one with it"
    second = (
        f"{smoother}, autograd's d loss / d s changes sign {_span(by('noise', 'coarse', 'grad_sign_changes'), '{:d}')} times "
        f"against {_span(by('none', 'coarse', 'grad_sign_changes'), '{:d}')} and differs from the curve's slope by {_span(by('noise', 'coarse', 'fd_relative_rms'), '{:.2f}')} (relative RMS) "
        f"against {_span(by('none', 'coarse', 'fd_relative_rms'), '{:.2f}')}; at the step of 0.005 near the minimum the curves have "
        f"{_span(by('noise', 'fine', 'local_minima'), '{:d}')} local minima with the jitter and {_span(by('none', 'fine', 'local_minima'), '{:d}')} without."
    )
    noise_min = {(r["scene"], r["samples"]): r["fine"]["argmin"] for r in summary if r["jitter"] == "noise"}
    none_min = {(r["scene"], r["samples"]): r["fine"]["argmin"] for r in summary if r["jitter"] == "none"}
    shift = [noise_min[k] - none_min[k] for k in noise_min]
    direction = "not in one direction" if min(shift) < 0 < max(shift) else ("always to smaller s" if max(shift) < 0 else "always to larger s")
    worst = max(abs(g["autograd"] / g["fine_fd"] - 1.0) for g in gradients if g["fine_fd"] != 0)
    third = (
        f"The jitter moves the minimum (fine window) by {_span(shift)} in s, {direction} (with it s = {_span(list(noise_min.values()), '{:.3f}')}, without "
        f"{_span(list(none_min.values()), '{:.3f}')}; (S + 1) / S = {', '.join(f'{(k + 1) / k:.3f}' for k in SURFACE_SAMPLES)}), and autograd matches a central difference "
        f"of step 1e-4 within {100 * worst:.1f} % at every point checked, with either jitter."
    )
    return " ".join((first, second, third))


def section(command: str, size: int, note: str, shutters: str, plot_path: str | None, closing: str, accuracy_table: str, summary_table: str, surface_table: str, gradient_table: str, seconds: float) -> str:
    load = os.getloadavg() if hasattr(os, "getloadavg") else ("?",) * 3
    picture = f"\n\n![jitter loss curves]({plot_path})" if plot_path else ""
    mitsuba = f" ({note})" if note else " and the four Mitsuba 3 scenes (`diffblur.scenes.mitsuba`, rendered once into its cache)"
    return f"""{HEADING}

Generated by `{command}` (`scripts/measure_jitter.py`), {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC; {platform.machine()}, os.cpu_count() = {os.cpu_count()}, torch {torch.__version__} (threads {torch.get_num_threads()}), load average {load[0]:.1f} before the run (shared machine), {seconds:.0f} s.

`torch_impl.reconstruct` at {size}x{size}, float64, CPU, every option at its default except `samples`, `jitter`, `sampling` and the scene's own shutter ({shutters}): `jitter="noise"` (interleaved gradient noise, the default) against `jitter="none"`, PSNR and SSIM (`diffblur.metrics`) against the accumulated ground truth. Scenes: every preset of `diffblur.scenes.PRESETS`, the benchmark's `uniform` pan{mitsuba}. "none - noise" > 0: the filter without jitter is the closer one. The bilinear rows run on the fused kernel, the pyramid rows on the tensor ops.

{accuracy_table}

Over the moving scenes (all but `static`, whose output is the image up to rounding either way):

{summary_table}

The loss surface of a fit: the true velocity scaled by s, loss = MSE of reconstruct(color, s V, depth, samples=S, sampling="bilinear") against the target, 41 points on 0.5-1.5 (step 0.025, "window" 0.500-1.500), then 41 on a fine window of +-0.1 (step 0.005) around the mean of the two jitters' coarse minima, the same window for both jitters. argmin: the grid's best point refined by the parabola through its neighbours; its taps span S / (S + 1) of the path, so a minimum near (S + 1) / S is the filter's known under-blur, not the jitter's. Roughness: RMS of the second difference over the curve's range (a smooth curve's is set by its curvature and the step, so compare the jitters at one step), interior local minima of the curve, sign changes of autograd's d loss / d s along the grid (1 for a curve with one minimum inside the window, 0 if it lies outside), and how autograd's d loss / d s at each interior point agrees with the central difference of the curve at the grid's step (sign agreement; RMS of the difference over the RMS of the difference quotient).

{surface_table}

d loss / d s from autograd against central differences of the loss (the step of the coarse curve, and 1e-4):

{gradient_table}{picture}

{closing}
"""


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--no-mitsuba", action="store_true", help="skip the Mitsuba scenes")
    parser.add_argument("--write", action="store_true", help=f"put the section {HEADING!r} into BENCHMARKS.md")
    parser.add_argument("--benchmarks", default="BENCHMARKS.md", help="the markdown file --write writes (relative to the repository root)")
    parser.add_argument("--plot", default=None, help="save the loss curves to this PNG (a path relative to the repository root)")
    args = parser.parse_args(argv)
    command = "PYTHONPATH=. python scripts/measure_jitter.py" + "".join(" " + shlex.quote(a) for a in (sys.argv[1:] if argv is None else argv))
    t0 = time.perf_counter()
    log(f"rendering scenes at {args.size}x{args.size}")
    all_scenes, note = scenes(args.size, not args.no_mitsuba)
    if note:
        log(note)
    rows = accuracy(all_scenes)
    summary, gradients, curves = surface(args.size)
    texts = tables(rows, summary, gradients)
    closing = conclusion(rows, summary, gradients)
    for text in (*texts, closing):
        print(text + "\n", flush=True)
    shutters = ", ".join(sorted({type(b.shutter).__name__.lower() for _, b in all_scenes}))
    if args.plot:
        plot(str(ROOT / args.plot), curves)
        log(f"wrote {args.plot}")
    if args.write:
        from diffblur.app.bench import replace_section

        text = section(command, args.size, note, shutters, args.plot, closing, *texts, time.perf_counter() - t0)
        replace_section(str(ROOT / args.benchmarks), HEADING, text)
        log(f"wrote the section {HEADING!r} of {args.benchmarks}")


if __name__ == "__main__":
    main()
