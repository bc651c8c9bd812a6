"""Motion models: a few parameters in, the ops' inputs out, so a user models only what the scene needs.

A model is written once for both frameworks: it receives the framework's adapter (`be`, see
`fitting._backends`) and the current pyramid level's arrays (`ctx`), and returns the re-blurred
image. Parameters are a dict of NumPy arrays outside the solver (`init`, `rescale`, `report`) and of
framework arrays inside it (`render`, `prior`).
"""

from __future__ import annotations

import copy
import math
import warnings
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from diffblur import checks
from diffblur.shutters import LinearRamp, ShutterWindow, Trapezoid, Tukey, get_shutter

#: Default start for velocities: away from the v = 0 stationary point of a symmetric shutter, and
#: with unequal components so that it is not on a symmetry axis of the image either.
DEFAULT_VELOCITY = (1.0, 0.5)
#: Starts closer to 0 than this (pixels) are moved out to it (see `nudge`).
MIN_START_SPEED = 0.1

#: The scatter's compositing in every model: seed 003's sum. The models' algebra rests on it (`covered`
#: reads 1 - the scatter of ones over a zero background as the share of the exposure the paths cover,
#: `layered_scatter` composites premultiplied per-layer scatters itself), and the held-out results
#: (docs/fitting.md) were measured with it; the op's default "layers" also splats three times.
COMPOSITE = "sum"


def nudge(v: np.ndarray) -> np.ndarray:
    """A start velocity, moved off v = 0: under a symmetric shutter the blur is even in v, so its
    gradient vanishes at 0 and a solver started there never leaves."""
    v = np.array(v, dtype=np.float64).reshape(2)
    speed = math.hypot(*v)
    if speed < MIN_START_SPEED:
        v = v / speed * MIN_START_SPEED if speed > 0 else np.array([MIN_START_SPEED, 0.5 * MIN_START_SPEED])
    return v


def is_symmetric(window: ShutterWindow) -> bool:
    """w(t) == w(-t): then a velocity -v blurs exactly like +v."""
    t = np.linspace(-1.0, 1.0, 41)
    return bool(np.allclose(np.asarray(window.weight(t), dtype=np.float64), np.asarray(window.weight(-t), dtype=np.float64)))


def canonical_sign(v: np.ndarray) -> np.ndarray:
    """The representative of {v, -v} with x > 0 (or x == 0 and y >= 0)."""
    v = np.asarray(v, dtype=np.float64)
    flip = v[..., 0] < 0
    flip = flip | ((v[..., 0] == 0) & (v[..., 1] < 0))
    return np.where(flip[..., None], -v, v)


def interpolation_matrix(size: int, nodes: int) -> np.ndarray:
    """(size, nodes) linear interpolation from `nodes` evenly spread samples (the first at pixel 0,
    the last at pixel size - 1) to every pixel: a smooth, exact upsampling both frameworks share."""
    if nodes == 1:
        return np.ones((size, 1))
    position = np.linspace(0.0, nodes - 1.0, size)
    low = np.minimum(np.floor(position).astype(int), nodes - 2)
    frac = position - low
    out = np.zeros((size, nodes))
    out[np.arange(size), low] = 1.0 - frac
    out[np.arange(size), low + 1] += frac
    return out


@dataclass
class Context:
    """One pyramid level, in the solver's framework: the images and what the model reads."""

    be: Any
    color: Any
    depth: Any
    target: Any
    height: int
    width: int
    scale: float  # this level's pixels per full-resolution pixel
    options: dict
    extras: dict


@dataclass(frozen=True)
class TabulatedWindow(ShutterWindow):
    """A shutter window given by its antiderivative W at the edges of K equal strata of [-1, 1]
    (`edges`, `values`: K + 1 each, arrays of the fit's framework), linear in between.

    The ops weigh the scatter's K points and the gather's K taps by the window's mass on their
    strata, which this gives exactly; and a table is data to JAX, where a window is a static option:
    the fit's compiled loss then serves every shutter, not one each."""

    edges: Any
    values: Any
    name: ClassVar[str] = "tabulated"

    def _per_stratum(self, x: Any, t: Any) -> Any:
        """A (K,) array `x` shaped to broadcast against t[..., None] (JAX's strict rank promotion)."""
        return x.reshape((1,) * len(t.shape) + (-1,))

    def _position(self, t: Any) -> Any:
        """(..., K): how far t is through each stratum, 0 to 1 inside it."""
        low, width = self.edges[:-1], self.edges[1:] - self.edges[:-1]
        return (t[..., None] - self._per_stratum(low, t)) / self._per_stratum(width, t)

    def _masses(self, t: Any) -> Any:
        return self._per_stratum(self.values[1:] - self.values[:-1], t)

    def weight(self, t: Any, xp: Any = np) -> Any:
        t = _as_array(t, xp)
        u = self._position(t)
        density = self._masses(t) / self._per_stratum(self.edges[1:] - self.edges[:-1], t)
        return xp.where((u >= 0.0) & (u < 1.0), density + 0.0 * u, 0.0 * u).sum(-1)

    def _antiderivative(self, t: Any, xp: Any) -> Any:
        u = self._position(t)
        u = xp.where(u < 0.0, 0.0 * u, xp.where(u > 1.0, 0.0 * u + 1.0, u))
        return self.values[0] + (u * self._masses(t)).sum(-1)


def _as_array(t: Any, xp: Any) -> Any:
    return np.asarray(t, dtype=np.float64) if xp is np else t


def shutter_tables(be: Any, window: ShutterWindow, counts: Any) -> dict[int, tuple[Any, Any]]:
    """For each count K, the edges of K equal strata of [-1, 1] and `window`'s antiderivative there
    (`TabulatedWindow`'s data), as arrays of `be`."""
    tables = {}
    for count in sorted(set(counts)):
        edges = np.linspace(-1.0, 1.0, count + 1)
        tables[count] = (be.array(edges), be.array(np.asarray(window.antiderivative(edges), dtype=np.float64)))
    return tables


def shutter_of(ctx: Context, count: int) -> ShutterWindow:
    """The window an op of `count` points or taps blurs with: the level's table for that count
    (`shutter_tables`) where there is one, else the options' window."""
    tables = ctx.extras.get("shutter_tables") or {}
    return TabulatedWindow(*tables[count]) if count in tables else ctx.options["shutter"]


