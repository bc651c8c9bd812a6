"""`recover`: fit a motion model to a blurred target, in PyTorch or JAX, coarse to fine."""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from diffblur import checks
from diffblur.shutters import get_shutter
from fitting import _backends, _models, _pyramid, _solvers

METHODS = ("reconstruct", "gather", "scatter")
#: Each model's default op (`method=None`), from the held-out evaluation (BENCHMARKS.md, "Held-out
#: recovery"). The scatter for one velocity, layers, motion IDs and a known motion: it spreads a
#: moving point over every pixel it passes (see `_models.covered`), where the gather reads along each
#: pixel's own velocity only; on the held-out pans the global velocity comes out 0.002 px off (median)
#: through it, 0.12 through the gather, 0.38 through seed 000's filter, which samples along each tile
#: neighbourhood's largest velocity. The gather for fields that vary from pixel to pixel (camera,
#: tiles, dense): on held-out zoom-03 with the true velocity the filter is 24 dB from the truth, the
#: gather 29, the scatter 31, and a held-out zoom fit takes 0.3 s through the gather, 3.5 through the
#: scatter (PyTorch). `rotation` always goes through the arc
#: scatter.
DEFAULT_METHODS = {"global": "scatter", "exposure": "scatter", "shutter": "reconstruct", "motion_ids": "scatter", "layers": "scatter", "camera": "gather", "rotation": "scatter", "tiles": "gather", "dense": "gather"}
#: Through the scatter, an ID slower than this (pixels) is also tried exactly still (see `recover`).
STILL_SPEED = 0.25
#: The coarse search tries speeds up to this many pixels (full resolution) by default.
SEARCH_RADIUS = 16.0
#: A fit that explains less than this fraction of the blur (`FitResult.explained`) warns.
EXPLAINED_WARNING = 0.5
#: A fit through a method other than the model's default scatter is refitted through the scatter
#: from its answer; a velocity field that moves more than this (pixels, at any pixel) there means the
#: method's own error biased the fit: not converged, with a warning. It is the 90th-percentile
#: target for a global velocity.
METHOD_SHIFT_WARNING = 0.25


@dataclass
class FitResult:
    """What `recover` found.

    params: the model's parameters as plain numbers and lists (e.g. {"velocity": [vx, vy]} for
    `global`; velocities up to sign, in canonical sign, when the shutter is symmetric). loss: the final
    mean squared residual (plus prior) on the cropped finest level. blurred: (1, C, H, W) the target
    re-blurred with the fitted parameters. history: the loss at every solver step, all levels in
    order. velocity: (1, 2, H, W) the fitted velocity field (pixels), in the sign `params` reports.
    converged: the solver's own stopping criterion was met at the finest level, and the method did
    not bias the fit (see method_shift; message: why not). explained: 1 - loss / (the loss of the unblurred sharp frame on the same pixels): 1 for
    a perfect fit, 0 for one no better than no blur. method_shift: for a fit through reconstruct or
    the gather where the model's default is the scatter, how far (pixels, the largest over the
    compared pixels) the velocity field moves when the scatter refits from this answer; past
    METHOD_SHIFT_WARNING the fit is reported not converged (NaN when not checked, as for a fit that
    did not converge anyway). ids: the ID map the palette refers to (`layers`, `motion_ids`).
    n_params, seconds, the rest as named.
    """

    model: str
    backend: str
    solver: str
    params: dict[str, Any]
    loss: float
    blurred: np.ndarray
    history: list[float]
    velocity: np.ndarray
    n_params: int
    levels: int
    seconds: float
    raw: dict[str, np.ndarray] = field(repr=False, default_factory=dict)
    pixels: int = 0
    converged: bool = False
    explained: float = float("nan")
    message: str = ""
    method: str = ""
    method_shift: float = float("nan")
    ids: np.ndarray | None = field(repr=False, default=None)


def _as_image(name: str, x: Any, channels: int | None = None) -> np.ndarray:
    x = np.asarray(x.detach().cpu() if hasattr(x, "detach") else x, dtype=np.float64)
    checks.require_image(name, x.shape, channels=channels)
    if x.shape[0] != 1:
        raise ValueError(f"{name} must hold one image (batch 1), got shape {x.shape}")
    return x


