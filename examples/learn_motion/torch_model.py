"""The PyTorch model: a small U-Net predicts per-pixel motion from two sharp frames, and the library's
`torch_impl.MotionBlur` layer blurs the middle frame with it. Trained against the blurred target
(and a smoothness prior on the motion), never against the true motion.

`jax_model.py` is the same architecture in Equinox; `copy_to_jax` there moves these weights across.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

import torch_impl
from examples.learn_motion.common import (
    BLUR_OPTIONS,
    CANDIDATES,
    INPUTS,
    LEVELS,
    RADIUS,
    SHARPNESS,
    MOTION_CHANNELS,
    TrainConfig,
    check_size,
    linear_motion,
    motion_paths,
    shutter_batches,
    training_loop,
    training_loss,
)
from examples.learn_motion.data import SHUTTERS

__all__ = ["MotionNet", "UNet", "block_matching", "loss_fn", "make_model", "matching_costs", "predict", "train"]


class _Block(nn.Sequential):
    """Two 3x3 convolutions, each followed by a ReLU."""

    def __init__(self, cin: int, cout: int):
        super().__init__(nn.Conv2d(cin, cout, 3, padding=1), nn.ReLU(), nn.Conv2d(cout, cout, 3, padding=1), nn.ReLU())


def matching_costs(frames: torch.Tensor, radius: int = RADIUS) -> torch.Tensor:
    """(B, (2 radius + 1)^2, H, W): for each candidate half-spread v (integer pixels, |vx|, |vy| <=
    radius, x fastest), minus the mean absolute difference between frame t = -1 at X - v and frame
    t = +1 at X + v (edges repeated): near 0 where v carries the point seen at X in the middle frame."""
    before = F.pad(frames[:, :3], (radius,) * 4, mode="replicate")
    after = F.pad(frames[:, 3:], (radius,) * 4, mode="replicate")
    height, width = frames.shape[-2:]
    costs = []
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            a = before[:, :, radius - dy : radius - dy + height, radius - dx : radius - dx + width]
            b = after[:, :, radius + dy : radius + dy + height, radius + dx : radius + dx + width]
            costs.append(-(a - b).abs().mean(dim=1, keepdim=True))
    return torch.cat(costs, dim=1)


def block_matching(frames: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """A parameter-free first guess: the soft-argmin velocity over CANDIDATES (B, 2, H, W), the mean
    of the candidates weighted by softmax(SHARPNESS x cost), so about 0 where nothing matches better
    than the rest (flat texture), and its confidence, the best cost (B, 1, H, W), <= 0."""
    costs = matching_costs(frames).float()
    weights = torch.softmax(SHARPNESS * costs, dim=1)
    velocity = torch.einsum("bkhw,kc->bchw", weights, torch.from_numpy(CANDIDATES).to(weights.device))
    return velocity, costs.amax(dim=1, keepdim=True)


class UNet(nn.Module):
    """inputs (B, INPUTS, H, W) -> (B, out, H, W), H and W multiples of 2^LEVELS.

    Encoder: a block per level with widths width * (1, 2, 4, 4), 2x2 average pooling between them;
    decoder: nearest 2x upsampling, concatenation with the encoder's features of that size, a block;
    a 1x1 head scaled by `scale` (pixels), zero at initialisation."""

    def __init__(self, out: int, *, width: int = 16, scale: float = 4.0, inputs: int = INPUTS):
        super().__init__()
        widths = [width * min(2**k, 4) for k in range(LEVELS + 1)]
        self.down = nn.ModuleList([_Block(inputs, widths[0])] + [_Block(widths[k - 1], widths[k]) for k in range(1, LEVELS + 1)])
        self.up = nn.ModuleList([_Block(widths[k + 1] + widths[k], widths[k]) for k in reversed(range(LEVELS))])
        self.head = nn.Conv2d(widths[0], out, 1)
        nn.init.zeros_(self.head.weight), nn.init.zeros_(self.head.bias)
        self.scale = scale

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for k, block in enumerate(self.down):
            if k:
                x = F.avg_pool2d(x, 2)
            x = block(x)
            skips.append(x)
        for block, skip in zip(self.up, reversed(skips[:-1])):
            x = block(torch.cat([F.interpolate(x, scale_factor=2, mode="nearest"), skip], dim=1))
        return self.scale * self.head(x)


class MotionNet(nn.Module):
    """Block matching, the U-Net and one `MotionBlur` layer per shutter window of `data.SHUTTERS` (a
    batch shares one). The U-Net reads the two frames and block matching's velocity and confidence,
    and adds its correction to block matching's straight path.

    method: "bezier" (the curve scatter), "gather" or "reconstruct"; motion: "offsets" (the U-Net
    predicts p(-1) - X and p(+1) - X, a curved path through the middle frame; bezier only) or
    "velocity" (the half-spread V, the segment X - V ... X + V). The blur runs in the colour's dtype
    (under autocast the U-Net runs in bfloat16, the blur in float32)."""

    def __init__(self, method: str = "bezier", motion: str = "offsets", *, width: int = 8, scale: float = 2.0, residual: bool = True):
        super().__init__()
        self.method, self.motion, self.residual = method, motion, residual
        self.unet = UNet(MOTION_CHANNELS[motion], width=width, scale=scale)
        self.blurs = nn.ModuleList([torch_impl.MotionBlur(method, shutter=window, **BLUR_OPTIONS[method]) for window in SHUTTERS])

    def forward(self, frames: torch.Tensor, color: torch.Tensor, depth: torch.Tensor, shutter: int = 0, motion: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(blurred middle frame (B, 3, H, W), predicted motion (B, 2 or 4, H, W)); a given `motion`
        replaces the U-Net's (the report blurs by the true motion through the same layers)."""
        check_size(frames.shape[-2:])
        if motion is None:
            motion = self.motion_from(frames).to(color.dtype)
        paths = motion_paths(self.method, self.motion, motion)
        return self.blurs[shutter](color, paths.pop("velocity", None), depth if self.method != "gather" else None, **paths), motion

    def motion_from(self, frames: torch.Tensor) -> torch.Tensor:
        """The predicted motion (B, 4 or 2, H, W): block matching's, corrected by the U-Net."""
        velocity, confidence = block_matching(frames)
        correction = self.unet(torch.cat([frames, velocity / RADIUS, 10.0 * confidence], dim=1))
        if not self.residual:
            return correction
        return linear_motion(self.motion, velocity, lambda parts: torch.cat(parts, dim=1)) + correction