def _blur(ctx: Context, velocity: Any, shutter: Any = None) -> Any:
    """The configured op on a (1, 2, h, w) velocity field."""
    o = ctx.options
    if shutter is None:
        count = {"gather": o["samples"], "scatter": o.get("scatter_samples")}.get(o["method"])
        shutter = shutter_of(ctx, count) if count is not None else o["shutter"]
    # JAX's fused kernels have reverse-mode gradients only; LM and Dogleg take forward-mode Jacobians.
    impl = "tensor" if ctx.be.name == "jax" and o.get("jac", "fwd") == "fwd" else "auto"
    if o["method"] == "gather":
        return ctx.be.ops.gather_blur(ctx.color, velocity, samples=o["samples"], shutter=shutter, impl=impl)
    if o["method"] == "scatter":
        # Seed 003's scatter of linear motion (offsets -V, +V) with the user's shutter, coverage
        # normalisation and the push-pull fill: the blur that spreads an object over the pixels it
        # passes, which a gather (a pixel reads along its own velocity only) cannot. Where every pixel
        # moves (a pan) the fill is each pixel's own colour, as meant: the op's warning about that
        # would only repeat what the model says.
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r"bezier_scatter\(fill='still'\) found no still pixel", category=UserWarning)
            return ctx.be.ops.bezier_scatter(ctx.color, ctx.depth, -velocity, velocity, degree=1, samples=o["scatter_samples"], shutter=shutter, impl=impl, composite=COMPOSITE)
    # Seed 000's taps span S / (S + 1) of the exposure: scale the velocity so the blur spans all of it
    # and the parameters are the scene's (see recover's docstring).
    span = (o["samples"] + 1.0) / o["samples"]
    return ctx.be.ops.reconstruct(ctx.color, velocity * span, ctx.depth, samples=o["samples"], max_radius=o["max_radius"], shutter=shutter, impl=impl)


#: `covered`: a moving pixel counts as shown by the sharp frame where its paths cover at least this
#: fraction of the exposure.
COVERED = 0.99


def covered(ctx: Context, velocity: Any) -> np.ndarray:
    """(1, 1, h, w) 1 where the scatter's output rests on the sharp frame alone, 0 where it needs the
    push-pull fill: moving pixels that moving paths cover for less than COVERED of the exposure, where
    the target shows what the sharp frame hides behind a moving object. The fill's guess biases a fit
    (an object's speed comes out 10 to 15 % short on an object over a textured background), so the
    scatter's residual leaves such pixels out."""
    return (ctx.be.numpy(ctx.be.run(_hidden_share, ctx, velocity)) <= 1.0 - COVERED).astype(np.float64)


def _hidden_share(ctx: Context, velocity: Any) -> Any:
    """(1, 1, h, w) the share of each pixel's exposure that the fill or a hidden layer shows (see
    `covered`)."""
    if ctx.extras.get("layers") is not None:
        return layered_scatter(ctx, velocity, hidden_share=True)
    ones = ctx.depth * 0.0 + 1.0
    o = ctx.options
    return 1.0 - ctx.be.ops.bezier_scatter(ones, ctx.depth, -velocity, velocity, degree=1, samples=o["scatter_samples"], shutter=shutter_of(ctx, o["scatter_samples"]), fill=ones * 0.0, composite=COMPOSITE)


@dataclass
class LayerStack:
    """A level's depth layers for the layered scatter (`layered_scatter`), the nearest first.

    sources: (L, C + 2, h, w) per layer [colour x mask, mask, nearer], mask 1 on the layer's pixels
    and nearer 1 on the pixels of nearer layers (where the layer may be hidden); depth: (L, 1, h, w)
    the depth with every other layer's pixels set to the layer's median (each layer is scattered
    alone, with a depth test among its own pixels only); fill: (1, C, h, w) the farthest layer's
    colours extended by push-pull over the pixels nearer layers hide; ids: the model's ID of each
    layer, the nearest first; velocity: (L, 2, h, w) a known velocity field extended from each
    layer's pixels over the image by push-pull (`Exposure`), or None."""

    sources: Any
    depth: Any
    fill: Any
    ids: tuple[int, ...]
    velocity: Any = None


def _pool(x: np.ndarray) -> np.ndarray:
    """Sums over 2 x 2 blocks, an odd side padded with zeros (bezier_scatter's `_pool`)."""
    x = np.pad(x, ((0, 0), (0, 0), (0, x.shape[-2] % 2), (0, x.shape[-1] % 2)))
    return (x[..., 0::2, 0::2] + x[..., 0::2, 1::2]) + (x[..., 1::2, 0::2] + x[..., 1::2, 1::2])


def _upsample(x: np.ndarray, height: int, width: int) -> np.ndarray:
    """Bilinear upsampling by 2 between pixel centres, the border repeated (bezier_scatter's)."""
    for axis, size in ((-2, height), (-1, width)):
        before = np.concatenate([np.take(x, [0], axis), np.take(x, np.arange(x.shape[axis] - 1), axis)], axis)
        after = np.concatenate([np.take(x, np.arange(1, x.shape[axis]), axis), np.take(x, [-1], axis)], axis)
        doubled = np.stack([0.75 * x + 0.25 * before, 0.75 * x + 0.25 * after], axis=axis)
        shape = list(x.shape)
        shape[axis] *= 2
        x = np.take(doubled.reshape(shape), np.arange(size), axis)
    return x


def push_pull(color: np.ndarray, known: np.ndarray) -> np.ndarray:
    """`color` (B, C, H, W) extended from the pixels where `known` (B, 1, H, W) is 1 over the
    others by bezier_scatter's push-pull (its fill="still"; `diffblur.reference._scatter.still_fill`
    is the loop-based oracle): NumPy, for the fits' constant data."""
    levels = [(color * known, known)]
    while max(levels[-1][1].shape[-2:]) > 1:
        levels.append(tuple(_pool(v) for v in levels[-1]))
    total, weight = levels[-1]
    estimate = total / np.where(weight > 0, weight, 1.0)
    for total, weight in reversed(levels[:-1]):
        mean = np.where(weight > 0, total / np.where(weight > 0, weight, 1.0), 0.0)
        share = np.minimum(weight, 1.0)
        estimate = share * mean + (1.0 - share) * _upsample(estimate, *weight.shape[-2:])
    return np.where(levels[-1][1] > 0, estimate, color)


