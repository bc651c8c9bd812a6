"""Every method against the Mitsuba ground truth (`diffblur.scenes.mitsuba`), in both backends: the
section "Scenes from a physically based renderer" of BENCHMARKS.md.

`python -m diffblur.app.mitsuba_bench --size 128 --write BENCHMARKS.md` renders (or reads from the cache)
the four scenes, runs each method with its defaults (only the scene's shutter passed) in PyTorch and
JAX, and writes the section between its markers, replacing an older one or appending it
(`diffblur bench`, which rewrites the rest of the file, keeps it). Per scene and method: PSNR and
SSIM against the accumulated target, and the forward time (median of 3 after a warm-up; PyTorch
eager, JAX eager calls). Then the issue's targets: each depth-reading op at its default band against
its best band (absolute 0.01 to 100 depth units, relative 0.03 to 3), and every op with the offsets'
float leftovers (static surfaces carry up to 5e-5 px at 128x128) against the same offsets with them zeroed.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
from typing import Any, Callable

import numpy as np

from diffblur import conventions
from diffblur.metrics import psnr, ssim
from diffblur.app.timing import median_ms

__all__ = ["BEGIN", "END", "METHODS", "measure", "section", "write_section"]

BEGIN = "<!-- mitsuba-scenes:begin (python -m diffblur.app.mitsuba_bench writes this section) -->"
END = "<!-- mitsuba-scenes:end -->"

#: name -> call(ops, buffers as backend arrays, shutter): each method with its defaults.
METHODS: dict[str, Callable[..., Any]] = {
    "gather_blur": lambda o, x, s: o.gather_blur(x["color"], x["velocity"], shutter=s),
    "reconstruct": lambda o, x, s: o.reconstruct(x["color"], x["velocity"], x["depth"], shutter=s),
    "reconstruct, own directions": lambda o, x, s: o.reconstruct(x["color"], x["velocity"], x["depth"], shutter=s, directions="neighbor_and_own"),
    "bezier_scatter": lambda o, x, s: o.bezier_scatter(x["color"], x["depth"], x["offset_prev"], x["offset_next"], shutter=s),
    "bezier_scatter, composite layers": lambda o, x, s: o.bezier_scatter(x["color"], x["depth"], x["offset_prev"], x["offset_next"], shutter=s, composite="layers"),
    "bezier_scatter, composite sum": lambda o, x, s: o.bezier_scatter(x["color"], x["depth"], x["offset_prev"], x["offset_next"], shutter=s, composite="sum"),
    "bezier_scatter, background": lambda o, x, s: o.bezier_scatter(x["color"], x["depth"], x["offset_prev"], x["offset_next"], shutter=s, fill=x["background"]),
    "warp_blend": lambda o, x, s: o.warp_blend(x["color"], x["velocity"]),
    "accumulate_warps": lambda o, x, s: o.accumulate_warps(x["color"], x["velocity"], shutter=s),
    "accumulate_warps, curved": lambda o, x, s: o.accumulate_warps(x["color"], None, shutter=s, offset_prev=x["offset_prev"], offset_next=x["offset_next"]),
}
#: The bands tried for "best band": absolute (depth units) and relative (fractions of depth).
BANDS = [("soft_z_extent", v) for v in (0.01, 0.1, 1.0, 10.0, 100.0)] + [("relative_z_extent", v) for v in (0.03, 0.1, 0.3, 1.0, 3.0)]


def _backend(name: str):
    if name == "torch":
        import torch

        import torch_impl

        return torch_impl, (lambda a: torch.tensor(np.ascontiguousarray(a), dtype=torch.float32)), (lambda t: t.detach().numpy().astype(np.float64)), (lambda t: t)
    import jax.numpy as jnp

    import jax_impl

    return jax_impl, (lambda a: jnp.asarray(a, dtype=jnp.float32)), (lambda t: np.asarray(t, dtype=np.float64)), (lambda t: t.block_until_ready())


def _arrays(buffers, convert) -> dict:
    fields = ("color", "depth", "velocity", "offset_prev", "offset_next")
    out = {f: convert(getattr(buffers, f)) for f in fields}
    out["background"] = None if buffers.background is None else convert(buffers.background)
    return out


def _without_leftovers(buffers):
    """The buffers with every offset shorter than STILL_SPEED set to exactly 0."""
    fields = {}
    for name in ("offset_prev", "offset_next"):
        offset = getattr(buffers, name).copy()
        offset[np.broadcast_to(np.hypot(offset[:, :1], offset[:, 1:]) < conventions.STILL_SPEED, offset.shape)] = 0.0
        fields[name] = offset
    fields["velocity"] = 0.5 * (fields["offset_next"] - fields["offset_prev"])
    return buffers.__class__(**{**buffers.__dict__, **fields})


def measure(
    *, size: int = 128, backends: tuple[str, ...] = ("torch", "jax"), scenes: tuple[str, ...] | None = None, cache_dir: str | None = None, repeats: int = 3
) -> dict:
    """The section's numbers: rows (scene, method, backend, psnr, ssim, forward ms), bands and
    leftovers (PyTorch); scenes: None for all of MITSUBA_SCENES."""
    import warnings

    from diffblur.scenes.mitsuba import MITSUBA_SCENES, mitsuba_buffers

    rows, bands, leftovers, sharp = [], [], [], {}
    for scene in MITSUBA_SCENES if scenes is None else scenes:
        b = mitsuba_buffers(scene, height=size, width=size, cache_dir=cache_dir)
        shutter = b.shutter.name
        sharp[scene] = (psnr(b.color, b.target), b.instants)
        for backend in backends:
            ops, convert, numpy, block = _backend(backend)
            x = _arrays(b, convert)
            for method, call in METHODS.items():
                if x["background"] is None and "background" in method:
                    continue
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", UserWarning)
                    out = numpy(call(ops, x, shutter))
                    ms = median_ms(lambda: block(call(ops, x, shutter)), repeats)
                rows.append(dict(scene=scene, method=method, backend=backend, psnr=psnr(out, b.target), ssim=ssim(out, b.target), ms=ms))
        ops, convert, numpy, _ = _backend("torch")
        x = _arrays(b, convert)
        for method, call in (("reconstruct", METHODS["reconstruct"]), ("bezier_scatter", METHODS["bezier_scatter"])):
            scores = {}
            for option, value in [(None, None), *BANDS]:
                kwargs = {} if option is None else {option: value}
                if method == "reconstruct":
                    out = ops.reconstruct(x["color"], x["velocity"], x["depth"], shutter=shutter, **kwargs)
                else:
                    out = ops.bezier_scatter(x["color"], x["depth"], x["offset_prev"], x["offset_next"], shutter=shutter, **kwargs)
                scores["default" if option is None else f"{'absolute' if option == 'soft_z_extent' else 'relative'} {value:g}"] = psnr(numpy(out), b.target)
            best = max((k for k in scores if k != "default"), key=scores.get)
            bands.append(dict(scene=scene, method=method, default=scores["default"], best=best, best_psnr=scores[best]))
        zeroed = _arrays(_without_leftovers(b), convert)
        largest = float(np.max(np.where(np.hypot(*b.offset_prev[0]) < conventions.STILL_SPEED, np.hypot(*b.offset_prev[0]), 0.0)))
        for method, call in METHODS.items():
            if x["background"] is None and "background" in method:
                continue
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)
                a, z = psnr(numpy(call(ops, x, shutter)), b.target), psnr(numpy(call(ops, zeroed, shutter)), b.target)
            leftovers.append(dict(scene=scene, method=method, change_db=abs(a - z), largest_px=largest))
    return dict(size=size, rows=rows, bands=bands, leftovers=leftovers, sharp=sharp, backends=list(backends))


def section(results: dict) -> str:
    """The markdown section, between BEGIN and END."""
    from diffblur.app.bench import cpu_model

    size = results["size"]
    lines = [
        BEGIN,
        "## Scenes from a physically based renderer",
        "",
        f"Generated by `python -m diffblur.app.mitsuba_bench --size {size} --write BENCHMARKS.md` "
        f"(`diffblur.app.mitsuba_bench`), {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, "
        f"{cpu_model()}, {os.cpu_count()} cores visible, {platform.python_version()}.",
        "",
        f"Mitsuba 3 (`diffblur.scenes.mitsuba`, scalar_rgb) renders four 3D scenes at {size}x{size}: a perspective "
        "camera, textured boxes, spheres and planes tilted to the view, depth in world units (2 to 12), "
        "offsets from each pixel's t = 0 hit point and its object's (or the camera's) motion, box shutter. "
        "Every method runs with its defaults, only the scene's shutter passed; float32; forward ms: median "
        "of 3 after a warm-up, PyTorch eager and JAX eager calls, on a machine shared with other work "
        "(times are indicative). `*`: the best PSNR of the scene.",
        "",
    ]
    for scene in dict.fromkeys(r["scene"] for r in results["rows"]):
        base, instants = results["sharp"][scene]
        rows = [r for r in results["rows"] if r["scene"] == scene]
        best = max(r["psnr"] for r in rows)
        lines += [f"### `{scene}` ({instants} instants; the sharp frame scores {base:.2f} dB)", "", "| method | backend | PSNR dB | SSIM | fwd ms |", "|---|---|---:|---:|---:|"]
        for r in rows:
            mark = " *" if r["psnr"] == best else ""
            lines.append(f"| {r['method']}{mark} | {r['backend']} | {r['psnr']:.2f} | {r['ssim']:.3f} | {r['ms']:.1f} |")
        lines.append("")
    lines += [
        "### Targets",
        "",
        "Default depth band against the best of absolute 0.01, 0.1, 1, 10, 100 depth units and relative 0.03, 0.1, 0.3, 1, 3 (PyTorch); target: within 0.5 dB.",
        "",
        "| scene | op | default dB | best band | best dB | gap dB | met |",
        "|---|---|---:|---|---:|---:|---|",
    ]
    for r in results["bands"]:
        gap = r["best_psnr"] - r["default"]
        lines.append(f"| {r['scene']} | {r['method']} | {r['default']:.2f} | {r['best']} | {r['best_psnr']:.2f} | {gap:.2f} | {'yes' if gap <= 0.5 else 'no'} |")
    lines += [
        "",
        "The scenes' offsets as rendered (static surfaces carry float leftovers, up to the largest shown) against the same offsets with every one shorter than STILL_SPEED set to 0 (PyTorch); target: no change above 0.05 dB.",
        "",
        "| scene | largest leftover px | largest change dB (method) | met |",
        "|---|---:|---|---|",
    ]
    for scene in dict.fromkeys(r["scene"] for r in results["leftovers"]):
        rows = [r for r in results["leftovers"] if r["scene"] == scene]
        worst = max(rows, key=lambda r: r["change_db"])
        lines.append(f"| {scene} | {worst['largest_px']:.1e} | {worst['change_db']:.4f} ({worst['method']}) | {'yes' if worst['change_db'] <= 0.05 else 'no'} |")
    targets = {"moving_box": 39.0, "propeller": 42.0, "crossing": 38.0, "dolly": 37.0}
    lines += ["", "Best method per scene with defaults (both backends' best), against the issue's targets:", "", "| scene | best method | PSNR dB | target dB | met |", "|---|---|---:|---:|---|"]
    for scene, target in targets.items():
        rows = [r for r in results["rows"] if r["scene"] == scene]
        if rows:
            top = max(rows, key=lambda r: r["psnr"])
            lines.append(f"| {scene} | {top['method']} ({top['backend']}) | {top['psnr']:.2f} | {target:.0f} | {'yes' if top['psnr'] >= target else 'no'} |")
    lines += ["", END]
    return "\n".join(lines)


def write_section(path: str, text: str) -> None:
    """Put the section into the markdown file at path: in place of an older one, else at the end."""
    old = open(path).read() if os.path.exists(path) else ""
    if BEGIN in old and END in old:
        head, rest = old.split(BEGIN, 1)
        new = head + text + rest.split(END, 1)[1]
    else:
        new = old.rstrip("\n") + "\n\n" + text + "\n"
    with open(path, "w") as f:
        f.write(new)


def kept_section(path: str) -> str | None:
    """The section as it stands in the file at path, or None."""
    if not os.path.exists(path):
        return None
    text = open(path).read()
    if BEGIN not in text or END not in text:
        return None
    return BEGIN + text.split(BEGIN, 1)[1].split(END, 1)[0] + END


__all__ += ["kept_section"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m diffblur.app.mitsuba_bench", description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=128, help="scene height and width in pixels (default: 128)")
    parser.add_argument("--backends", default="torch,jax", help="comma-separated: torch, jax (default: both)")
    parser.add_argument("--write", default=None, help="markdown file to write the section into (default: print it)")
    parser.add_argument("--cache", default=None, help="render cache folder (default: DIFFBLUR_CACHE or .cache/diffblur)")
    args = parser.parse_args(argv)
    text = section(measure(size=args.size, backends=tuple(args.backends.split(",")), cache_dir=args.cache))
    if args.write:
        write_section(args.write, text)
        print(f"wrote the section into {args.write}")
    else:
        print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
