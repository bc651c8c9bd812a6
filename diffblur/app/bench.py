"""`diffblur bench`: the speed/accuracy trade of every method and setting, in both backends.

`run_benchmarks(...)` renders the ground-truth presets (plus "uniform", one photograph under a
horizontal camera pan: the scene kornia's single-kernel blur models exactly), runs every entry of
`SETTINGS` on each scene in PyTorch and JAX, and measures:

| field | how |
|---|---|
| psnr_db, ssim | against the scene's accumulated ground truth (`diffblur.metrics`), float32 output |
| forward_ms | median wall time of repeated forward passes after a warm-up; torch eager under no_grad, JAX `jax.jit` after compilation |
| backward_ms | the same for forward + backward (sum of the output, gradient w.r.t. the setting's floating inputs); JAX `jit(value_and_grad)`. Timed in turn with the forward (`diffblur.app.timing.median_ms_each`), so the machine's drift reaches both alike |
| compile_s, compile_backward_s | JAX: lowering + XLA compilation of the forward / forward+backward (paid once per shape); torch eager: none |
| peak_mb | resident-set high-water mark above the resting RSS during one forward + backward (Linux: malloc_trim, then /proc/self/clear_refs resets VmHWM) |
| xla_temp_mb | JAX only: XLA's compiled memory_analysis() temporary buffers of the forward + backward |
| brute_force_psnr_db | the peer "brute-force accumulation at the same time budget": the scene renderer's own accumulation (`diffblur.scenes.accumulate`, NumPy) with the most instants that fit in this row's forward time |

Peers run in the same sweep: `kornia.filters.motion_blur` (on "uniform", kernel sizes 9/31/61,
bilinear mode, backward w.r.t. the image and its angle) and the accumulation at 1, 2, 4, ... instants.
A "targets" pass runs the design's performance targets at 1280x720 on the uniform scene, every
setting's forward and fwd+bwd taking turns in one loop (the targets are ratios between settings).

The results go to `docs/benchmarks.json` (machine-readable), `BENCHMARKS.md` (a table per scene,
with the machine, versions, date and load) and `docs/pareto.png` (PSNR against forward time).
The backends are imported here, inside the functions, so `diffblur` itself stays free of them.
"""

from __future__ import annotations

import ctypes
import datetime
import json
import math
import os
import platform
import sys
import time
from dataclasses import asdict, dataclass, field
from typing import Any, Callable

import numpy as np

from diffblur import checks, metrics
from diffblur.app.timing import median_ms, median_ms_each
from diffblur.scenes import PRESETS, Camera, ImageTexture, Layer, Scene, Static, accumulate, photo, render_buffers, trace

__all__ = ["SETTINGS", "TARGET_SETTINGS", "Setting", "run_benchmarks", "uniform_scene"]

#: Half-spread (px) of the uniform scene's pan at >= 128 px: its blur spans 2 x 15 + 1 = 31 pixels,
#: kornia's middle kernel size.
UNIFORM_HALF_SPREAD = 15.0
KORNIA_KERNELS = (9, 31, 61)
ACCUMULATION_INSTANTS = (1, 2, 4, 8, 16, 32, 64)


@dataclass(frozen=True)
class Setting:
    """One benchmark entry: a method with one choice of its accuracy settings.

    call(ops, x) runs it with `ops` = torch_impl or jax_impl (or kornia for a peer) on the dict x of
    float32 inputs named by `inputs` (of "color", "velocity", "depth", "offset_prev", "offset_next",
    "offset_mid_prev", "background", "angle"); `grad` names those differentiated in the backward.
    A scene without one of the inputs (only "background" can be missing) skips the entry.
    """

    method: str
    label: str
    call: Callable[[Any, dict], Any]
    inputs: tuple[str, ...]
    grad: tuple[str, ...]
    backends: tuple[str, ...] = ("torch", "jax")
    quick: bool = False
    scenes: tuple[str, ...] | None = None  # None: every scene


def _reconstruct(**options):
    return lambda ops, x: ops.reconstruct(x["color"], x["velocity"], x["depth"], **options)


def _gather(**options):
    return lambda ops, x: ops.gather_blur(x["color"], x["velocity"], **options)


def _scatter(with_background=False, **options):
    def call(ops, x):
        if options.get("degree") == 3:
            options_ = dict(options, offset_mid_prev=x["offset_mid_prev"])
        else:
            options_ = options
        if with_background:  # the scene behind as the fill
            options_ = dict(options_, fill=x["background"])
        return ops.bezier_scatter(x["color"], x["depth"], x["offset_prev"], x["offset_next"], **options_)

    return call


def _warp_blend(**options):
    return lambda ops, x: ops.warp_blend(x["color"], x["velocity"], **options)


def _accumulate_warps(curved=False, **options):
    if curved:
        return lambda ops, x: ops.accumulate_warps(x["color"], None, offset_prev=x["offset_prev"], offset_next=x["offset_next"], **options)
    return lambda ops, x: ops.accumulate_warps(x["color"], x["velocity"], **options)


def _kornia(kernel_size):
    def call(kornia, x):
        return kornia.filters.motion_blur(x["color"], kernel_size, x["angle"], 0.0, border_type="replicate", mode="bilinear")

    return call