def layer_stack(be: Any, color: np.ndarray, depth: np.ndarray, ids: np.ndarray, velocity: np.ndarray | None = None) -> LayerStack | None:
    """The `LayerStack` of an ID map, its IDs ordered by median depth (the nearest first), with a
    known (1, 2, H, W) `velocity` extended from each layer over the image; None when the map holds
    one ID."""
    present = [int(k) for k in np.unique(ids)]
    if len(present) < 2:
        return None
    medians = {k: float(np.median(depth[ids == k])) for k in present}
    order = tuple(sorted(present, key=lambda k: (medians[k], k)))
    masks = [(ids == k).astype(np.float64) for k in order]
    sources, depths = [], []
    nearer = np.zeros_like(masks[0])
    for k, mask in zip(order, masks):
        sources.append(np.concatenate([color * mask, mask, nearer], axis=1))
        depths.append(np.where(mask > 0, depth, medians[k]))
        nearer = nearer + mask
    fill = be.array(push_pull(color, masks[-1]))
    known = None if velocity is None else be.array(np.concatenate([push_pull(velocity, mask) for mask in masks]))
    return LayerStack(be.array(np.concatenate(sources)), be.array(np.concatenate(depths)), fill, order, known)


def layered_scatter(ctx: Context, motion: Any, *, hidden_share: bool = False) -> Any:
    """Seed 003's scatter of linear motion, one depth layer at a time, composited nearest first.

    `motion`: (n L, 2, h, w) per candidate a velocity field for each of the L layers of
    ctx.extras["layers"] (the nearest first), each over the whole image. Every layer's pixels are
    scattered alone, premultiplied: its colour C_k and its coverage A_k (the fraction of the exposure
    it covers a pixel). The composite C_0 + (1 - A_0) (C_1 + (1 - A_1) (... + fill)) then puts a
    nearer layer in front of a farther one wherever their paths cross, which one scatter of every
    pixel cannot: seed 003 has no depth write, so there two moving objects are averaged. For one
    layer moving over a still one this is the plain scatter (the still layer's coverage is its mask).

    Returns (n, C, h, w); with hidden_share, (n, 1, h, w) the share of each pixel's exposure that
    shows what the sharp frame hides (the fill, or a layer where a nearer one covered it at t = 0),
    plus where two layers each cover the pixel for part of the exposure (the composite's guess).
    """
    be, o = ctx.be, ctx.options
    stack: LayerStack = ctx.extras["layers"]
    layers = len(stack.ids)
    n = motion.shape[0] // layers
    channels = stack.fill.shape[1]
    sources = be.concat([stack.sources] * n)
    depth = be.concat([stack.depth] * n)
    zero = sources * 0.0
    # fill=0: what no path covers adds nothing, so each layer comes out premultiplied.
    splatted = be.ops.bezier_scatter(sources, depth, -motion, motion, degree=1, samples=o["scatter_samples"], shutter=shutter_of(ctx, o["scatter_samples"]), fill=zero, composite=COMPOSITE)
    splatted = splatted.reshape(n, layers, channels + 2, ctx.height, ctx.width)
    out, through, hidden = 0.0, 1.0, 0.0
    partial_sum, partial_squares = 0.0, 0.0
    for k in range(layers):
        out = out + through * splatted[:, k, :channels]
        if k < layers - 1:
            hidden = hidden + through * splatted[:, k, channels + 1 : channels + 2]
        coverage = splatted[:, k, channels : channels + 1]
        through = through * (1.0 - coverage)
        if hidden_share:
            partial = 4.0 * coverage * (1.0 - coverage)
            partial_sum, partial_squares = partial_sum + partial, partial_squares + partial * partial
    if hidden_share:
        # The composite is exact where at most one layer covers a pixel for part of the exposure
        # (a still layer covers it all or none of it); where two do, it assumes their coverings
        # independent in time, which crossing objects are not. Their product counts as hidden.
        overlap = 0.5 * (partial_sum * partial_sum - partial_squares)
        return hidden + through + overlap
    return out + through * stack.fill


def render_batch(ctx: Context, motions: Any) -> Any:
    """(n, C, h, w): the configured op on n models' motions (`Model.motion`, concatenated along the
    batch axis) at once, the images repeated."""
    n = motions.shape[0]
    if ctx.extras.get("layers") is not None:
        return layered_scatter(ctx, motions)
    batch = Context(ctx.be, ctx.be.concat([ctx.color] * n), ctx.be.concat([ctx.depth] * n), ctx.target, ctx.height, ctx.width, ctx.scale, ctx.options, ctx.extras)
    return _blur(batch, motions)


class Model:
    """Base class; see the module docstring."""

    name: ClassVar[str]
    #: Adam's default learning rate (parameter units per step).
    learning_rate: ClassVar[float] = 0.1
    #: Whether the blur depends on the sign of the velocity only through the shutter.
    sign_ambiguous: ClassVar[bool] = True

    def static_key(self) -> tuple:
        """The options `render`, `velocity`, `motion` and `prior` read (the rest only shape the
        inputs): models with equal keys share compiled functions. None by default."""
        return ()

    def inputs(self, shape: tuple[int, ...], depth: np.ndarray, depth_given: bool) -> dict[str, np.ndarray]:
        """The model's own full-resolution arrays for the pyramid ("velocity", "ids", "mask",
        "background", and "weight" to multiply the residual's), checked against the image's `shape`
        (1, C, H, W); none by default."""
        return {}

    def init(self, ctx: Context, init: dict | None) -> dict[str, np.ndarray]:
        raise NotImplementedError

    def velocity(self, p: dict, ctx: Context) -> Any:
        raise NotImplementedError

    #: Whether `render` is the configured op on `motion` (so candidates render in one batch).
    batched = True
    #: Whether the model gives each depth layer a velocity field of its own (`layer_motion`), so that
    #: the scatter composites the layers (`layered_scatter`).
    layered = False

    def layer_motion(self, p: dict, ctx: Context) -> Any:
        """(L, 2, h, w): a velocity field per layer of ctx.extras["layers"], the nearest first."""
        raise NotImplementedError

    def motion(self, p: dict, ctx: Context) -> Any:
        """What the op receives: the velocity field, or one per layer where the scatter composites
        depth layers."""
        return self.layer_motion(p, ctx) if ctx.extras.get("layers") is not None else self.velocity(p, ctx)

    def render(self, p: dict, ctx: Context) -> Any:
        if ctx.extras.get("layers") is not None:
            return layered_scatter(ctx, self.layer_motion(p, ctx))
        return _blur(ctx, self.velocity(p, ctx))

    def prior(self, p: dict, ctx: Context) -> list:
        """Extra least-squares residuals (regularisation), each a flat array; none by default."""
        return []

    def rescale(self, p: dict, factor: float, height: int, width: int) -> dict[str, np.ndarray]:
        """The parameters at a level `factor` times finer (height x width pixels)."""
        return {k: np.array(v) for k, v in p.items()}

    def report(self, p: dict, symmetric: bool) -> dict[str, Any]:
        raise NotImplementedError

    def canonical(self, p: dict) -> dict[str, np.ndarray]:
        """The representative of the parameters that blur alike under a symmetric shutter."""
        return p

    def search(self, p: dict, loss: Any, ctx: Context, radius: float, symmetric: bool) -> dict[str, np.ndarray]:
        """A coarse global search before the local solver (at the coarsest level): `loss([p, ...])`
        gives the losses of NumPy parameter dicts, `radius` is the largest speed to try in this level's
        pixels. None by default."""
        return p


