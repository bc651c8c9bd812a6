"""What the PyTorch and the JAX model share: the blur's options, the training schedule and the
batches (NumPy), and how a predicted motion becomes the layer's inputs."""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from typing import Callable, Iterator

import numpy as np

__all__ = ["BLUR_OPTIONS", "CANDIDATES", "INPUTS", "LEVELS", "RADIUS", "SHARPNESS", "MIRROR", "MOTION_CHANNELS", "SMOOTHNESS", "EDGE", "TrainConfig", "smoothness", "augment", "batches", "check_size", "learning_rate", "motion_paths", "shutter_batches", "training_loss", "training_loop"]

#: Poolings in the U-Net: H and W must be multiples of 2^LEVELS.
LEVELS = 3
#: Block matching's search radius (pixels of half-spread, each way in x and y) and sharpness: the
#: motion starts from a soft-argmin over (2 RADIUS + 1)^2 candidate velocities (`CANDIDATES`).
RADIUS = 4
SHARPNESS = 100.0
#: The candidate half-spreads (K, 2), x then y, x fastest.
CANDIDATES = np.array([(dx, dy) for dy in range(-RADIUS, RADIUS + 1) for dx in range(-RADIUS, RADIUS + 1)], dtype=np.float32)
#: The U-Net's input channels: the two frames, block matching's velocity (/ RADIUS) and its confidence.
INPUTS = 6 + 2 + 1

#: Channels the U-Net predicts per way of giving the motion.
MOTION_CHANNELS = {"offsets": 4, "velocity": 2}
#: The layer's options per method. The scatter fills the time nothing covers a moving pixel with its
#: own colour: the default push-pull fill reads the still pixels, and a predicted motion has none.
BLUR_OPTIONS = {
    "bezier": {"samples": 8, "fill": "color"},
    "gather": {"samples": 15},
    "reconstruct": {"samples": 15},
}
#: The index in data.SHUTTERS of each window played backwards (a ramp's slope changes sign).
MIRROR = (0, 1, 3, 2)
#: The weight of the motion prior in the training loss (`smoothness`): loss = mean squared error of the
#: blur + SMOOTHNESS x the total variation of the predicted motion. Chosen on the validation split
#: (`data.VALIDATION`, examples of the training seed that no training run reads), see README.md.
SMOOTHNESS = 3e-3
#: The edge-aware variant's strength (`smoothness(..., image, edge=EDGE)`): 0 weighs every pair of
#: neighbours alike.
EDGE = 0.0


def smoothness(motion, image=None, *, edge: float = EDGE):
    """The motion prior: the total variation of the motion (B, C, H, W), in pixels, the mean over channels
    and pixels of |m(x + 1, y) - m(x, y)| plus that of |m(x, y + 1) - m(x, y)|. Plain array arithmetic,
    the same formula for PyTorch tensors, JAX and NumPy arrays.

    The blur alone rewards unphysical per-pixel motion (any path whose blur matches, pixel by pixel);
    objects move as wholes, so the prior favours motion that is constant over a neighbourhood, and L1
    lets it change at once at an object's edge. With `edge` > 0 and `image` (B, 3, H, W), a pair of
    neighbours counts 1 / (1 + edge x |image difference|, mean over colour), less across colour edges."""
    dx = abs(motion[..., :, 1:] - motion[..., :, :-1])
    dy = abs(motion[..., 1:, :] - motion[..., :-1, :])
    if edge and image is not None:
        dx = dx / (1.0 + edge * abs(image[..., :, 1:] - image[..., :, :-1]).mean(1)[:, None])
        dy = dy / (1.0 + edge * abs(image[..., 1:, :] - image[..., :-1, :]).mean(1)[:, None])
    return dx.mean() + dy.mean()


@dataclass(frozen=True)
class TrainConfig:
    """One training run. It stops after `minutes` of training or `steps` steps, whichever is first."""

    method: str = "bezier"
    motion: str = "offsets"
    width: int = 8
    scale: float = 2.0
    #: Add the U-Net's output to block matching's straight path (True) or take it as the motion.
    residual: bool = True
    batch: int = 8
    lr: float = 1e-3
    #: The prior's weight in the loss (`smoothness`, `SMOOTHNESS`); 0: the blur's error alone.
    smoothness: float = SMOOTHNESS
    #: The prior's edge-awareness (`EDGE`); 0: every pair of neighbours alike.
    edge: float = EDGE
    minutes: float = 4.0
    steps: int = 100_000
    seed: int = 0
    log_every: int = 100

    def __post_init__(self) -> None:
        if self.method not in BLUR_OPTIONS:
            raise ValueError(f"method must be one of {', '.join(BLUR_OPTIONS)}, got {self.method!r}")
        if self.motion not in MOTION_CHANNELS:
            raise ValueError(f"motion must be one of {', '.join(MOTION_CHANNELS)}, got {self.motion!r}")
        if self.motion == "offsets" and self.method != "bezier":
            raise ValueError(f"motion='offsets' (curved paths) needs method='bezier', got {self.method!r}")

    def as_dict(self) -> dict:
        return asdict(self)


def check_size(shape) -> None:
    height, width = (int(s) for s in shape)
    step = 2**LEVELS
    if height % step or width % step:
        raise ValueError(f"the U-Net needs H and W that are multiples of {step}, got {height}x{width}")