def _flatten(p: dict[str, np.ndarray]) -> tuple[np.ndarray, tuple[tuple[str, tuple[int, ...]], ...]]:
    spec = tuple((k, tuple(np.shape(v))) for k, v in p.items())
    return np.concatenate([np.ravel(v) for v in p.values()]).astype(np.float64), spec


def _unflatten(y: Any, spec: tuple[tuple[str, tuple[int, ...]], ...]) -> dict[str, Any]:
    out, start = {}, 0
    for name, shape in spec:
        size = int(np.prod(shape)) if shape else 1
        out[name] = y[start : start + size].reshape(shape)
        start += size
    return out


def _auto_max_radius(speed: float, samples: int, size: int) -> float:
    """reconstruct's tile radius for a level: room for the start's speed to double (a pixel gathers
    only from neighbouring tiles, so a radius below the fitted speed would cut the blur off), at
    least 4 px, at most half the image."""
    return float(min(max(4.0, math.ceil(2.0 * speed * (samples + 1) / samples) + 2.0), max(2.0, size / 2)))


def _scatter_points(speed: float) -> int:
    """The scatter's points per path for a level: one per half pixel of a path twice the start's
    length (room for the speed to double), rounded up to a multiple of 8 (so that fits of one size
    share their compiled functions in JAX), 8 to 48. Half as many moved the exposure of development
    scenes with a non-box shutter by up to 0.7 % (its median over the family from 1.2 to 1.4 %)."""
    return int(min(48, 8 * math.ceil(max(8, math.ceil(8.0 * speed) + 1) / 8)))


class Traced:
    """A model as static data of the compiled level functions (`_backends.JaxAdapter.run`): equal
    when their class and `static_key()` are, which is all that `render`, `velocity`, `motion` and
    `prior` read besides the level's context."""

    def __init__(self, model: _models.Model) -> None:
        self.model = model
        self.key = (type(model), model.static_key())

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Traced) and other.key == self.key

    def __hash__(self) -> int:
        return hash(self.key)


# The level's functions, module-level so that JAX compiles each once per static part and shapes.


def _level_residuals(y: Any, ctx: _models.Context, traced: Traced, spec: tuple, crop: int, count: float) -> Any:
    """The level's residual vector at flat parameters y: the weighted, cropped data residual over
    sqrt(count), then the model's prior."""
    p = _unflatten(y, spec)
    data = ((traced.model.render(p, ctx) - ctx.target) * ctx.extras["weight"])[:, :, crop : ctx.height - crop, crop : ctx.width - crop].reshape(-1) / math.sqrt(count)
    return ctx.be.concat([data, *traced.model.prior(p, ctx)])


def _level_loss(y: Any, ctx: _models.Context, traced: Traced, spec: tuple, crop: int, count: float) -> Any:
    r = _level_residuals(y, ctx, traced, spec, crop, count)
    return (r * r).sum()


def _velocity(p: dict, ctx: _models.Context, traced: Traced) -> Any:
    return traced.model.velocity(p, ctx)


def _motion(p: dict, ctx: _models.Context, traced: Traced) -> Any:
    return traced.model.motion(p, ctx)


def _render(p: dict, ctx: _models.Context, traced: Traced) -> Any:
    return traced.model.render(p, ctx)


def _candidate_errors(stacked: dict, ctx: _models.Context, traced: Traced, crop: int) -> Any:
    """(n,) mean squared weighted, cropped data residual of each candidate (`stacked`: each
    parameter's n values along a first axis)."""
    fit_model, be = traced.model, ctx.be
    if fit_model.batched:
        rendered = _models.render_batch(ctx, be.per_candidate(_motion)(stacked, ctx, traced))
    else:
        rendered = be.per_candidate(_render)(stacked, ctx, traced)
    error = ((rendered - ctx.target) * ctx.extras["weight"])[:, :, crop : ctx.height - crop, crop : ctx.width - crop]
    return (error * error).reshape(error.shape[0], -1).mean(1)


def auto_levels(height: int, width: int, search_radius: float) -> int:
    """Pyramid levels for an image and a search: halve until the search's largest speed is at most
    4 px or the image's short side would drop below 24 px, whichever comes first."""
    by_size = int(math.floor(math.log2(max(min(height, width) / 24.0, 1.0))))
    by_speed = int(math.ceil(math.log2(max(search_radius / 4.0, 1.0))))
    return 1 + max(0, min(by_size, by_speed))