_RV = ("color", "velocity", "depth")
_CV = ("color", "velocity")
_SC = ("color", "depth", "offset_prev", "offset_next")
_SC3 = _SC + ("offset_mid_prev",)
_SCB = _SC + ("background",)

#: Every method and accuracy setting, one entry each (extend here as methods land).
SETTINGS: tuple[Setting, ...] = (
    Setting("reconstruct", "S=5, bilinear", _reconstruct(samples=5), _RV, _RV),
    Setting("reconstruct", "S=9, bilinear", _reconstruct(samples=9), _RV, _RV),
    Setting("reconstruct", "S=15, bilinear", _reconstruct(samples=15), _RV, _RV, quick=True),
    Setting("reconstruct", "S=15, bilinear, tensor ops", _reconstruct(samples=15, impl="tensor"), _RV, _RV, quick=True),
    Setting("reconstruct", "S=15, bilinear, adaptive", _reconstruct(samples=15, adaptive=True), _RV, _RV),
    Setting("reconstruct", "S=5, bilinear, pyramid", _reconstruct(samples=5, sampling="pyramid"), _RV, _RV),
    Setting("reconstruct", "S=31, bilinear", _reconstruct(samples=31), _RV, _RV),
    Setting("reconstruct", "S=15, nearest (paper)", _reconstruct(samples=15, sampling="nearest"), _RV, _RV),
    Setting("reconstruct", "S=15, bilinear, no jitter", _reconstruct(samples=15, jitter="none"), _RV, _RV),
    Setting("reconstruct", "S=15, bilinear, own directions", _reconstruct(samples=15, directions="neighbor_and_own"), _RV, _RV),
    Setting("reconstruct", "S=15, bilinear, gaussian shutter", _reconstruct(samples=15, shutter="gaussian"), _RV, _RV),
    Setting("gather_blur", "S=5, bilinear", _gather(samples=5), _CV, _CV, quick=True),
    Setting("gather_blur", "S=15, bilinear", _gather(samples=15), _CV, _CV),
    Setting("gather_blur", "S=15, bilinear, tensor ops", _gather(samples=15, impl="tensor"), _CV, _CV),
    Setting("gather_blur", "S=15, bilinear, adaptive", _gather(samples=15, adaptive=True), _CV, _CV),
    Setting("gather_blur", "S=5, bilinear, pyramid", _gather(samples=5, sampling="pyramid"), _CV, _CV),
    Setting("gather_blur", "S=31, bilinear", _gather(samples=31), _CV, _CV),
    Setting("gather_blur", "S=15, nearest", _gather(samples=15, sampling="nearest"), _CV, _CV),
    Setting("bezier_scatter", "degree 1, 16 points", _scatter(degree=1, samples=16, shutter="box"), _SC, _SC),
    Setting("bezier_scatter", "degree 2, 8 points", _scatter(degree=2, samples=8, shutter="box"), _SC, _SC, quick=True),
    Setting("bezier_scatter", "degree 2, 16 points", _scatter(degree=2, samples=16, shutter="box"), _SC, _SC),
    Setting("bezier_scatter", "degree 2, 16 points, tensor ops", _scatter(degree=2, samples=16, shutter="box", impl="tensor"), _SC, _SC),
    Setting("bezier_scatter", "degree 2, 32 points", _scatter(degree=2, samples=32, shutter="box"), _SC, _SC),
    Setting("bezier_scatter", "degree 3, 16 points", _scatter(degree=3, samples=16, shutter="box"), _SC3, _SC3),
    Setting("bezier_scatter", "degree 2, 16 points, paper normalisation", _scatter(degree=2, samples=16, shutter="box", normalization="paper"), _SC, _SC),
    Setting("bezier_scatter", "degree 2, 16 points, gaussian shutter", _scatter(degree=2, samples=16, shutter="gaussian"), _SC, _SC),
    Setting(
        "bezier_scatter",
        "degree 2, 16 points, background",
        _scatter(with_background=True, degree=2, samples=16, shutter="box"),
        _SCB,
        _SC,
    ),
    Setting("warp_blend", "1 iteration", _warp_blend(iterations=1), _CV, _CV),
    Setting("warp_blend", "2 iterations", _warp_blend(iterations=2), _CV, _CV),
    Setting("warp_blend", "3 iterations", _warp_blend(iterations=3), _CV, _CV, quick=True),
    Setting("accumulate_warps", "8 instants", _accumulate_warps(instants=8), _CV, _CV),
    Setting("accumulate_warps", "32 instants", _accumulate_warps(instants=32), _CV, _CV),
    Setting("accumulate_warps", "8 instants, curved offsets", _accumulate_warps(curved=True, instants=8), ("color", "offset_prev", "offset_next"), ("color", "offset_prev", "offset_next")),
) + tuple(
    Setting("kornia.motion_blur", f"kernel {k}, bilinear", _kornia(k), ("color", "angle"), ("color", "angle"), backends=("torch",), quick=k == 31, scenes=("uniform",))
    for k in KORNIA_KERNELS
)

