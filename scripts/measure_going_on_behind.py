"""bezier_scatter's composite="instants" with and without its rule for an object that goes on behind a
nearer surface (`diffblur.ops.scatter._going_on_behind`): PSNR against the ground truth, PyTorch,
float32, box shutter, with the default fill and with the scene behind as the fill. "without" zeroes
the rule (a monkeypatch), so the two columns differ in that rule alone.

    PYTHONPATH=. python scripts/measure_going_on_behind.py --sets tuned,presets --size 128
    PYTHONPATH=. python scripts/measure_going_on_behind.py --sets 20261208 --variants 3 --size 128

A set is "tuned" (the four Mitsuba scenes), "presets" (the 2.5D presets, seed 0) or a seed, which
draws `scripts/mitsuba_untuned.py`'s variants of the Mitsuba scenes with it; every set at --size.
Measured numbers: docs/defaults.md, "The scatter's compositing".
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings

import torch

import torch_impl
from diffblur.metrics import psnr
from diffblur.ops import scatter

_RULE = scatter._going_on_behind


def _without(be, kind, times, terms, x, y, moving, depth, extent):
    return be.xp.zeros((times.shape[0], depth.shape[0], 1, *depth.shape[2:]), dtype=depth.dtype)


def _score(b, fill, rule) -> float:
    scatter._going_on_behind = rule
    try:
        t = [torch.from_numpy(getattr(b, k)) for k in ("color", "depth", "offset_prev", "offset_next")]
        kwargs = {} if fill is None else {"fill": torch.from_numpy(fill)}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # no still pixel (a moving camera)
            out = torch_impl.bezier_scatter(*t, shutter=b.shutter.name, **kwargs)
    finally:
        scatter._going_on_behind = _RULE
    return psnr(out.numpy(), b.target)


def _scenes(name: str, size: int, variants: int):
    if name == "tuned":
        from diffblur.scenes.mitsuba import MITSUBA_SCENES, mitsuba_buffers

        return {f"Mitsuba {n}": mitsuba_buffers(n, height=size, width=size) for n in MITSUBA_SCENES}
    if name == "presets":
        from diffblur.scenes import make_scene

        return {n: make_scene(n, height=size, width=size) for n in ("translate", "pan", "crossing", "propeller", "zoom", "gears")}
    sys.path.insert(0, os.path.dirname(__file__))
    from mitsuba_untuned import untuned_scenes

    return {f"Mitsuba {n}": b for n, b in untuned_scenes(size, variants, seed=int(name)).items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sets", default="tuned,presets")
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--variants", type=int, default=3, help="variants of each Mitsuba scene in a seed's set")
    args = parser.parse_args()
    print("| set | scene | without | with | without, bg | with, bg |")
    print("|---|---|---:|---:|---:|---:|")
    for set_name in args.sets.split(","):
        for name, b in _scenes(set_name, args.size, args.variants).items():
            cells = [_score(b, None, _without), _score(b, None, _RULE)]
            if b.background is not None:
                cells += [_score(b, b.background, _without), _score(b, b.background, _RULE)]
            print(f"| {set_name} | {name} | " + " | ".join(f"{c:.2f}" for c in cells) + " |" + (" - | - |" if b.background is None else ""), flush=True)


if __name__ == "__main__":
    main()