def _parameter_scale(fit_model: _models.Model, params: dict[str, np.ndarray], ctx: _models.Context) -> np.ndarray:
    """Per flat parameter, the RMS pixels of motion one unit of it makes (central differences of the
    model's velocity field), so the solver steps every parameter in comparable units; 1 where a
    parameter moves nothing (a shutter's shape) and for fields of more than 64 parameters."""
    y, spec = _flatten(params)
    if y.size > 64:
        return np.ones_like(y)
    be = ctx.be
    scale = np.ones_like(y)
    for i in range(y.size):
        h = 1e-4 * max(1.0, abs(y[i]))
        fields = []
        for sign in (1.0, -1.0):
            trial = y.copy()
            trial[i] += sign * h
            fields.append(be.numpy(be.run(_velocity, {k: be.array(v) for k, v in _unflatten(trial, spec).items()}, ctx, Traced(fit_model))))
        rms = float(np.sqrt(np.mean(((fields[0] - fields[1]) / (2 * h)) ** 2)))
        if rms > 1e-3:
            scale[i] = rms
    return scale


#: Candidates rendered per batched call of the op in the coarse search.
SEARCH_BATCH = 64


def _losses(fit_model: _models.Model, ctx: _models.Context, candidates: list[dict[str, np.ndarray]], margin: int) -> np.ndarray:
    """The data loss of each candidate's parameters on a level (the solver's, without the prior),
    rendered SEARCH_BATCH at a time where the model allows it."""
    be = ctx.be
    crop = int(round(margin * ctx.scale))
    out = []
    for start in range(0, len(candidates), SEARCH_BATCH):
        chunk = candidates[start : start + SEARCH_BATCH]
        # Every chunk as long as the first (the last one padded with its own last candidate), so that
        # JAX compiles the search once.
        size = min(len(candidates), SEARCH_BATCH)
        padded = chunk + [chunk[-1]] * (size - len(chunk))
        stacked = {k: be.array(np.stack([np.asarray(c[k], dtype=np.float64) for c in padded])) for k in chunk[0]}
        out.append(be.numpy(be.run(_candidate_errors, stacked, ctx, Traced(fit_model), crop))[: len(chunk)])
    return np.concatenate(out)