def _tensors(arrays: dict, device, index=slice(None)) -> tuple[torch.Tensor, ...]:
    return tuple(torch.from_numpy(np.ascontiguousarray(arrays[name][index])).to(device) for name in ("frames", "color", "depth", "target"))


def make_model(config: TrainConfig, device: str = "cpu") -> MotionNet:
    """The model before training (seeded by config.seed)."""
    torch.manual_seed(config.seed)
    return MotionNet(config.method, config.motion, width=config.width, scale=config.scale, residual=config.residual).to(device)


def loss_fn(model: MotionNet, frames, color, depth, target, shutter: int, config: TrainConfig) -> torch.Tensor:
    """The training loss (`common.training_loss`): the mean squared error of the blurred middle frame
    against the blurred target, plus config.smoothness x the total variation of the predicted motion."""
    blurred, motion = model(frames, color, depth, shutter)
    return training_loss(((blurred - target) ** 2).mean(), motion, color, config)


def train(data: dict, config: TrainConfig, *, device: str = "cpu", log=print) -> tuple[MotionNet, dict]:
    """Adam on `loss_fn` (the blur's error against the blurred target and the motion prior), for
    config.minutes or config.steps, whichever ends first (`common.training_loop`). Returns the model
    and the history."""
    model = make_model(config, device)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)

    def step(arrays: dict, shutter: int, lr: float) -> float:
        for group in optimizer.param_groups:
            group["lr"] = lr
        frames, color, depth, target = _tensors(arrays, device)
        loss = loss_fn(model, frames, color, depth, target, shutter, config)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        return loss.item()

    return model, training_loop(data, config, step, label="torch", log=log)


@torch.no_grad()
def predict(model: MotionNet, data: dict, *, motion: np.ndarray | None = None, batch: int = 16, device: str = "cpu") -> tuple[np.ndarray, np.ndarray]:
    """The model on every example (grouped by shutter): (blurred (N, 3, H, W), motion (N, 2 or 4, H, W)).
    With `motion` (N, 2 or 4, H, W), the layers blur by it instead of the U-Net's."""
    count = len(data["shutter"])
    blurred = np.zeros(data["color"].shape, np.float32)
    out_motion = np.zeros((count, MOTION_CHANNELS[model.motion]) + data["color"].shape[2:], np.float32)
    for shutter, index in shutter_batches(data, batch):
        frames, color, depth, _ = _tensors(data, device, index)
        given = None if motion is None else torch.from_numpy(np.ascontiguousarray(motion[index], dtype=np.float32)).to(device)
        out, predicted = model(frames, color, depth, shutter, given)
        blurred[index], out_motion[index] = out.float().cpu().numpy(), predicted.float().cpu().numpy()
    return blurred, out_motion
