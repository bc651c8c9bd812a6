"""Where each method's error lives on the Mitsuba scenes (issue 21's per-scene targets).

    PYTHONPATH=. python scripts/diagnose_mitsuba.py --size 128 [--scenes moving_box,dolly] [--sweep]

Per scene: every method with its defaults, then (--sweep) hand-tuned settings, each with its PSNR
and the split of its squared error over regions found from the buffers and the renderer's geometry
(never from the target):

- hidden: pixels whose ray, at one of HIDDEN_INSTANTS instants of the exposure, hits a point the
  sharp frame does not show (traced by Mitsuba; see `hidden`): no method that reads one frame has it;
- border: pixels whose path (X + offset at t = -1, +1, and X - offset, what the camera brings in)
  leaves the image: what they show during the exposure is partly outside the sharp frame;
- edge: within 1 px of a depth discontinuity (3 x 3 depth ratio > 1.1) that moves or is swept;
- moving: the other moving pixels (objects' interiors; everything under a moving camera);
- swept: still pixels that a moving path passes over (coverage > 1e-3, no depth test);
- still: the rest (still pixels nothing passes over).

Regions are exclusive, taken in this order. For each region: its share of the pixels, its share of
the squared error, and the PSNR the method would reach were that region exact ("if 0"). PyTorch,
float32, box shutter.
"""

from __future__ import annotations

import argparse
import math
import warnings

import numpy as np
import torch

import torch_impl
from diffblur import conventions
from diffblur.metrics import psnr

REGIONS = ("hidden", "border", "edge", "moving", "swept", "still")
#: Instants at which the renderer's rays are traced to find the pixels that see hidden points.
HIDDEN_INSTANTS = 9


def hidden(b) -> np.ndarray:
    """Fraction of HIDDEN_INSTANTS instants (stratum midpoints) at which each pixel's ray hits a point
    the sharp frame does not show: moved back to t = 0 by its object's motion and projected, it lands
    outside the image or more than 1 % behind the depth buffer there (hidden by a nearer surface)."""
    from diffblur.scenes.mitsuba import _hits, _mitsuba, project

    mi = _mitsuba()
    scene = b.scene
    height, width = scene.height, scene.width
    depth0 = b.depth[0, 0]
    out = np.zeros((height, width))
    for t in [(2.0 * i + 1.0) / HIDDEN_INSTANTS - 1.0 for i in range(HIDDEN_INSTANTS)]:
        points, index = _hits(mi, scene, t)
        back = points.copy()
        for k, o in enumerate(scene.objects):
            mine = index == k
            inverse = np.linalg.inv(o.motion.matrix(t))
            back[mine] = points[mine] @ inverse[:3, :3].T + inverse[:3, 3]
        x, y, z = project(scene.camera, 0.0, back, height, width)
        inside = (x > -0.5) & (x < width - 0.5) & (y > -0.5) & (y < height - 0.5)
        xi = np.clip(np.round(x).astype(int), 0, width - 1)
        yi = np.clip(np.round(y).astype(int), 0, height - 1)
        # the nearest depth around the landing point (a silhouette pixel may hold either surface)
        zmin = np.min(np.stack([depth0[np.clip(yi + a, 0, height - 1), np.clip(xi + c, 0, width - 1)] for a in (-1, 0, 1) for c in (-1, 0, 1)]), 0)
        zmax = np.max(np.stack([depth0[np.clip(yi + a, 0, height - 1), np.clip(xi + c, 0, width - 1)] for a in (-1, 0, 1) for c in (-1, 0, 1)]), 0)
        seen = inside & (z <= zmax * 1.01)
        out += ~seen
    return out / HIDDEN_INSTANTS


def _t(a):
    return torch.tensor(np.ascontiguousarray(a), dtype=torch.float32)


def coverage(b) -> np.ndarray:
    """Fraction of the exposure some moving path covers each pixel (no depth test), (H, W)."""
    from diffblur.ops.sampling import pixel_grid
    from diffblur.ops.scatter import _bezier_terms, _splat_sums, constant_masses, moving_mask
    from diffblur.shutters import get_shutter
    from torch_impl._backend import TORCH

    color, depth = _t(b.color), _t(b.depth)
    prev, nxt = _t(b.offset_prev), _t(b.offset_next)
    x, y = pixel_grid(TORCH, color.shape[2], color.shape[3], color)
    moving = moving_mask("bezier", (prev, nxt), x, y)
    masses = torch.tensor(constant_masses(get_shutter("box"), 32), dtype=torch.float32)
    sums = _splat_sums(TORCH, color, depth, _bezier_terms(2, prev, nxt, None), masses, 1e9, moving, x, y, kind="bezier", paper=False, passes=1)
    return sums[0, -1].numpy()


def regions(b) -> dict[str, np.ndarray]:
    _, _, height, width = b.color.shape
    cx, cy = np.meshgrid(np.arange(width), np.arange(height), indexing="xy")
    outside = np.zeros((height, width), bool)
    for o in (b.offset_prev[0], b.offset_next[0]):
        for sign in (1, -1):
            px, py = cx + sign * o[0], cy + sign * o[1]
            outside |= (px < -0.5) | (px > width - 0.5) | (py < -0.5) | (py > height - 0.5)
    speed = np.maximum(np.hypot(*b.offset_prev[0]), np.hypot(*b.offset_next[0]))
    moving = speed > conventions.STILL_SPEED
    z = np.pad(b.depth[0, 0], 1, mode="edge")
    windows = np.stack([z[i : i + height, j : j + width] for i in range(3) for j in range(3)])
    discontinuity = windows.max(0) / windows.min(0) > 1.1
    swept = coverage(b) > 1e-3
    out = {}
    taken = np.zeros((height, width), bool)
    for name, mask in (
        ("hidden", hidden(b) > 0),
        ("border", outside),
        ("edge", discontinuity & (moving | swept)),
        ("moving", moving),
        ("swept", swept),
        ("still", np.ones_like(moving)),
    ):
        out[name] = mask & ~taken
        taken |= mask
    return out