#: The coarse search's grid step (pixels of the level it runs at): within the basin of the local
#: solver for textures smoother than a couple of pixels.
SEARCH_STEP = 0.5


def velocity_candidates(radius: float, symmetric: bool, step: float = SEARCH_STEP) -> np.ndarray:
    """(n, 2) velocities on a square grid of `step` within `radius` of 0, 0 included; one of each
    pair {v, -v} when the shutter is symmetric (they blur alike)."""
    ticks = np.arange(-math.floor(radius / step), math.floor(radius / step) + 1) * step
    vx, vy = np.meshgrid(ticks, ticks, indexing="xy")
    v = np.stack([vx.ravel(), vy.ravel()], axis=1)
    v = v[np.hypot(v[:, 0], v[:, 1]) <= radius + 1e-9]
    if symmetric:
        v = v[(v[:, 0] > 0) | ((v[:, 0] == 0) & (v[:, 1] >= 0))]
    return v


def search_velocity(losses: Any, make: Any, radius: float, symmetric: bool) -> np.ndarray:
    """The velocity within `radius` whose parameters `make(v)` have the lowest loss: a grid of twice
    SEARCH_STEP first, then SEARCH_STEP within two coarse steps of its best (a quarter of the
    candidates of the fine grid alone, for the same final step)."""
    coarse = best_candidate(velocity_candidates(radius, symmetric, 2.0 * SEARCH_STEP), losses, make)
    ticks = np.arange(-2, 3) * SEARCH_STEP
    around = coarse + np.stack(np.meshgrid(ticks, ticks, indexing="xy"), axis=-1).reshape(-1, 2)
    return best_candidate(around, losses, make)


def best_candidate(candidates: np.ndarray, losses: Any, make: Any) -> np.ndarray:
    """The candidate whose parameters `make(candidate)` have the lowest loss; `losses` takes a list
    of parameter dicts and returns their losses (one batched call of the op per chunk)."""
    values = np.asarray(losses([make(c) for c in candidates]), dtype=np.float64)
    return np.array(candidates[int(np.nanargmin(values))], dtype=np.float64)


def _start(init: dict | None, name: str, default: Any) -> np.ndarray:
    return np.array(default if not init or name not in init else init[name], dtype=np.float64)


def known_velocity(velocity: Any, shape: tuple[int, ...], model: str) -> np.ndarray:
    """(1, 2, H, W) float64 from a (vx, vy) pair or a field, the half-spread at exposure 1."""
    if velocity is None:
        raise ValueError(f"model {model!r} fits the exposure or shutter of a known motion: pass fitting.{type_names[model]}(velocity=...) (the half-spread at exposure 1)")
    v = np.asarray(velocity.detach().cpu() if hasattr(velocity, "detach") else velocity, dtype=np.float64)
    height, width = shape[2:]
    if v.size == 2:
        return np.broadcast_to(v.reshape(1, 2, 1, 1), (1, 2, height, width)).copy()
    checks.require_image("velocity", v.shape, channels=2)
    checks.require_same_batch_and_size("sharp", shape, [("velocity", v.shape)])
    return v


def id_map(ids: Any, shape: tuple[int, ...]) -> np.ndarray:
    """A checked (1, 1, H, W) map of non-negative integer IDs."""
    ids = np.asarray(ids)
    expected = (1, 1, *shape[2:])
    if ids.shape != expected:
        raise ValueError(f"ids must have shape {expected} (one ID per pixel), got {ids.shape}")
    if not np.issubdtype(ids.dtype, np.integer) or ids.min() < 0:
        raise ValueError(f"ids must be non-negative integers, got dtype {ids.dtype} and minimum {ids.min()}")
    return ids.astype(np.int64)


def away_from_boundaries(ids: np.ndarray, distance: float) -> np.ndarray:
    """(1, 1, H, W) 1 where no pixel within `distance` (Chebyshev) has another ID, else 0."""
    weight = np.ones(ids.shape, dtype=np.float64)
    reach = int(math.ceil(distance))
    if reach == 0:
        return weight
    padded = np.pad(ids[0, 0], reach, mode="edge")
    h, w = ids.shape[2:]
    for dy in range(-reach, reach + 1):
        for dx in range(-reach, reach + 1):
            shifted = padded[reach + dy : reach + dy + h, reach + dx : reach + dx + w]
            weight[0, 0][shifted != ids[0, 0]] = 0.0
    return weight