#: The design's performance targets, run at 1280x720 on the uniform scene (one image, float32).
TARGET_SETTINGS: tuple[Setting, ...] = (
    Setting("reconstruct", "S=15, bilinear", _reconstruct(samples=15), _RV, _RV),
    Setting("reconstruct", "S=15, bilinear, no jitter", _reconstruct(samples=15, jitter="none"), _RV, _RV),
    Setting("reconstruct", "S=31, bilinear", _reconstruct(samples=31), _RV, _RV),
    Setting("reconstruct", "S=15, bilinear, tensor ops", _reconstruct(samples=15, impl="tensor"), _RV, _RV),
    Setting("kornia.motion_blur", "kernel 31, bilinear", _kornia(31), ("color", "angle"), ("color", "angle"), backends=("torch",)),
    Setting("bezier_scatter", "degree 2, 16 points", _scatter(degree=2, samples=16, shutter="box"), _SC, _SC),
)


def uniform_scene(*, height: int = 128, width: int = 128, instants: int | None = None):
    """One opaque photograph under a horizontal camera pan: every pixel has the same velocity,
    UNIFORM_HALF_SPREAD px (scaled down below 128 px). Returns `diffblur.scenes.SceneBuffers`;
    instants: its target's (`render_buffers`), e.g. 1 where only the inputs are wanted."""
    half = UNIFORM_HALF_SPREAD * min(1.0, min(height, width) / 128.0)
    margin = int(math.ceil(half)) + 2
    color = photo("astronaut", height + 2 * margin, width + 2 * margin)
    layer = Layer(ImageTexture(color, None, (-margin, -margin)), 1.0, Static(), name="photograph")
    scene = Scene(height, width, (layer,), Camera(pan=(half, 0.0)))
    return render_buffers(scene, name="uniform", instants=instants)


@dataclass
class Row:
    """One measurement (see the module table); None where a field does not apply."""

    scene: str
    size: str
    method: str
    setting: str
    backend: str
    psnr_db: float
    ssim: float
    forward_ms: float
    backward_ms: float | None = None
    compile_s: float | None = None
    compile_backward_s: float | None = None
    peak_mb: float | None = None
    xla_temp_mb: float | None = None
    brute_force_psnr_db: float | None = None
    brute_force_instants: int | None = None
    extra: dict = field(default_factory=dict)


# ---------------------------------------------------------------------------------------------
# measurement helpers


def _status_kb(key: str) -> int | None:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1])
    except OSError:
        pass
    return None


def _peak_rss_mb(fn: Callable[[], Any]) -> float | None:
    """RSS high-water mark above the resting RSS while fn() runs, MB; None where Linux's
    /proc/self/clear_refs (which resets VmHWM) is not available."""
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)  # hand freed heap pages back, so they do not hide the peak
    except (OSError, AttributeError):
        pass
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        return None
    rest = _status_kb("VmRSS")
    fn()
    peak = _status_kb("VmHWM")
    if rest is None or peak is None:
        return None
    return max(0.0, (peak - rest) / 1024.0)


def _inputs(buffers) -> dict[str, np.ndarray]:
    """The scene's float32 NumPy inputs of every method (module docstring of Setting)."""
    grid = np.stack(np.meshgrid(np.arange(buffers.color.shape[3]), np.arange(buffers.color.shape[2]), indexing="xy")).astype(np.float64)
    mid_prev = (trace(buffers.scene, np.array([-0.5]))[0] - grid)[None]
    v = buffers.velocity[0].reshape(2, -1).mean(axis=1)
    angle = math.degrees(math.atan2(-v[1], v[0])) if np.hypot(*v) > 0 else 0.0  # kornia: anticlockwise, y up
    out = {
        "color": buffers.color,
        "velocity": buffers.velocity,
        "depth": buffers.depth,
        "offset_prev": buffers.offset_prev,
        "offset_next": buffers.offset_next,
        "offset_mid_prev": mid_prev,
        "angle": np.array([angle]),
    }
    if buffers.background is not None:
        out["background"] = buffers.background
    return {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in out.items()}


class _TorchRunner:
    """PyTorch's calls on `device` ("cpu", "cuda"); on a GPU each call waits for the device's work
    (`torch.cuda.synchronize`), so that a wall-clock time is the work's."""

    def __init__(self, device: str = "cpu") -> None:
        import torch

        import torch_impl

        self.torch, self.ops, self.device = torch, torch_impl, torch.device(device)

    def measure(self, setting: Setting, x: dict[str, np.ndarray], repeats: int) -> dict:
        return _timed(self.prepare(setting, x), repeats)

    def prepare(self, setting: Setting, x: dict[str, np.ndarray]) -> dict:
        """The setting's forward and forward+backward calls, ready to time, and its output."""
        torch = self.torch
        if setting.method.startswith("kornia"):
            import kornia

            ops = kornia
        else:
            ops = self.ops
        tensors = {k: torch.from_numpy(v).to(self.device) for k, v in x.items()}
        wait = torch.cuda.synchronize if self.device.type == "cuda" else (lambda: None)

        def forward():
            with torch.no_grad():
                out = setting.call(ops, tensors)
            wait()
            return out

        leaves = {k: v.clone().requires_grad_(k in setting.grad) for k, v in tensors.items()}

        def backward():
            for v in leaves.values():
                v.grad = None
            out = setting.call(ops, leaves)
            out.sum().backward()
            wait()

        return dict(output=forward().cpu().numpy(), forward=forward, backward=backward)