def split(out: np.ndarray, b, masks) -> dict:
    err = ((out.astype(np.float64) - b.target) ** 2).sum(1)[0]  # (H, W), summed over channels
    total = err.sum()
    n = err.size * b.color.shape[1]
    res = {}
    for name, m in masks.items():
        rest = total - err[m].sum()
        res[name] = (m.mean(), err[m].sum() / total, 10 * math.log10(n / max(rest, 1e-30)))
    return res


def methods(b, sweep: bool):
    c, v, z, p, nx = (_t(getattr(b, f)) for f in ("color", "velocity", "depth", "offset_prev", "offset_next"))
    bg = None if b.background is None else _t(b.background)
    o = torch_impl
    yield "gather_blur", lambda: o.gather_blur(c, v)
    yield "reconstruct", lambda: o.reconstruct(c, v, z)
    yield "bezier_scatter", lambda: o.bezier_scatter(c, z, p, nx)
    yield "bezier_scatter, sum", lambda: o.bezier_scatter(c, z, p, nx, composite="sum")
    if bg is not None:
        yield "bezier_scatter, background", lambda: o.bezier_scatter(c, z, p, nx, fill=bg)
        yield "bezier_scatter, background, sum", lambda: o.bezier_scatter(c, z, p, nx, fill=bg, composite="sum")
    yield "warp_blend", lambda: o.warp_blend(c, v)
    yield "accumulate_warps", lambda: o.accumulate_warps(c, v)
    if not sweep:
        return
    for s in (31, 63):
        yield f"gather S={s}", lambda s=s: o.gather_blur(c, v, samples=s)
    for it in (4, 5):
        yield f"warp_blend it={it}", lambda it=it: o.warp_blend(c, v, iterations=it)
    for n in (32, 64):
        yield f"accumulate {n}", lambda n=n: o.accumulate_warps(c, v, instants=n)
    for mr in (5.0, 10.0, 40.0):
        yield f"reconstruct max_radius={mr:g}", lambda mr=mr: o.reconstruct(c, v, z, max_radius=mr)
    yield "reconstruct S=31", lambda: o.reconstruct(c, v, z, samples=31)
    yield "reconstruct own", lambda: o.reconstruct(c, v, z, directions="neighbor_and_own")
    yield "reconstruct no depth test", lambda: o.reconstruct(c, v, z, soft_z_extent=1e6)
    for extra in ({}, {"background": bg} if bg is not None else None):
        if extra is None:
            continue
        tag = ", bg" if extra else ""
        yield f"scatter no depth test{tag}", lambda e=extra: o.bezier_scatter(c, z, p, nx, soft_z_extent=1e6, **e)
        yield f"scatter rel 1{tag}", lambda e=extra: o.bezier_scatter(c, z, p, nx, relative_z_extent=1.0, **e)
        yield f"scatter rel 0.03{tag}", lambda e=extra: o.bezier_scatter(c, z, p, nx, relative_z_extent=0.03, **e)
        yield f"scatter 64 points{tag}", lambda e=extra: o.bezier_scatter(c, z, p, nx, max_samples=64, **e)
        yield f"scatter degree 1{tag}", lambda e=extra: o.bezier_scatter(c, z, p, nx, degree=1, **e)
        yield f"scatter fill color{tag}", lambda e=extra: o.bezier_scatter(c, z, p, nx, fill="color", **e)
        yield f"scatter paper{tag}", lambda e=extra: o.bezier_scatter(c, z, p, nx, normalization="paper", **e)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--scenes", default="moving_box,crossing,dolly,propeller")
    parser.add_argument("--sweep", action="store_true")
    parser.add_argument("--maps", default=None, help="folder for error-map .npy files of the defaults")
    args = parser.parse_args()
    from diffblur.scenes.mitsuba import mitsuba_buffers

    torch.set_num_threads(1)
    for name in args.scenes.split(","):
        b = mitsuba_buffers(name, height=args.size, width=args.size)
        masks = regions(b)
        print(f"\n## {name} {args.size}x{args.size}: sharp {psnr(b.color, b.target):.2f} dB; pixels "
              + ", ".join(f"{r} {masks[r].mean():.0%}" for r in REGIONS))
        print(f"| method | PSNR | " + " | ".join(f"{r} err% (if 0)" for r in REGIONS) + " |")
        for label, call in methods(b, args.sweep):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                out = call().detach().numpy()
            s = split(out, b, masks)
            print(f"| {label} | {psnr(out, b.target):.2f} | " + " | ".join(f"{s[r][1]:.0%} ({s[r][2]:.1f})" for r in REGIONS) + " |", flush=True)
            if args.maps and label in ("bezier_scatter", "bezier_scatter, background", "warp_blend", "reconstruct", "gather_blur"):
                import os

                os.makedirs(args.maps, exist_ok=True)
                np.save(f"{args.maps}/{name}_{label.replace(', ', '_')}.npy", out)


if __name__ == "__main__":
    main()