class Global(Model):
    """One velocity (x, y) in pixels for the whole image: 2 parameters."""

    name = "global"
    learning_rate = 0.2

    def init(self, ctx, init):
        return {"velocity": nudge(_start(init, "velocity", DEFAULT_VELOCITY))}

    def velocity(self, p, ctx):
        return ctx.be.broadcast(p["velocity"].reshape(1, 2, 1, 1), (1, 2, ctx.height, ctx.width))

    def rescale(self, p, factor, height, width):
        return {"velocity": p["velocity"] * factor}

    def report(self, p, symmetric):
        v = np.asarray(p["velocity"], dtype=np.float64)
        return {"velocity": (canonical_sign(v) if symmetric else v).tolist()}

    def canonical(self, p):
        return {"velocity": canonical_sign(p["velocity"])}

    def search(self, p, loss, ctx, radius, symmetric):
        found = search_velocity(loss, lambda v: {"velocity": v}, radius, symmetric)
        return {"velocity": nudge(found)}


class Exposure(Model):
    """Known motion, unknown exposure: 1 parameter.

    velocity: the known motion, (vx, vy) or a (1, 2, H, W) field, the half-spread at exposure 1."""

    name = "exposure"
    learning_rate = 0.05

    def __init__(self, velocity: Any = None) -> None:
        self.known = velocity

    def inputs(self, shape, depth, depth_given):
        return {"velocity": known_velocity(self.known, shape, self.name)}

    def init(self, ctx, init):
        return {"exposure": _start(init, "exposure", 0.5)}

    layered = True

    def velocity(self, p, ctx):
        return ctx.extras["velocity"] * p["exposure"]

    def layer_motion(self, p, ctx):
        return ctx.extras["layers"].velocity * p["exposure"]

    def report(self, p, symmetric):
        e = float(p["exposure"])
        return {"exposure": abs(e) if symmetric else e}

    def canonical(self, p):
        return {"exposure": np.abs(p["exposure"])}

    def search(self, p, loss, ctx, radius, symmetric):
        # Exposures from 2 % to the one that moves the fastest pixel `radius` pixels, log-spaced.
        speed = float(np.max(np.hypot(*ctx.be.numpy(ctx.extras["velocity"])[0])))
        top = max(radius / max(speed, 1e-9), 0.05)
        exposures = np.geomspace(0.02, top, 48)
        if not symmetric:
            exposures = np.concatenate([-exposures[::-1], exposures])
        return {"exposure": best_candidate(exposures, loss, lambda e: {"exposure": np.array(e)}).reshape(())}


#: Shutter families with one shape parameter: (window class, field, squashing into its range).
SHUTTER_FAMILIES = {
    "linear_ramp": (LinearRamp, "slope", "tanh"),
    "tukey": (Tukey, "taper", "sigmoid"),
    "trapezoid": (Trapezoid, "ramp", "sigmoid"),
}


def _squash(kind: str, x: Any, xp: Any) -> Any:
    return xp.tanh(x) if kind == "tanh" else 1.0 / (1.0 + xp.exp(-x))


def _unsquash(kind: str, y: float) -> float:
    y = min(max(y, -0.999), 0.999) if kind == "tanh" else min(max(y, 0.001), 0.999)
    return math.atanh(y) if kind == "tanh" else math.log(y / (1.0 - y))


class Shutter(Model):
    """Known motion (`velocity`, as `Exposure`'s), unknown shutter shape: the shape parameter of
    `family` ("linear_ramp", "tukey", "trapezoid"; 1 parameter), and the exposure too with
    fit_exposure (2). The shape is held squashed into its range (tanh, sigmoid)."""

    name = "shutter"
    learning_rate = 0.1
    sign_ambiguous = False
    batched = False

    def __init__(self, velocity: Any = None, *, family: str = "linear_ramp", fit_exposure: bool = False) -> None:
        if family not in SHUTTER_FAMILIES:
            raise ValueError(f"family must be one of {', '.join(repr(f) for f in SHUTTER_FAMILIES)}; got {family!r}")
        self.known = velocity
        self.family = family
        self.fit_exposure = fit_exposure

    def static_key(self):
        return (self.family, self.fit_exposure)

    def inputs(self, shape, depth, depth_given):
        return {"velocity": known_velocity(self.known, shape, self.name)}

    def init(self, ctx, init):
        cls, field, kind = SHUTTER_FAMILIES[self.family]
        shape = float(_start(init, field, 0.25 if kind == "tanh" else 0.5))
        p = {"shape": np.array(_unsquash(kind, shape))}
        if self.fit_exposure:
            p["exposure"] = _start(init, "exposure", 0.8)
        return p

    def render(self, p, ctx):
        cls, field, kind = SHUTTER_FAMILIES[self.family]
        window = cls(**{field: _squash(kind, p["shape"], ctx.be.xp)})
        exposure = p["exposure"] if self.fit_exposure else 1.0
        return _blur(ctx, ctx.extras["velocity"] * exposure, shutter=window)

    def velocity(self, p, ctx):
        return ctx.extras["velocity"] * (p["exposure"] if self.fit_exposure else 1.0)

    def report(self, p, symmetric):
        cls, field, kind = SHUTTER_FAMILIES[self.family]
        out = {"shutter": self.family, field: float(_squash(kind, np.asarray(p["shape"]), np))}
        if self.fit_exposure:
            out["exposure"] = float(p["exposure"])
        return out