class _JaxRunner:
    def __init__(self) -> None:
        import jax
        import jax.numpy as jnp

        import jax_impl

        self.jax, self.jnp, self.ops = jax, jnp, jax_impl
        self.compiled: dict = {}

    def _compile(self, key, fn, *args):
        """The compiled function, its XLA temporaries (MB) and its compile time (s), once per key."""
        if key in self.compiled:
            return self.compiled[key]
        start = time.perf_counter()
        compiled = self.jax.jit(fn).lower(*args).compile()
        seconds = time.perf_counter() - start
        try:
            temp = compiled.memory_analysis().temp_size_in_bytes / 2**20
        except (AttributeError, TypeError, NotImplementedError):
            temp = None
        self.compiled[key] = (compiled, temp, seconds)
        return self.compiled[key]

    def measure(self, setting: Setting, x: dict[str, np.ndarray], repeats: int) -> dict:
        return _timed(self.prepare(setting, x), repeats)

    def prepare(self, setting: Setting, x: dict[str, np.ndarray]) -> dict:
        """The setting's compiled forward and forward+backward calls, ready to time, its output and
        compile figures."""
        jax, jnp = self.jax, self.jnp
        arrays = {k: jnp.asarray(v) for k, v in x.items()}
        grads = {k: v for k, v in arrays.items() if k in setting.grad}
        rest = {k: v for k, v in arrays.items() if k not in setting.grad}
        shapes = tuple(sorted((k, v.shape) for k, v in arrays.items()))

        def forward_fn(a):
            return setting.call(self.ops, a)

        def loss(g, r):
            return jnp.sum(setting.call(self.ops, {**r, **g}))

        key = (setting.method, setting.label, shapes)
        fwd, _, fwd_compile = self._compile(key + ("forward",), forward_fn, arrays)
        bwd, temp, bwd_compile = self._compile(key + ("backward",), jax.value_and_grad(loss), grads, rest)
        return dict(
            output=np.asarray(jax.block_until_ready(fwd(arrays))),
            forward=lambda: jax.block_until_ready(fwd(arrays)),
            backward=lambda: jax.block_until_ready(bwd(grads, rest)),
            compile_s=fwd_compile,
            compile_backward_s=bwd_compile,
            xla_temp_mb=temp,
        )


def _timed(prepared: dict, repeats: int) -> dict:
    """A runner's prepared calls timed in turn (forward, forward+backward), with the peak memory of
    one forward+backward: the fields of a `Row`, and the output."""
    forward, backward = prepared.pop("forward"), prepared.pop("backward")
    prepared["forward_ms"], prepared["backward_ms"] = median_ms_each([forward, backward], repeats)
    prepared["peak_mb"] = _peak_rss_mb(backward)
    return prepared


# ---------------------------------------------------------------------------------------------
# the sweep


def cpu_model() -> str:
    """The processor's name (/proc/cpuinfo's model name where there is one)."""
    model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return model


def _machine(load_before: tuple[float, float, float]) -> dict:
    model = cpu_model()
    versions = {"python": platform.python_version(), "numpy": np.__version__}
    for name in ("torch", "jax", "jaxlib", "kornia", "numba"):
        module = sys.modules.get(name)
        if module is not None:
            versions[name] = getattr(module, "__version__", "?")
    try:
        import torch

        threads = torch.get_num_threads()
    except ImportError:
        threads = None
    numba = sys.modules.get("numba")
    return {
        "cpu": model,
        "cores": os.cpu_count(),
        "torch_threads": threads,
        "numba_threads": numba.get_num_threads() if numba is not None else None,
        "platform": platform.platform(),
        "versions": versions,
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "load_before": list(load_before),
        "load_after": list(os.getloadavg()),
        "device": "cpu",
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
        # Whether PyTorch's OpenMP threads spin between ops, competing with the fused kernels'
        # threads on few cores (docs/fused.md).
        "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY", ""),
    }


def _accumulation_rows(buffers, instants: tuple[int, ...], size: str) -> list[Row]:
    rows = []
    for n in instants:
        image, count = accumulate(buffers.scene, shutter=buffers.shutter, instants=n)
        ms = median_ms(lambda: accumulate(buffers.scene, shutter=buffers.shutter, instants=n), repeats=1, warmup=0)
        rows.append(
            Row(
                buffers.name,
                size,
                "accumulation (renderer)",
                f"{count} instants",
                "numpy",
                float(metrics.psnr(image, buffers.target)),
                float(metrics.ssim(image, buffers.target)),
                ms,
                extra={"instants": count},
            )
        )
    return rows


def _brute_force_at_budget(rows: list[Row], accumulation: list[Row]) -> None:
    """Give each row the accumulation's PSNR with the most instants that run within its forward time."""
    for row in rows:
        fitting = [a for a in accumulation if a.forward_ms <= row.forward_ms]
        if fitting:
            best = max(fitting, key=lambda a: a.extra["instants"])
            row.brute_force_psnr_db, row.brute_force_instants = best.psnr_db, best.extra["instants"]
        else:
            row.brute_force_psnr_db, row.brute_force_instants = None, 0


