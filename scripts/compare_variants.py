"""PSNR of method variants on three scene sets (PyTorch, float32, box shutter):

- tuned: the four Mitsuba scenes (`diffblur.scenes.mitsuba`) at --size;
- presets: the 2.5D presets (`diffblur.scenes`, seed 0) at --size;
- untuned: the Mitsuba variants of scripts/mitsuba_untuned.py (UNTUNED_SEED, 64x64) and the presets
  drawn with seed UNTUNED_SEED, nothing tuned on them;
- heldout: the same drawn with HELDOUT_SEED (--variants 3 at 64x64), rendered after composite=
  "instants" was chosen, for reporting only.

    PYTHONPATH=. python scripts/compare_variants.py --group scatter --sets tuned,presets,untuned
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings

import numpy as np
import torch

sys.path.insert(0, os.path.dirname(__file__))

import torch_impl  # noqa: E402
from diffblur.metrics import psnr  # noqa: E402


def _t(a):
    return torch.tensor(np.ascontiguousarray(a), dtype=torch.float32)


def variants(group: str):
    o = torch_impl
    if group == "scatter":
        return {
            "sum": lambda c, v, z, p, n, bg: o.bezier_scatter(c, z, p, n, composite="sum"),
            "layers": lambda c, v, z, p, n, bg: o.bezier_scatter(c, z, p, n, composite="layers"),
            "sum, no depth test": lambda c, v, z, p, n, bg: o.bezier_scatter(c, z, p, n, soft_z_extent=1e6, composite="sum"),
            "layers, no depth test": lambda c, v, z, p, n, bg: o.bezier_scatter(c, z, p, n, soft_z_extent=1e6),
            "sum, background": lambda c, v, z, p, n, bg: None if bg is None else o.bezier_scatter(c, z, p, n, fill=bg, composite="sum"),
            "layers, background": lambda c, v, z, p, n, bg: None if bg is None else o.bezier_scatter(c, z, p, n, fill=bg),
        }
    if group == "composite":  # bezier_scatter's composites, each with the fill="still" default and the scene's background
        table = {}
        for composite in ("instants", "layers", "sum"):
            table[composite] = lambda c, v, z, p, n, bg, k=composite: o.bezier_scatter(c, z, p, n, composite=k)
            table[f"{composite}, background"] = lambda c, v, z, p, n, bg, k=composite: None if bg is None else o.bezier_scatter(c, z, p, n, fill=bg, composite=k)
        return table
    if group == "band":  # the scatter's relative depth band, with layers (the default composite)
        return {f"relative {r:g}": (lambda c, v, z, p, n, bg, r=r: o.bezier_scatter(c, z, p, n, relative_z_extent=r)) for r in (0.03, 0.1, 0.2, 0.3, 1.0)} | {
            f"relative {r:g}, background": (lambda c, v, z, p, n, bg, r=r: None if bg is None else o.bezier_scatter(c, z, p, n, relative_z_extent=r, fill=bg)) for r in (0.1, 0.3)}
    if group == "reconstruct":
        from proto_reconstruct import reconstruct as r

        return {
            "reconstruct": lambda c, v, z, p, n, bg: o.reconstruct(c, v, z),
            "proto": lambda c, v, z, p, n, bg: r(c, v, z),
            "lookup 0.5": lambda c, v, z, p, n, bg: r(c, v, z, lookup_jitter=0.5),
            "lookup 1": lambda c, v, z, p, n, bg: r(c, v, z, lookup_jitter=1.0),
            "directional": lambda c, v, z, p, n, bg: r(c, v, z, directional=True),
            "own": lambda c, v, z, p, n, bg: o.reconstruct(c, v, z, directions="neighbor_and_own"),
            "gather": lambda c, v, z, p, n, bg: o.gather_blur(c, v),
        }
    raise SystemExit(f"unknown group {group}")


def scene_sets(sets: list[str], size: int):
    if "tuned" in sets:
        from diffblur.scenes.mitsuba import MITSUBA_SCENES, mitsuba_buffers

        for name in MITSUBA_SCENES:
            yield "tuned", name, mitsuba_buffers(name, height=size, width=size)
    if "presets" in sets:
        from diffblur.scenes import make_scene

        for name in ("translate", "pan", "crossing", "propeller", "zoom", "gears"):
            yield "presets", name, make_scene(name, height=size, width=size)
    if "untuned" in sets:
        from diffblur.scenes import make_scene
        from mitsuba_untuned import UNTUNED_SEED, untuned_scenes

        for name, b in untuned_scenes(64, 2).items():
            yield "untuned", "mitsuba " + name, b
        for name in ("translate", "pan", "crossing", "propeller", "zoom", "gears"):
            yield "untuned", f"{name} s{UNTUNED_SEED}", make_scene(name, height=size, width=size, seed=UNTUNED_SEED)
    if "heldout" in sets:
        from diffblur.scenes import make_scene
        from mitsuba_untuned import HELDOUT_SEED, untuned_scenes

        for name, b in untuned_scenes(64, 3, HELDOUT_SEED).items():
            yield "heldout", "mitsuba " + name, b
        for name in ("translate", "pan", "crossing", "propeller", "zoom", "gears"):
            yield "heldout", f"{name} s{HELDOUT_SEED}", make_scene(name, height=size, width=size, seed=HELDOUT_SEED)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--group", default="scatter")
    parser.add_argument("--sets", default="tuned,presets,untuned")
    parser.add_argument("--size", type=int, default=64)
    args = parser.parse_args()
    torch.set_num_threads(1)
    table = variants(args.group)
    print("| set | scene | " + " | ".join(table) + " |")
    print("|---|---|" + "---:|" * len(table))
    for group, name, b in scene_sets(args.sets.split(","), args.size):
        x = [_t(getattr(b, f)) for f in ("color", "velocity", "depth", "offset_prev", "offset_next")]
        bg = None if b.background is None else _t(b.background)
        cells = []
        for label, call in table.items():
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                out = call(*x, bg)
            cells.append("-" if out is None else f"{psnr(out.detach().numpy(), b.target):.2f}")
        print(f"| {group} | {name} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