class MotionIds(Model):
    """One velocity per ID of an ID map (seed 001's vector motion IDs): 2 per ID.

    ids: (1, 1, H, W) non-negative integers. boundary: leave out of the residual the pixels within
    this many pixels of a change of ID: there objects occlude each other over the exposure, which the
    filters only approximate, and that error would bias every velocity it touches (0: keep them)."""

    name = "motion_ids"
    learning_rate = 0.2

    def __init__(self, ids: Any = None, *, boundary: float = 0) -> None:
        self.ids = ids
        self.boundary = checks.require_nonnegative_number("boundary", boundary)

    def inputs(self, shape, depth, depth_given):
        if self.ids is None:
            raise ValueError("model 'motion_ids' needs an ID map: pass fitting.MotionIds(ids=...) (a (1, 1, H, W) integer map)")
        ids = id_map(self.ids, shape)
        return {"ids": ids, "weight": away_from_boundaries(ids, self.boundary)}

    def init(self, ctx, init):
        count = ctx.extras["palette_size"]
        start = _start(init, "palette", np.tile(DEFAULT_VELOCITY, (count, 1)))
        return {"palette": np.stack([nudge(v) for v in start.reshape(count, 2)])}

    layered = True

    def velocity(self, p, ctx):
        return ctx.be.ops.velocity_from_motion_ids(ctx.extras["ids"], p["palette"][None])

    def layer_motion(self, p, ctx):
        velocities = ctx.be.stack([p["palette"][k] for k in ctx.extras["layers"].ids])
        return ctx.be.broadcast(velocities.reshape(-1, 2, 1, 1), (velocities.shape[0], 2, ctx.height, ctx.width))

    def rescale(self, p, factor, height, width):
        return {"palette": p["palette"] * factor}

    def report(self, p, symmetric):
        palette = np.asarray(p["palette"], dtype=np.float64)
        return {"palette": (canonical_sign(palette) if symmetric else palette).tolist()}

    def canonical(self, p):
        return {"palette": canonical_sign(p["palette"])}

    def search(self, p, loss, ctx, radius, symmetric):
        """Each ID's velocity on the grid in turn, the others held (starting still), twice over, the
        largest region first. A pixel's blur is even in its own velocity under a symmetric shutter,
        so each ID searches one of each pair {v, -v}."""
        palette = np.zeros_like(np.asarray(p["palette"], dtype=np.float64))
        counts = np.bincount(np.asarray(ctx.be.numpy(ctx.extras["ids"]), dtype=np.int64).ravel(), minlength=len(palette))
        for _ in range(2):
            for k in np.argsort(-counts[: len(palette)], kind="stable"):

                def at(v, k=k):
                    trial = palette.copy()
                    trial[k] = v
                    return {"palette": trial}

                palette[k] = search_velocity(loss, at, radius, symmetric)
        return {"palette": np.stack([nudge(v) for v in palette])}



#: `depth_layers`: a jump in depth of more than 10 % starts a new layer (a ratio, so any depth unit
#: gives the same layers); at most 4 layers; a layer holds at least 0.5 % of the pixels.
LAYER_DEPTH_RATIO = 1.1
MAX_LAYERS = 4
MIN_LAYER_FRACTION = 0.005


def depth_layers(depth: np.ndarray, *, max_layers: int = MAX_LAYERS, ratio: float = LAYER_DEPTH_RATIO, min_fraction: float = MIN_LAYER_FRACTION) -> tuple[np.ndarray, np.ndarray]:
    """Cluster a (1, 1, H, W) positive depth buffer into layers by its gaps: sorted log depths split
    where consecutive values differ by more than log(ratio), at the `max_layers - 1` largest such
    gaps; a layer with fewer than `min_fraction` of the pixels joins its nearest neighbour in depth.
    Scale-free: depth times any constant gives the same layers. A surface tilted to the view (depth
    varying smoothly) stays one layer.

    Returns (ids, depths): (1, 1, H, W) int64 labels, 0 the nearest layer, and each layer's median depth.
    """
    z = np.log(np.asarray(depth, dtype=np.float64))
    values = np.sort(z.ravel())
    gaps = np.diff(values)
    at = np.nonzero(gaps > math.log(ratio))[0]
    at = np.sort(at[np.argsort(-gaps[at], kind="stable")[: max_layers - 1]])
    edges = [(values[i] + values[i + 1]) / 2 for i in at]
    ids = np.digitize(z, edges).astype(np.int64)
    # Merge layers that are too small into their nearest neighbour in depth.
    while True:
        counts = np.bincount(ids.ravel(), minlength=len(edges) + 1)
        small = [k for k in range(len(counts)) if counts[k] < min_fraction * ids.size]
        if not small or len(counts) == 1:
            break
        k = small[0]
        medians = [np.median(z[ids == j]) if counts[j] else np.inf for j in range(len(counts))]
        others = [j for j in range(len(counts)) if j != k and counts[j]]
        into = min(others, key=lambda j: abs(medians[j] - medians[k])) if counts[k] else others[0]
        ids[ids == k] = into
        ids = np.unique(ids, return_inverse=True)[1].reshape(ids.shape).astype(np.int64)
        edges = edges[: ids.max()]
    depths = np.array([float(np.exp(np.median(z[ids == k]))) for k in range(int(ids.max()) + 1)])
    return ids, depths


class Layers(MotionIds):
    """A velocity per depth layer (2 per layer). An object over a still background, two objects
    crossing, a background panning behind a foreground: each layer moves on its own.

    The layers are the depth buffer's clusters (`depth_layers` with `max_layers` and `ratio`), or
    the given `ids`; `boundary` as `MotionIds`'. params: "palette" (a velocity per layer, the
    nearest first) and "depths" (each layer's median depth)."""

    name = "layers"

    def __init__(self, ids: Any = None, *, boundary: float = 0, max_layers: int = MAX_LAYERS, ratio: float = LAYER_DEPTH_RATIO) -> None:
        super().__init__(ids, boundary=boundary)
        self.max_layers = checks.require_positive_int("max_layers", max_layers)
        if not ratio > 1:
            raise ValueError(f"ratio must be a depth ratio > 1, got {ratio}")
        self.ratio = float(ratio)
        self.depths: tuple[float, ...] = ()

    def inputs(self, shape, depth, depth_given):
        if self.ids is None:
            if not depth_given:
                raise ValueError("model 'layers' needs depth= (its layers are the depth buffer's clusters) or fitting.Layers(ids=...)")
            ids, depths = depth_layers(depth, max_layers=self.max_layers, ratio=self.ratio)
        else:
            ids = id_map(self.ids, shape)
            depths = [float(np.median(depth[ids == k])) if np.any(ids == k) else float("nan") for k in range(int(ids.max()) + 1)]
        self.depths = tuple(float(d) for d in depths)
        return {"ids": ids, "weight": away_from_boundaries(ids, self.boundary)}

    def report(self, p, symmetric):
        out = super().report(p, symmetric)
        out["depths"] = [float(d) for d in self.depths]
        return out

def _centred_grid(ctx: Context) -> tuple[Any, Any]:
    """(1, 1, h, w) x - cx and y - cy about the image centre."""
    x = np.arange(ctx.width) - (ctx.width - 1) / 2.0
    y = np.arange(ctx.height) - (ctx.height - 1) / 2.0
    return ctx.be.array(np.broadcast_to(x, (1, 1, ctx.height, ctx.width))), ctx.be.array(np.broadcast_to(y[:, None], (1, 1, ctx.height, ctx.width)))