def run_benchmarks(
    *,
    out_dir: str | os.PathLike = ".",
    quick: bool = False,
    height: int = 160,
    width: int = 160,
    scenes: tuple[str, ...] | None = None,
    backends: tuple[str, ...] = ("torch", "jax"),
    repeats: int | None = None,
    targets: bool | None = None,
    target_repeats: int = 5,
    threads: int | None = None,
    target_height: int = 720,
    target_width: int = 1280,
    progress: bool = True,
) -> dict:
    """Run the sweep, write BENCHMARKS.md, docs/benchmarks.json and docs/pareto.png under out_dir,
    and return the results ({"machine": ..., "rows": [...], "targets": [...]}).

    threads: PyTorch intra-op and fused-kernel (numba) threads (and, at 1, XLA's Eigen thread pool off;
    set before JAX starts); None keeps the frameworks' defaults.
    quick: the entries marked quick, scenes "uniform" and "crossing", 1 repeat, no targets pass.
    scenes: preset names and/or "uniform" (default: all). repeats: timed runs per measurement
    (default 3, quick 1). targets: run TARGET_SETTINGS at target_height x target_width (default:
    not quick), timed target_repeats times each (5: on a shared 2-core machine one 720p run of the
    fused reconstruct has ranged 100-220 ms; the median of 2 was often the slow one).
    """
    height = checks.require_positive_int("height", height)
    width = checks.require_positive_int("width", width)
    all_scenes = ("uniform",) + PRESETS
    if scenes is None:
        scenes = ("uniform", "crossing") if quick else all_scenes
    for name in scenes:
        checks.require_choice("scenes", name, all_scenes)
    for name in backends:
        checks.require_choice("backends", name, ("torch", "jax"))
    repeats = (1 if quick else 3) if repeats is None else checks.require_positive_int("repeats", repeats)
    targets = (not quick) if targets is None else bool(targets)
    settings = [s for s in SETTINGS if s.quick or not quick]
    instants = (1, 4) if quick else ACCUMULATION_INSTANTS
    load_before = os.getloadavg()
    if threads is not None:
        # Set before either backend starts its thread pools: with more threads than free cores (a
        # shared machine), every parallel region waits for descheduled threads (measured 14x slower).
        threads = checks.require_positive_int("threads", threads)
        if threads == 1 and "jax" in backends:
            os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_cpu_multi_thread_eigen=false").strip()
        if "torch" in backends:
            import torch

            previous_threads = torch.get_num_threads()
            torch.set_num_threads(threads)
        from diffblur.kernels import shared as kernels

        if kernels.available():  # the fused kernels' thread pool
            import numba

            previous_numba_threads = numba.get_num_threads()
            numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        return _run(quick, height, width, scenes, backends, repeats, targets, target_repeats, target_height, target_width, threads, out_dir, progress, settings, instants, load_before)
    finally:
        if threads is not None and "torch" in backends:
            torch.set_num_threads(previous_threads)
        if threads is not None and kernels.available():
            numba.set_num_threads(previous_numba_threads)


def _run(quick, height, width, scenes, backends, repeats, targets, target_repeats, target_height, target_width, threads, out_dir, progress, settings, instants, load_before):
    from tqdm import tqdm

    runners: dict[str, Any] = {}
    if "torch" in backends:
        runners["torch"] = _TorchRunner()
    if "jax" in backends:
        runners["jax"] = _JaxRunner()

    def jobs_for(name, x, chosen):
        return [
            (s, b)
            for s in chosen
            for b in s.backends
            if b in runners and (s.scenes is None or name in s.scenes) and all(n in x for n in s.inputs)
        ]

    rendered = []
    for name in scenes:
        buffers = uniform_scene(height=height, width=width) if name == "uniform" else _preset(name, height, width)
        rendered.append((buffers, _inputs(buffers)))
    total = sum(len(jobs_for(b.name, x, settings)) for b, x in rendered)
    target_scene = None
    if targets:
        buffers = uniform_scene(height=target_height, width=target_width)
        target_scene = (buffers, _inputs(buffers))
        total += len(jobs_for("uniform", target_scene[1], TARGET_SETTINGS))

    rows: list[Row] = []
    target_rows: list[Row] = []
    with tqdm(total=total, desc="benchmarking", unit="run", disable=not progress) as bar:
        for buffers, x in rendered:
            size = f"{width}x{height}"
            scene_rows = [_measure(runners, s, b, buffers, x, size, repeats, bar) for s, b in jobs_for(buffers.name, x, settings)]
            accumulation = _accumulation_rows(buffers, instants, size)
            _brute_force_at_budget(scene_rows, accumulation)
            rows += scene_rows + accumulation
        if target_scene is not None:
            buffers, x = target_scene
            size = f"{target_width}x{target_height}"
            target_rows = _measure_in_turns(runners, jobs_for("uniform", x, TARGET_SETTINGS), buffers, x, size, target_repeats, bar)

    results = {
        "machine": _machine(load_before),
        "command": _command(quick, height, width, scenes, backends, repeats, targets) + (f" --threads {threads}" if threads else ""),
        "repeats": repeats,
        "target_repeats": target_repeats,
        "rows": [asdict(r) for r in rows],
        "targets": [asdict(r) for r in target_rows],
    }
    _write(out_dir, results)
    return results


def _command(quick, height, width, scenes, backends, repeats, targets) -> str:
    """The `diffblur bench` command line that reproduces a run (height == width on the command line)."""
    words = ["diffblur bench"] + (["--quick"] if quick else [])
    words += [f"--size {height}" if height == width else f"(height={height}, width={width})"]
    words += [f"--scenes {','.join(scenes)}", f"--backends {','.join(backends)}", f"--repeats {repeats}"]
    words += ["--targets" if targets else "--no-targets"]
    return " ".join(words)


def _preset(name, height, width):
    from diffblur.scenes import make_scene

    return make_scene(name, height=height, width=width)