def recover(
    sharp: Any,
    target: Any,
    *,
    model: str | _models.Model,
    depth: Any = None,
    backend: str = "torch",
    method: str | None = None,
    solver: str | None = None,
    iterations: int | None = None,
    levels: int | None = None,
    init: dict[str, Any] | None = None,
    search: bool = True,
    search_radius: float = SEARCH_RADIUS,
    shutter: Any = "box",
    samples: int = 9,
    arc_samples: int = 16,
    max_radius: float | None = None,
    margin: int | None = None,
    weight: Any = None,
    learning_rate: float | None = None,
    jac: str = "fwd",
    dtype: str = "float64",
    on_step: Callable[[int, float], None] | None = None,
    warn: bool = True,
    check_method: bool = True,
) -> FitResult:
    """Recover a motion model's parameters from a sharp frame and a blurred target.

    Args:
        sharp, target: (1, C, H, W) linear images (NumPy, or any array NumPy can read).
        model: a model object carrying its own options (`fitting.Global()`, `Exposure(velocity=...)`,
            `Shutter(velocity=..., family=...)`, `MotionIds(ids=..., boundary=...)`, `Layers(...)`,
            `CameraMotion()`, `Rotation(mask=..., background=...)`, `Tiles(grid=...)`,
            `Dense(tv_weight=...)`), or one of `fitting.MODELS` as a shortcut for its defaults
            ("global", "layers", "camera", "rotation", "tiles", "dense"; the others need data).
        depth: (1, 1, H, W) positive depth (reconstruct's depth test, the camera's parallax, the
            scatter's depth test, the layers of `layers`); None for a flat scene (depth 1).
        backend: "torch" or "jax".
        method: the op the blur goes through: "reconstruct" (seed 000), "gather" (seed 001) or
            "scatter" (seed 003's scatter of linear motion, offsets -V and +V, with the push-pull
            fill); None takes the model's default (`DEFAULT_METHODS`). `rotation` always uses the
            arc scatter. Seed 000's taps span S / (S + 1) of the exposure, so the reconstruct path
            scales the velocity by (S + 1) / S: the parameters are the scene's, not the filter's.
        solver: "lbfgs" (the default in both frameworks: SciPy's L-BFGS-B on the framework's exact
            gradient, one loop for both, so they reach the same minimum), torch "adam", JAX "lm"
            (Levenberg-Marquardt; matrix-free CG for `dense`), "dogleg", "bfgs" or "adam" (optimistix).
        iterations: solver steps per level (default: 200 for lbfgs, 60 for Adam, 20 otherwise).
        levels: pyramid levels for coarse-to-fine (1 = single scale; None: `auto_levels`, from the
            image size and `search_radius`); each level halves the size, the fit at a coarse level
            starts the next finer one.
        init: starting values by parameter name, full resolution ({"velocity": (vx, vy)} ...); given,
            it replaces the coarse search. A velocity start at 0 is moved to 0.1 px: v = 0 is a
            stationary point of a symmetric shutter.
        search: without `init`, search the coarsest level on a grid of candidates (velocities up to
            `search_radius` pixels at full resolution; exposures, angles and zooms that move pixels as
            far) before the local solver, so a fit converges from no start for blurs that large.
        shutter: the window the blur assumes (name or `diffblur.shutters` window); with a symmetric
            one the velocity is reported up to sign (canonical sign: x > 0), an asymmetric one
            (LinearRamp) resolves it.
        samples: taps of reconstruct/gather (odd); arc_samples: points per arc of the scatter.
        max_radius: reconstruct's tile radius; None sets it per level from the starting velocity.
        margin: border pixels (full resolution) left out of the residual, where the target saw
            outside the image; default max(2, min(H, W) // 10).
        weight: (1, 1, H, W) a weight on every pixel's residual (0 leaves it out), on top of the
            model's own (`MotionIds`' boundary band); `select_model` gives every candidate the same.
        learning_rate: Adam's (default per model). jac: "fwd" or "bwd" Jacobians for LM and Dogleg
            ("bwd" for ops with a custom_vjp). dtype: "float64" or "float32".
        on_step: called as on_step(step, loss) after every solver step (e.g. a progress bar).
        warn: a `UserWarning` naming the model when the fit did not converge or explains less than
            EXPLAINED_WARNING (half) of the blur.
        check_method: when `method` is reconstruct or the gather and the model's default is the
            scatter, refit a converged answer through the scatter (finest level, no search) and
            report the move as `FitResult.method_shift`; past METHOD_SHIFT_WARNING the method's own
            error has biased the fit, which then counts as not converged.

    Returns:
        A `FitResult`.
    """
    start_time = time.perf_counter()
    checks.require_choice("backend", backend, _backends.BACKENDS)
    method = DEFAULT_METHODS[_models.as_model(model).name] if method is None else method
    checks.require_choice("method", method, METHODS)
    checks.require_choice("dtype", dtype, ("float64", "float32"))
    checks.require_choice("jac", jac, ("fwd", "bwd"))
    solver = _solvers.default_solver(backend, _models.as_model(model).name) if solver is None else solver
    checks.require_choice("solver", solver, _solvers.TORCH_SOLVERS if backend == "torch" else _solvers.JAX_SOLVERS)
    samples = checks.require_odd_int("samples", samples)
    arc_samples = checks.require_positive_int("arc_samples", arc_samples)
    default_iterations = {"lbfgs": 200, "adam": 60}.get(solver, 20)
    iterations = default_iterations if iterations is None else checks.require_positive_int("iterations", iterations)
    search_radius = checks.require_positive_number("search_radius", search_radius)
    window = get_shutter(shutter)

    color = _as_image("sharp", sharp)
    goal = _as_image("target", target)
    checks.require_same_shape("target", goal.shape, "sharp", color.shape)
    _, _, height, width = color.shape
    levels = min(auto_levels(height, width, search_radius), _pyramid.max_levels(height, width)) if levels is None else checks.require_positive_int("levels", levels)
    if levels > _pyramid.max_levels(height, width):
        raise ValueError(f"levels must be <= {_pyramid.max_levels(height, width)} for a {height} x {width} image (coarsest level >= 8 pixels), got {levels}")
    z = np.ones((1, 1, height, width)) if depth is None else _as_image("depth", depth, channels=1)
    checks.require_same_batch_and_size("sharp", color.shape, [("depth", z.shape)])
    if not np.all(z > 0):
        raise ValueError(checks.nonpositive_message("depth"))
    margin = max(2, min(height, width) // 10) if margin is None else int(checks.require_nonnegative_number("margin", margin))
    if 2 * margin >= min(height, width):
        raise ValueError(f"margin must leave pixels to compare: < {min(height, width) // 2} for a {height} x {width} image, got {margin}")

    fit_model = _models.as_model(model)
    model = fit_model.name
    if weight is None:
        shared_weight = np.ones_like(z)
    else:
        shared_weight = np.asarray(weight, dtype=np.float64)
        checks.require_same_shape("weight", shared_weight.shape, "depth", z.shape)
    arrays: dict[str, np.ndarray | None] = {"color": color, "target": goal, "depth": z, "velocity": None, "ids": None, "mask": None, "background": None, "weight": shared_weight}
    own = fit_model.inputs(color.shape, z, depth is not None)
    arrays["weight"] = shared_weight * own.pop("weight", 1.0)
    arrays.update(own)

    # The scatter composites depth layers (`_models.layered_scatter`) for the models with a velocity
    # per layer: the model's IDs, or the depth buffer's layers for a known field.
    layered = method == "scatter" and fit_model.layered and depth is not None
    if layered:
        arrays["layer_ids"] = arrays["ids"] if arrays["ids"] is not None else _models.depth_layers(z)[0]
    be = _backends.adapter(backend, dtype)
    pyramid = _pyramid.pyramid(arrays, levels)
    stacks: dict[int, Any] = {}

    def layers_of(level: int) -> Any:
        """The level's `_models.LayerStack` (None unless the scatter composites layers), built once."""
        if level not in stacks:
            a = pyramid[level]
            stacks[level] = _models.layer_stack(be, a["color"], a["depth"], a["layer_ids"], a["velocity"]) if layered else None
        return stacks[level]
    palette_size = int(arrays["ids"].max()) + 1 if arrays["ids"] is not None else 0
    # The JAX ops' custom_vjp rules (the fused kernels) have reverse-mode gradients only: forward-mode
    # Jacobians (jac="fwd") are for the least-squares solvers alone.
    jac = jac if solver in _solvers.LEAST_SQUARES else "bwd"

    def context(level: int, speed: float) -> _models.Context:
        a = pyramid[level]
        h, w = a["color"].shape[2:]
        extras = {"palette_size": palette_size, "depth_numpy": a["depth"], "mask_numpy": a["mask"]}
        for name in ("velocity", "mask", "background", "weight"):
            extras[name] = None if a[name] is None else be.array(a[name])
        extras["ids"] = None if a["ids"] is None else be.ints(a["ids"])
        extras["layers"] = layers_of(level)
        # Only what the method reads: the options are static data of JAX's compiled functions.
        radius = (max_radius if max_radius is not None else _auto_max_radius(speed, samples, max(h, w))) if method == "reconstruct" else None
        points = _scatter_points(speed) if method == "scatter" else None
        # The scatter and the gather take the shutter as a table of data (`_models.TabulatedWindow`,
        # exact at their points), so that JAX compiles one loss for every shutter; reconstruct's
        # jittered taps read the window anywhere.
        counts = {"scatter": [points], "gather": [samples]}.get(method, []) + ([arc_samples] if model == "rotation" else [])
        extras["shutter_tables"] = _models.shutter_tables(be, window, counts)
        options = {"method": method, "samples": samples, "arc_samples": arc_samples, "shutter": window if method == "reconstruct" else None, "max_radius": radius, "jac": jac, "scatter_samples": points}
        return _models.Context(be, be.array(a["color"]), be.array(a["depth"]), be.array(a["target"]), h, w, 0.5**level, options, extras)

    traced = Traced(fit_model)

    def as_arrays(params: dict[str, np.ndarray]) -> dict[str, Any]:
        return {k: be.array(v) for k, v in params.items()}

    def speed_of(params: dict[str, np.ndarray], level: int) -> float:
        probe = context(level, 1.0)
        return float(np.max(np.hypot(*be.numpy(be.run(_velocity, as_arrays(params), probe, traced))[0])))

    def objective(ctx: _models.Context, spec: tuple) -> tuple[Callable, tuple]:
        """The level's residual vector as a function of the flat parameters, and the arguments that
        `_level_residuals` and `_level_loss` take after them."""
        crop = int(round(margin * ctx.scale))
        count = float(goal.shape[1] * (ctx.height - 2 * crop) * (ctx.width - 2 * crop))
        arguments = (ctx, traced, spec, crop, count)
        return (lambda y: _level_residuals(y, *arguments)), arguments

    # Start values at full resolution, then down to the coarsest level.
    finest = context(0, 2.0)
    params = fit_model.init(finest, init)
    for level in range(1, levels):
        h, w = pyramid[level]["color"].shape[2:]
        params = fit_model.rescale(params, 0.5, h, w)

    symmetric = _models.is_symmetric(window)
    searched = search and not init and type(fit_model).search is not _models.Model.search
    if searched:
        coarsest = levels - 1
        radius = search_radius * 0.5**coarsest
        ctx = context(coarsest, radius)
        params = fit_model.search(params, lambda candidates: _losses(fit_model, ctx, candidates, margin), ctx, radius, symmetric)
        # The search's grid (half a pixel of the coarsest level) lands in the finest level's basin;
        # solving the coarser levels first can lead a small object's velocity away from it, into
        # a minimum of the coarse image that the finest one does not share.
        for level in reversed(range(levels - 1)):
            h, w = pyramid[level]["color"].shape[2:]
            params = fit_model.rescale(params, 2.0, h, w)

    history: list[float] = []

    def record(loss: float) -> None:
        history.append(loss)
        if on_step is not None:
            on_step(len(history), loss)

    learning_rate = fit_model.learning_rate if learning_rate is None else checks.require_positive_number("learning_rate", learning_rate)
    trust_coverage = method == "scatter" and model != "rotation"

    def fit_from(params: dict[str, np.ndarray], *, finest_only: bool = False, fixed: np.ndarray | None = None) -> tuple[dict[str, np.ndarray], Any, Callable, np.ndarray, float, _solvers.Solved]:
        """Coarse to fine from `params` (coarsest level's; the finest's with `finest_only`), the
        `fixed` parameters held (lbfgs); the finest level's results."""
        # The scatter's fits leave out the pixels that rest on its fill (`_models.covered`), found
        # from each level's start; the finest level is solved twice, the second time with the pixels
        # found from its first answer.
        passes = [] if finest_only else [(level, 1) for level in reversed(range(1, levels))]
        passes += [(0, 1)] + ([(0, 2)] if trust_coverage else [])
        for level, _pass in passes:
            ctx = context(level, speed_of(params, level))
            y0, spec = _flatten(params)
            if trust_coverage:
                shown = _models.covered(ctx, be.run(_motion, as_arrays(params), ctx, traced))
                ctx.extras["weight"] = be.array(pyramid[level]["weight"] * shown)
            residuals, arguments = objective(ctx, spec)
            if solver == "lbfgs":
                solved = _solvers.lbfgs_solve(be.value_and_grad(_level_loss, *arguments), y0, scale=_parameter_scale(fit_model, params, ctx), iterations=iterations, on_step=record, fixed=fixed)
            elif backend == "torch":
                solved = _solvers.torch_adam(be, residuals, y0, iterations=iterations, learning_rate=learning_rate, on_step=record)
            else:
                solved = _solvers.jax_solve(be, residuals, y0, solver=solver, iterations=iterations, learning_rate=learning_rate, on_step=record, jac=jac, matrix_free=model == "dense")
            params = {k: np.asarray(v, dtype=np.float64) for k, v in _unflatten(solved.y, spec).items()}
            if level > 0:
                h, w = pyramid[level - 1]["color"].shape[2:]
                params = fit_model.rescale(params, 2.0, h, w)
        loss = float(be.numpy(be.run(_level_loss, be.array(solved.y), *arguments)))
        return params, ctx, residuals, solved.y, loss, solved

    best = fit_from(params, finest_only=searched)
    if not symmetric and model == "global" and not search:
        # An asymmetric shutter tells +v from -v, but each is a local minimum of the other's basin:
        # without the search (which tries both), start from both signs and keep the better fit.
        mirrored = fit_from({"velocity": -params["velocity"]})
        if mirrored[4] < best[4]:
            best = mirrored
    if trust_coverage and solver == "lbfgs" and isinstance(fit_model, _models.MotionIds) and not layered:
        # One scatter of every pixel treats a pixel as still only when its velocity is exactly 0, and
        # composites a still background under what passes over it but a moving one beside it (seed
        # 003 has no depth write): a background fitted to a few hundredths of a pixel blurs unlike a
        # still one, and no gradient leads to exactly 0. So IDs slower than STILL_SPEED are tried at
        # exactly 0, the others refitted, and that answer kept where its loss is no higher. (The
        # layered scatter composites every layer alike, whatever its speed: it needs no such try.)
        palette = best[0]["palette"]
        still = np.hypot(palette[:, 0], palette[:, 1]) < STILL_SPEED
        if still.any() and np.any(palette[still] != 0):
            snapped = {"palette": np.where(still[:, None], 0.0, palette)}
            refit = fit_from(snapped, finest_only=True, fixed=np.repeat(still, 2))
            if refit[4] <= best[4]:
                best = refit
    params, ctx, residuals, y, loss, solved = best
    if symmetric and fit_model.sign_ambiguous:
        params = fit_model.canonical(params)
    y, spec = _flatten(params)
    p_be = _unflatten(be.array(y), spec)
    blurred = be.numpy(be.run(_render, p_be, ctx, traced))
    field_ = be.numpy(be.run(_velocity, p_be, ctx, traced))
    # The same pixels and weights, with no blur at all: what the fit is measured against.
    crop = int(round(margin * ctx.scale))
    unblurred = (color - goal) * be.numpy(ctx.extras["weight"])
    unblurred_loss = float(np.sum(unblurred[:, :, crop : height - crop, crop : width - crop] ** 2) / (goal.shape[1] * (height - 2 * crop) * (width - 2 * crop)))
    explained = 1.0 - loss / unblurred_loss if unblurred_loss > 0 else float("nan")
    result = FitResult(
        model=model,
        backend=backend,
        solver=solver,
        params=fit_model.report(params, symmetric and fit_model.sign_ambiguous),
        loss=loss,
        blurred=blurred,
        history=history,
        velocity=field_,
        n_params=int(y.size),
        levels=levels,
        seconds=time.perf_counter() - start_time,
        raw=params,
        pixels=int(np.prod(goal.shape)),
        converged=bool(solved.converged),
        explained=float(explained),
        message=solved.message,
        method=method,
        ids=arrays["ids"],
    )
    if check_method and result.converged and method != DEFAULT_METHODS[model] and DEFAULT_METHODS[model] == "scatter":
        _check_method(result, sharp=color, target=goal, model=fit_model, depth=depth, backend=backend, shutter=shutter, samples=samples, arc_samples=arc_samples, margin=margin, weight=weight, dtype=dtype)
    if warn and not result.converged:
        warnings.warn(f"recover(model={model!r}) did not converge: {result.message}", UserWarning, stacklevel=2)
    if warn and not explained >= EXPLAINED_WARNING:
        warnings.warn(
            f"recover(model={model!r}) explains only {explained:.0%} of the blur (1 - loss / the unblurred frame's loss): the model may not fit this scene; select_model tries richer ones",
            UserWarning,
            stacklevel=2,
        )
    return result


def _check_method(result: FitResult, *, sharp: np.ndarray, target: np.ndarray, model: _models.Model, depth: Any, margin: int, **options: Any) -> None:
    """Refit `result` through the scatter from its answer and record how far the velocity field
    moves (`FitResult.method_shift`); past METHOD_SHIFT_WARNING mark it not converged, saying why.

    The scatter is the forward model whose own error is smallest on the held-out family, so a fit
    through reconstruct or the gather that it moves far was pulled there by that method's error, a
    bias that neither the fit's loss nor `explained` shows."""
    check = recover(sharp, target, model=model, depth=depth, method="scatter", levels=1, init=result.raw, search=False, margin=margin, warn=False, check_method=False, **options)
    height, width = sharp.shape[2:]
    inner = (slice(None), slice(None), slice(margin, height - margin), slice(margin, width - margin))
    a, b = result.velocity[inner][0], check.velocity[inner][0]
    # Up to sign at each pixel: a symmetric shutter leaves each velocity's sign open.
    per_pixel = np.minimum(np.hypot(*(a - b)), np.hypot(*(a + b)))
    result.method_shift = float(per_pixel.max())
    if result.method_shift > METHOD_SHIFT_WARNING:
        result.converged = False
        result.message = (
            f"through method={result.method!r} the fit is biased by the method's own error: refitted through the scatter from its answer, "
            f"the velocity field moves by up to {result.method_shift:.2f} px (more than {METHOD_SHIFT_WARNING}); fit with method='scatter'"
        )