class CameraMotion(Model):
    """Pan, zoom (a dolly) and roll of the camera, 4 parameters, as a velocity field with parallax:

        v(X) = pan / Z + advance (X - c) / Z + sin(roll) (-(y - cy), x - cx)

    with Z the depth (1 without depth), c the image centre. pan is in pixels x depth units (a point at
    depth Z moves pan / Z pixels, as `diffblur.scenes.Camera`'s pan), advance in depth units (the
    dolly's first-order image motion), roll in radians at t = 1.
    """

    name = "camera"
    learning_rate = 0.1

    def init(self, ctx, init):
        z = float(np.median(ctx.extras["depth_numpy"]))
        return {
            "pan": nudge(_start(init, "pan", np.array(DEFAULT_VELOCITY) * z) / z) * z,
            "advance": _start(init, "advance", 0.0),
            "roll": _start(init, "roll", 0.0),
        }

    def velocity(self, p, ctx):
        x, y = _centred_grid(ctx)
        inverse_depth = 1.0 / ctx.depth
        s = ctx.be.xp.sin(p["roll"])
        u = p["pan"][0] * inverse_depth + p["advance"] * x * inverse_depth - s * y
        v = p["pan"][1] * inverse_depth + p["advance"] * y * inverse_depth + s * x
        return ctx.be.concat([u, v], axis=1)

    def rescale(self, p, factor, height, width):
        return {"pan": p["pan"] * factor, "advance": np.array(p["advance"]), "roll": np.array(p["roll"])}

    def report(self, p, symmetric):
        p = self.canonical(p) if symmetric else p
        return {"pan": np.asarray(p["pan"]).tolist(), "advance": float(p["advance"]), "roll": float(p["roll"])}

    def canonical(self, p):
        pan = np.asarray(p["pan"], dtype=np.float64)
        flip = pan[0] < 0 or (pan[0] == 0 and pan[1] < 0) or (not np.any(pan) and float(p["advance"]) < 0)
        sign = -1.0 if flip else 1.0
        return {"pan": sign * pan, "advance": np.array(sign * float(p["advance"])), "roll": np.array(sign * float(p["roll"]))}

    def search(self, p, loss, ctx, radius, symmetric):
        """The pan on the velocity grid (at the median depth), then the advance (a zoom moving the
        image's corners up to `radius` pixels, either way), then the roll likewise."""
        depth = ctx.extras["depth_numpy"]
        z = float(np.median(depth))
        reach = math.hypot(ctx.width, ctx.height) / 2.0
        zero = np.array(0.0)
        pan = best_candidate(velocity_candidates(radius, symmetric) * z, loss, lambda v: {"pan": v, "advance": zero, "roll": zero})
        ticks = np.linspace(-1.0, 1.0, 33)
        advance = best_candidate(ticks * radius * float(np.min(depth)) / reach, loss, lambda a: {"pan": pan, "advance": np.array(a), "roll": zero})
        roll = best_candidate(ticks * min(radius / reach, 1.0), loss, lambda r: {"pan": pan, "advance": np.array(advance), "roll": np.array(r)})
        if not np.any(pan) and not advance and not roll:
            pan = nudge(pan / z) * z
        return {"pan": pan, "advance": np.array(float(advance)), "roll": np.array(float(roll))}


class Rotation(Model):
    """A centre (x, y) and an angle (radians at t = 1): curved motion through the arc scatter, 3
    parameters.

    mask: (1, 1, H, W) the pixels that turn (default: those nearer than the farthest depth; all where
    that leaves none). background: (1, C, H, W) the still background, for the scatter's two-layer
    normalisation."""

    name = "rotation"
    learning_rate = 0.05
    batched = False

    def __init__(self, *, mask: Any = None, background: Any = None) -> None:
        self.mask = mask
        self.background = background

    def inputs(self, shape, depth, depth_given):
        if self.mask is None:
            mask = (depth < depth.max() - 1e-9 * depth.max()).astype(np.float64)
        else:
            mask = np.asarray(self.mask, dtype=np.float64)
            checks.require_same_shape("mask", mask.shape, "depth", depth.shape)
        if not mask.any():
            mask = np.ones_like(depth)
        out = {"mask": mask}
        if self.background is not None:
            background = np.asarray(self.background, dtype=np.float64)
            checks.require_same_shape("background", background.shape, "sharp", tuple(shape))
            out["background"] = background
        return out

    def init(self, ctx, init):
        mask = ctx.extras["mask_numpy"][0, 0]
        ys, xs = np.nonzero(mask > 0.5)
        centroid = (xs.mean(), ys.mean()) if len(xs) else ((ctx.width - 1) / 2, (ctx.height - 1) / 2)
        angle = float(_start(init, "angle", 0.1))
        if abs(angle) < 1e-3:  # the arc's blur is even in the angle under a symmetric shutter
            angle = 1e-3
        return {"center": _start(init, "center", centroid), "angle": np.array(angle)}

    def velocity(self, p, ctx):
        """The arc's half-spread sin(angle) R90 (X - centre), for pictures."""
        x = ctx.be.array(np.broadcast_to(np.arange(ctx.width, dtype=np.float64), (1, 1, ctx.height, ctx.width))) - p["center"][0]
        y = ctx.be.array(np.broadcast_to(np.arange(ctx.height, dtype=np.float64)[:, None], (1, 1, ctx.height, ctx.width))) - p["center"][1]
        s = ctx.be.xp.sin(p["angle"]) * ctx.extras["mask"]
        return ctx.be.concat([-s * y, s * x], axis=1)

    def render(self, p, ctx):
        o = ctx.options
        center = ctx.be.broadcast(p["center"].reshape(1, 2, 1, 1), (1, 2, ctx.height, ctx.width))
        kwargs = {} if ctx.extras.get("background") is None else {"fill": ctx.extras["background"]}
        # JAX's fused scatter has reverse-mode gradients only; LM and Dogleg take forward-mode Jacobians.
        if ctx.be.name == "jax" and o.get("jac", "fwd") == "fwd":
            kwargs["impl"] = "tensor"
        return ctx.be.ops.bezier_scatter(
            ctx.color, ctx.depth, None, None, arc_center=center, arc_angle=p["angle"] * ctx.extras["mask"], samples=o["arc_samples"], shutter=shutter_of(ctx, o["arc_samples"]), composite=COMPOSITE, **kwargs
        )

    def rescale(self, p, factor, height, width):
        # Pixel centres at integers: a coarse pixel i covers fine pixels 2i and 2i + 1, centre 2i + 1/2.
        return {"center": p["center"] * factor + (factor - 1.0) / 2.0, "angle": np.array(p["angle"])}

    def report(self, p, symmetric):
        angle = float(p["angle"])
        return {"center": np.asarray(p["center"]).tolist(), "angle": abs(angle) if symmetric else angle}

    def canonical(self, p):
        return {"center": p["center"], "angle": np.abs(p["angle"])}

    def search(self, p, loss, ctx, radius, symmetric):
        """The angle (about the mask's centroid) at which the turning pixels' rim moves 1/48 to
        all of `radius` pixels, log-spaced, both ways unless the shutter is symmetric."""
        mask = ctx.extras["mask_numpy"][0, 0] > 0.5
        ys, xs = np.nonzero(mask)
        if not len(xs):
            return p
        rim = max(float(np.max(np.hypot(xs - p["center"][0], ys - p["center"][1]))), 1.0)
        angles = np.geomspace(radius / rim / 48.0, min(radius / rim, 1.5), 48)
        if not symmetric:
            angles = np.concatenate([-angles[::-1], angles])
        return {"center": p["center"], "angle": best_candidate(angles, loss, lambda a: {"center": p["center"], "angle": np.array(a)}).reshape(())}