def _measure(runners, setting: Setting, backend: str, buffers, x, size, repeats, bar) -> Row:
    bar.set_postfix_str(f"{buffers.name} {size}: {setting.method} {setting.label} [{backend}]")
    m = runners[backend].measure(setting, {k: x[k] for k in setting.inputs}, repeats)
    bar.update()
    return _row(setting, backend, buffers, size, m)


def _measure_in_turns(runners, jobs, buffers, x, size, repeats, bar) -> list[Row]:
    """`_measure` for settings compared with each other (the targets pass): every job's forward and
    forward+backward take turns in one loop, so that the ratios between settings (reconstruct
    against kornia) are not those of a machine's speed minutes apart."""
    prepared = []
    for setting, backend in jobs:
        bar.set_postfix_str(f"{buffers.name} {size}: preparing {setting.method} {setting.label} [{backend}]")
        prepared.append(runners[backend].prepare(setting, {k: x[k] for k in setting.inputs}))
    calls = [call for m in prepared for call in (m.pop("forward"), m.pop("backward"))]
    bar.set_postfix_str(f"{buffers.name} {size}: {len(jobs)} settings in turns, {repeats} rounds")
    times = median_ms_each(calls, repeats)
    rows = []
    for i, ((setting, backend), m) in enumerate(zip(jobs, prepared)):
        bar.set_postfix_str(f"{buffers.name} {size}: peak memory of {setting.method} {setting.label} [{backend}]")
        m["forward_ms"], m["backward_ms"] = times[2 * i], times[2 * i + 1]
        m["peak_mb"] = _peak_rss_mb(calls[2 * i + 1])
        rows.append(_row(setting, backend, buffers, size, m))
        bar.update()
    return rows


def _row(setting: Setting, backend: str, buffers, size: str, m: dict) -> Row:
    output = m.pop("output").astype(np.float64)
    return Row(
        buffers.name,
        size,
        setting.method,
        setting.label,
        backend,
        float(metrics.psnr(output, buffers.target)),
        float(metrics.ssim(output, buffers.target)),
        **m,
    )


# ---------------------------------------------------------------------------------------------
# reports


def _fmt(value, digits=1) -> str:
    if value is None:
        return "-"
    if isinstance(value, float) and not math.isfinite(value):
        return "inf" if value > 0 else "nan"
    return f"{value:.{digits}f}"