def learning_rate(peak: float, progress: float) -> float:
    """A short warm-up, then a cosine from `peak` down to peak / 20 at progress 1."""
    progress = min(max(progress, 0.0), 1.0)
    warm = min(1.0, progress / 0.03)
    return peak * warm * (0.05 + 0.95 * 0.5 * (1.0 + math.cos(math.pi * progress)))


def linear_motion(motion: str, velocity, concatenate):
    """Block matching's velocity as the network's base motion: offsets (-v, +v) or v itself."""
    return concatenate([-velocity, velocity]) if motion == "offsets" else velocity


def training_loss(blur_error, motion, color, config: "TrainConfig"):
    """What both frameworks minimise: the blur's mean squared error `blur_error` plus the motion prior
    on the predicted `motion` (the edge-aware variant reads the middle frame `color`)."""
    if not config.smoothness:
        return blur_error
    return blur_error + config.smoothness * smoothness(motion, color, edge=config.edge)


def motion_paths(method: str, motion: str, predicted) -> dict:
    """The layer's path inputs from the U-Net's output (any array type): offsets (prev, next) or a velocity."""
    if motion == "offsets":
        return {"offset_prev": predicted[:, 0:2], "offset_next": predicted[:, 2:4]}
    return {"velocity": predicted}


def augment(arrays: dict, rng: np.random.Generator, shutter: int) -> tuple[dict, int]:
    """A random symmetry of the square (flips, transpose: exact for the renderer's pixel grid) and, half
    the time, time reversed: the input frames swap and the shutter is played backwards. Offsets, where
    present, follow."""
    out = dict(arrays)
    if rng.random() < 0.5:
        for name, value in out.items():
            out[name] = value.swapaxes(-1, -2)
        for name in ("offset_prev", "offset_next"):
            if name in out:
                out[name] = out[name][:, ::-1]
    for axis, channel in ((-1, 0), (-2, 1)):
        if rng.random() < 0.5:
            for name, value in out.items():
                out[name] = np.flip(value, axis)
            for name in ("offset_prev", "offset_next"):
                if name in out:
                    out[name] = out[name].copy()
                    out[name][:, channel] *= -1
    if rng.random() < 0.5:
        frames = out["frames"]
        out["frames"] = np.concatenate([frames[:, 3:], frames[:, :3]], axis=1)
        if "offset_prev" in out:
            out["offset_prev"], out["offset_next"] = out["offset_next"], out["offset_prev"]
        shutter = MIRROR[shutter]
    return {name: np.ascontiguousarray(value) for name, value in out.items()}, shutter


def batches(data: dict, config: TrainConfig) -> Iterator[tuple[dict, int]]:
    """Endless training batches: a shutter drawn in proportion to its examples, `batch` of its examples
    (without replacement within an epoch of that shutter), augmented. Yields (arrays, shutter) with
    arrays frames, color, depth and target."""
    rng = np.random.default_rng(config.seed)
    groups = {int(s): np.flatnonzero(data["shutter"] == s) for s in np.unique(data["shutter"])}
    shutters = np.array(sorted(groups))
    weights = np.array([len(groups[s]) for s in shutters], np.float64)
    queues: dict[int, list[int]] = {s: [] for s in groups}
    while True:
        shutter = int(rng.choice(shutters, p=weights / weights.sum()))
        if len(queues[shutter]) < config.batch:
            queues[shutter] = list(rng.permutation(groups[shutter])) + queues[shutter]
        index = np.array(sorted(queues[shutter][-config.batch :]))
        del queues[shutter][-config.batch :]
        arrays = {name: data[name][index] for name in ("frames", "color", "depth", "target")}
        yield augment(arrays, rng, shutter)


def training_loop(data: dict, config: TrainConfig, step: Callable[[dict, int, float], float], *, label: str, log=print) -> dict:
    """The loop both frameworks train with: `step(arrays, shutter, lr)` takes one optimiser step on a
    batch of `batches` and returns its loss. The learning rate follows `learning_rate` over the
    progress, the larger of the steps' and the time's share of their budgets; the loop stops when
    either is spent. Returns the history: step, seconds and mean loss every config.log_every steps,
    and the totals (steps, train_seconds)."""
    history = {"step": [], "seconds": [], "loss": []}
    started = time.perf_counter()
    count, running = 0, []
    for count, (arrays, shutter) in enumerate(batches(data, config), start=1):
        progress = max(count / config.steps, (time.perf_counter() - started) / (60 * config.minutes))
        lr = learning_rate(config.lr, progress)
        running.append(step(arrays, shutter, lr))
        if count % config.log_every == 0 or progress >= 1:
            seconds = time.perf_counter() - started
            history["step"].append(count), history["seconds"].append(seconds), history["loss"].append(float(np.mean(running)))
            if log is not None:
                log(f"{label:5s} step {count:5d}  {seconds:6.0f} s  loss {np.mean(running):.3e}  lr {lr:.1e}")
            running = []
        if progress >= 1:
            break
    history["steps"], history["train_seconds"] = count, time.perf_counter() - started
    return history


def shutter_batches(data: dict, batch: int) -> Iterator[tuple[int, np.ndarray]]:
    """Every example once, for prediction: (shutter, indices) in batches of at most `batch` that share a shutter."""
    for shutter in np.unique(data["shutter"]):
        members = np.flatnonzero(data["shutter"] == shutter)
        for start in range(0, len(members), batch):
            yield int(shutter), members[start : start + batch]