class Tiles(Model):
    """A coarse grid of velocities (`grid=(rows, columns)`, 2 per node), upsampled bilinearly
    (nodes at the image's corners and evenly between)."""

    name = "tiles"
    learning_rate = 0.2

    def __init__(self, grid: tuple[int, int] = (3, 3)) -> None:
        if len(tuple(grid)) != 2 or min(int(g) for g in grid) < 1:
            raise ValueError(f"grid must be (rows, columns) of at least 1 node each, got {grid!r}")
        self.grid = (int(grid[0]), int(grid[1]))

    def static_key(self):
        return self.grid

    def init(self, ctx, init):
        start = _start(init, "tiles", np.broadcast_to(np.reshape(DEFAULT_VELOCITY, (2, 1, 1)), (2, *self.grid)))
        return {"tiles": start.reshape(2, *self.grid)}

    def velocity(self, p, ctx):
        rows = ctx.be.array(interpolation_matrix(ctx.height, self.grid[0]))
        cols = ctx.be.array(interpolation_matrix(ctx.width, self.grid[1]))
        return ctx.be.einsum("yi,cij,xj->cyx", rows, p["tiles"], cols)[None]

    def rescale(self, p, factor, height, width):
        return {"tiles": p["tiles"] * factor}

    def report(self, p, symmetric):
        return {"tiles": np.asarray(p["tiles"]).tolist()}


class Dense(Model):
    """A velocity per pixel (2 h w parameters) with a smoothness prior: tv_weight times the mean of
    sqrt(d^2 + eps) over the field's horizontal and vertical differences (total variation,
    Charbonnier-smoothed so it is differentiable at 0)."""

    name = "dense"
    learning_rate = 0.1
    TV_EPS = 1e-3

    def __init__(self, tv_weight: float = 1e-3) -> None:
        self.tv_weight = checks.require_nonnegative_number("tv_weight", tv_weight)

    def static_key(self):
        return (self.tv_weight,)

    def init(self, ctx, init):
        if init and "velocity" in init:
            field = np.asarray(init["velocity"], dtype=np.float64)
            if field.shape not in ((2, ctx.height, ctx.width), (1, 2, ctx.height, ctx.width)):
                raise ValueError(f"init['velocity'] of model 'dense' must be a (1, 2, H, W) field of the image's size, (1, 2, {ctx.height}, {ctx.width}), got shape {field.shape}")
            field = field.reshape(2, ctx.height, ctx.width)
        else:
            field = np.broadcast_to(np.reshape(DEFAULT_VELOCITY, (2, 1, 1)), (2, ctx.height, ctx.width)).copy()
        return {"velocity": field}

    def velocity(self, p, ctx):
        return p["velocity"][None]

    def prior(self, p, ctx):
        v = p["velocity"]
        dx = (v[:, :, 1:] - v[:, :, :-1]).reshape(-1)
        dy = (v[:, 1:, :] - v[:, :-1, :]).reshape(-1)
        count = dx.shape[0] + dy.shape[0]
        # Residuals r with sum r^2 = tv_weight * mean(sqrt(d^2 + eps)).
        weight = math.sqrt(self.tv_weight / count)
        return [weight * (d * d + self.TV_EPS) ** 0.25 for d in (dx, dy)]

    def rescale(self, p, factor, height, width):
        v = np.asarray(p["velocity"])
        rows = interpolation_matrix(height, v.shape[1])
        cols = interpolation_matrix(width, v.shape[2])
        return {"velocity": np.einsum("yi,cij,xj->cyx", rows, v, cols) * factor}

    def report(self, p, symmetric):
        v = np.asarray(p["velocity"])
        return {"velocity_mean": v.reshape(2, -1).mean(axis=1).tolist(), "velocity_shape": list(v.shape)}


#: The model classes by name; a name is the shortcut for the class with its defaults.
MODEL_TYPES: dict[str, type[Model]] = {"global": Global, "exposure": Exposure, "shutter": Shutter, "motion_ids": MotionIds, "layers": Layers, "camera": CameraMotion, "rotation": Rotation, "tiles": Tiles, "dense": Dense}
MODELS: tuple[str, ...] = tuple(MODEL_TYPES)
type_names = {name: cls.__name__ for name, cls in MODEL_TYPES.items()}


def as_model(model: str | Model) -> Model:
    """A fresh model to fit: a name's defaults, or a copy of a model object (recover keeps per-fit
    state on it, such as the layers' depths, and the caller's object must not change)."""
    if isinstance(model, Model):
        return copy.copy(model)
    if isinstance(model, str) and model in MODEL_TYPES:
        return MODEL_TYPES[model]()
    raise ValueError(f"model must be one of {', '.join(repr(m) for m in MODEL_TYPES)} or a fitting model object (fitting.Exposure(velocity=...), ...), got {model!r}")