def pareto_front(points: list[tuple[float, float]]) -> list[int]:
    """Indices of the points (time, psnr) that no other point beats on both (faster and better)."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], -points[i][1]))
    front, best = [], -math.inf
    for i in order:
        if points[i][1] > best:
            front.append(i)
            best = points[i][1]
    return front


def _table(rows: list[dict], front: set[int] | None = None) -> list[str]:
    lines = [
        "| method | setting | backend | PSNR dB | SSIM | fwd ms | fwd+bwd ms | compile s (fwd / fwd+bwd) | peak MB | XLA temp MB | brute force at same time |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for i, r in enumerate(rows):
        star = " *" if front and i in front else ""
        compile_ = "-" if r["compile_s"] is None and r["compile_backward_s"] is None else f"{_fmt(r['compile_s'])} / {_fmt(r['compile_backward_s'])}"
        brute = "-" if r["brute_force_instants"] is None else (f"{_fmt(r['brute_force_psnr_db'], 2)} dB ({r['brute_force_instants']} instants)" if r["brute_force_instants"] else "none fits")
        lines.append(
            f"| {r['method']}{star} | {r['setting']} | {r['backend']} | {_fmt(r['psnr_db'], 2)} | {_fmt(r['ssim'], 3)} | "
            f"{_fmt(r['forward_ms'])} | {_fmt(r['backward_ms'])} | {compile_} | {_fmt(r['peak_mb'])} | {_fmt(r['xla_temp_mb'])} | {brute} |"
        )
    return lines


def _target_lines(rows: list[dict]) -> list[str]:
    def find(method, setting, backend):
        for r in rows:
            if r["method"] == method and r["setting"] == setting and r["backend"] == backend:
                return r
        return None

    lines = ["| target | measured | met |", "|---|---|---|"]
    kornia = find("kornia.motion_blur", "kernel 31, bilinear", "torch")
    for backend in ("torch", "jax"):
        r = find("reconstruct", "S=15, bilinear", backend)
        r31 = find("reconstruct", "S=31, bilinear", backend)
        if r is None:
            continue
        ratio = r["backward_ms"] / r["forward_ms"]
        lines.append(f"| reconstruct {backend} forward <= 100 ms | {r['forward_ms']:.0f} ms | {'yes' if r['forward_ms'] <= 100 else 'no'} |")
        lines.append(f"| reconstruct {backend} fwd+bwd <= 3x forward | {r['backward_ms']:.0f} ms = {ratio:.1f}x | {'yes' if ratio <= 3 else 'no'} |")
        if r31 is not None and r["peak_mb"] is not None and r31["peak_mb"] is not None:
            lines.append(
                f"| reconstruct {backend} backward memory O(pixels): peak S=15 vs S=31 | {r['peak_mb']:.0f} MB vs {r31['peak_mb']:.0f} MB "
                f"| {'yes' if r31['peak_mb'] <= 1.3 * r['peak_mb'] + 20 else 'no'} |"
            )
        if kornia is not None:
            f, b = kornia["forward_ms"] / r["forward_ms"], kornia["backward_ms"] / r["backward_ms"]
            lines.append(f"| reconstruct {backend} >= 5x faster than kornia k=31 forward | {f:.2f}x ({kornia['forward_ms']:.0f} ms vs {r['forward_ms']:.0f} ms) | {'yes' if f >= 5 else 'no'} |")
            lines.append(f"| reconstruct {backend} >= 10x faster than kornia k=31 fwd+bwd | {b:.2f}x ({kornia['backward_ms']:.0f} ms vs {r['backward_ms']:.0f} ms) | {'yes' if b >= 10 else 'no'} |")
            shifted = find("reconstruct", "S=15, bilinear, no jitter", backend)
            if shifted is not None:  # the shifted rows (jitter="none"), beside the default's per-pixel taps
                f, b = kornia["forward_ms"] / shifted["forward_ms"], kornia["backward_ms"] / shifted["backward_ms"]
                ratio = shifted["backward_ms"] / shifted["forward_ms"]
                lines.append(
                    f"| reconstruct {backend}, jitter=\"none\" (shifted rows): vs kornia k=31 forward >= 5x, fwd+bwd >= 10x; fwd+bwd <= 3x forward "
                    f"| {f:.2f}x, {b:.2f}x; {ratio:.1f}x ({shifted['forward_ms']:.0f} / {shifted['backward_ms']:.0f} ms) | {'yes' if f >= 5 and b >= 10 and ratio <= 3 else 'no'} |"
                )
    for backend in ("torch", "jax"):
        r = find("bezier_scatter", "degree 2, 16 points", backend)
        if r is not None:
            lines.append(f"| bezier_scatter {backend} forward <= 300 ms | {r['forward_ms']:.0f} ms | {'yes' if r['forward_ms'] <= 300 else 'no'} |")
    return lines


def _markdown(results: dict) -> str:
    m = results["machine"]
    versions = ", ".join(f"{k} {v}" for k, v in m["versions"].items())
    out = [
        "# Benchmarks",
        "",
        f"Generated by `{results['command']}` (`diffblur.app.bench.run_benchmarks`); machine-readable results in "
        "[docs/benchmarks.json](docs/benchmarks.json), the Pareto plot in [docs/pareto.png](docs/pareto.png).",
        "",
        f"- date: {m['date']}",
        *([f"- {results['note']}"] if results.get("note") else []),
        f"- machine: {m['cpu']}, {m['cores']} cores visible, torch threads {m['torch_threads']}, numba threads (fused kernels) {m.get('numba_threads')}, XLA_FLAGS '{m.get('xla_flags', '')}', OMP_WAIT_POLICY '{m.get('omp_wait_policy', '')}', {m['device']}; {m['platform']}",
        f"- versions: {versions}",
        f"- load average (1, 5, 15 min) before: {', '.join(f'{v:.2f}' for v in m['load_before'])}; after: {', '.join(f'{v:.2f}' for v in m['load_after'])}",
        f"- timings: median of {results['repeats']} runs after one warm-up, forward and fwd+bwd runs taking turns, float32, one image; PyTorch eager (forward under no_grad), "
        "JAX under `jax.jit`, timed after compilation, compile time in its own column (paid once per input shape)",
        "- fwd+bwd: forward, then the gradient of the output's sum w.r.t. the method's floating inputs (reconstruct: color, "
        "velocity, depth; gather: color, velocity; scatter: color, depth, offsets; kornia: image and angle)",
        "- peak MB: resident-set high-water mark above the resting RSS during one forward + backward (malloc_trim, then "
        "/proc/self/clear_refs resets VmHWM), both backends; XLA temp MB: JAX's compiled memory_analysis() temporaries",
        "- brute force at same time: the scene renderer's own accumulation (NumPy, it knows the scene's geometry) with the most "
        "instants (1, 2, 4, ...) that run within the row's forward time, and its PSNR",
        "- no GPU on this machine: CUDA rows are absent",
        "- `*`: on the scene's Pareto front (no other row is both faster and closer to the ground truth)",
        "",
    ]
    if results["targets"]:
        size = results["targets"][0]["size"]
        paths = (
            "Paths: `reconstruct` by default (`jitter=\"noise\"`) reads each pixel's taps on their own; with `jitter=\"none\"` (the \"no jitter\" rows)"
            " it reads each tile's taps as shifted rows (docs/fused.md). `bezier_scatter` runs its default `composite=\"instants\"`: its splats on the fused kernel, each instant's composite by tensor ops (docs/defaults.md)."
        )
        out += [f"## Targets ({size}, uniform scene, float32, median of {results['target_repeats']} runs, every setting's forward and fwd+bwd in turns in one loop)", "", paths, ""] + _target_lines(results["targets"]) + [""]
        out += _table(results["targets"]) + [""]
    scenes = list(dict.fromkeys(r["scene"] for r in results["rows"]))
    for name in scenes:
        rows = [r for r in results["rows"] if r["scene"] == name]
        front = set(pareto_front([(r["forward_ms"], r["psnr_db"]) for r in rows]))
        out += [f"## Scene `{name}` ({rows[0]['size']})", ""] + _table(rows, front) + [""]
    return "\n".join(out)


_COLORS = {
    "reconstruct": "tab:blue",
    "gather_blur": "tab:orange",
    "bezier_scatter": "tab:green",
    "kornia.motion_blur": "tab:red",
    "warp_blend": "tab:purple",
    "accumulate_warps": "tab:brown",
    "accumulation (renderer)": "tab:gray",
}
_MARKERS = {"torch": "o", "jax": "^", "numpy": "s"}


def _plot(path: str, results: dict) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    scenes = list(dict.fromkeys(r["scene"] for r in results["rows"]))
    if not scenes:  # a targets-only run has no sweep to plot
        return
    columns = min(4, len(scenes))
    lines_ = math.ceil(len(scenes) / columns)
    fig = Figure(figsize=(4.2 * columns, 3.6 * lines_ + 0.8), layout="constrained")
    FigureCanvasAgg(fig)
    axes = np.atleast_1d(fig.subplots(lines_, columns, squeeze=False)).ravel()
    methods = []
    for ax, name in zip(axes, scenes):
        rows = [r for r in results["rows"] if r["scene"] == name and math.isfinite(r["psnr_db"])]
        for r in rows:
            methods.append(r["method"])
            ax.scatter(r["forward_ms"], r["psnr_db"], color=_COLORS.get(r["method"], "black"), marker=_MARKERS.get(r["backend"], "x"), s=22, alpha=0.85)
        front = pareto_front([(r["forward_ms"], r["psnr_db"]) for r in rows])
        ordered = sorted(front, key=lambda i: rows[i]["forward_ms"])
        ax.step([rows[i]["forward_ms"] for i in ordered], [rows[i]["psnr_db"] for i in ordered], where="post", color="black", lw=0.8, alpha=0.5)
        ax.set_xscale("log")
        # The renderer's accumulation converges to the ground truth (100+ dB): keep the axis on the
        # methods and say how far the renderer's points go.
        ours = [r["psnr_db"] for r in rows if r["backend"] != "numpy"]
        if ours:
            top = max(ours) + 6.0
            ax.set_ylim(min(r["psnr_db"] for r in rows) - 1.0, top)
            beyond = [r["psnr_db"] for r in rows if r["psnr_db"] > top]
            if beyond:
                ax.text(0.02, 0.97, f"renderer accumulation: up to {max(beyond):.0f} dB (off the top)", transform=ax.transAxes, fontsize=7, va="top")
        ax.set_title(f"{name} ({rows[0]['size'] if rows else ''})", fontsize=10)
        ax.set_xlabel("forward time, ms (log)")
        ax.set_ylabel("PSNR vs ground truth, dB")
        ax.grid(True, which="both", alpha=0.3)
    for ax in axes[len(scenes) :]:
        ax.axis("off")
    handles = [Line2D([], [], color=_COLORS.get(m, "black"), marker="o", ls="", label=m) for m in dict.fromkeys(methods)]
    handles += [Line2D([], [], color="black", marker=mk, ls="", label=b) for b, mk in _MARKERS.items()]
    handles += [Line2D([], [], color="black", lw=0.8, alpha=0.5, label="Pareto front")]
    fig.legend(handles=handles, loc="outside lower center", ncol=min(len(handles), 5), fontsize=9)
    m = results["machine"]
    fig.suptitle(f"diffblur: accuracy against forward time per method ({m['cpu']}, {m['cores']} cores, {m['date']})", fontsize=11)
    fig.savefig(path, dpi=80)


#: The headings of the sections this bench writes (`_markdown`); the rest of BENCHMARKS.md is other
#: commands' (the held-out recovery, the physically rendered scenes, compile against eager, soak).
OWN_HEADINGS = ("## Targets", "## Scene `")


def other_sections(path: str) -> str:
    """Everything of the file at `path` from the first section this bench does not write (a `## `
    heading not in OWN_HEADINGS, or a `<!-- ` marker) to the end: what a new run keeps."""
    if not os.path.exists(path):
        return ""
    lines = open(path).read().splitlines()
    for i, line in enumerate(lines):
        if line.startswith("<!-- ") or (line.startswith("## ") and not line.startswith(OWN_HEADINGS)):
            return "\n".join(lines[i:]) + "\n"
    return ""


def replace_section(path: str, heading: str, text: str) -> None:
    """Put `text`, a section that starts with the line `heading` ("## ..."), into the markdown file at
    `path`: in place of the section under that heading (to the next "## "), else at the end. For the
    measurement scripts that keep a section of BENCHMARKS.md."""
    current = open(path).read() if os.path.exists(path) else ""
    start = current.find(heading)
    if start < 0:
        new = current.rstrip() + "\n\n" + text
    else:
        end = current.find("\n## ", start + 1)
        new = current[:start] + text.rstrip() + "\n" + ("" if end < 0 else "\n" + current[end + 1 :])
    with open(path, "w") as f:
        f.write(new)


def _write(out_dir, results: dict) -> None:
    out_dir = os.fspath(out_dir)
    docs = os.path.join(out_dir, "docs")
    os.makedirs(docs, exist_ok=True)
    with open(os.path.join(docs, "benchmarks.json"), "w") as f:
        json.dump(results, f, indent=1, allow_nan=True)
    path = os.path.join(out_dir, "BENCHMARKS.md")
    others = other_sections(path)
    with open(path, "w") as f:
        f.write(_markdown(results) + "\n" + ("" if not others else "\n" + others))
    _plot(os.path.join(docs, "pareto.png"), results)
