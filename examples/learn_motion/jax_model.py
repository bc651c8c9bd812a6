"""The JAX model (Equinox + optax): the same U-Net as `torch_model.py` and `jax_impl.MotionBlur`.

The U-Net works on one example (C, H, W), as Equinox layers do; `MotionNet` maps it over the batch
with `jax.vmap` and blurs the batch with the layer. `from_torch` loads a PyTorch `MotionNet`'s
weights (as NumPy arrays, by name), so that the two frameworks can be compared on the same weights.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

import jax_impl
from examples.learn_motion.common import BLUR_OPTIONS, CANDIDATES, INPUTS, LEVELS, RADIUS, SHARPNESS, linear_motion, MOTION_CHANNELS, TrainConfig, check_size, motion_paths, shutter_batches, training_loop, training_loss
from examples.learn_motion.data import SHUTTERS

__all__ = ["MotionNet", "UNet", "block_matching", "from_torch", "loss_fn", "make_model", "matching_costs", "predict", "train", "train_step"]


class _Block(eqx.Module):
    """Two 3x3 convolutions, each followed by a ReLU."""

    first: eqx.nn.Conv2d
    second: eqx.nn.Conv2d

    def __init__(self, cin: int, cout: int, *, key, dtype):
        k1, k2 = jax.random.split(key)
        self.first = eqx.nn.Conv2d(cin, cout, 3, padding=1, key=k1, dtype=dtype)
        self.second = eqx.nn.Conv2d(cout, cout, 3, padding=1, key=k2, dtype=dtype)

    def __call__(self, x):
        return jax.nn.relu(self.second(jax.nn.relu(self.first(x))))


def _pool(x):
    c, h, w = x.shape
    return x.reshape(c, h // 2, 2, w // 2, 2).mean(axis=(2, 4))


def _upsample(x):
    return jnp.repeat(jnp.repeat(x, 2, axis=1), 2, axis=2)


def matching_costs(frames, radius: int = RADIUS):
    """`torch_model.matching_costs` for one example: frames (6, H, W) -> ((2 radius + 1)^2, H, W)."""
    height, width = frames.shape[-2:]
    pad = ((0, 0), (radius, radius), (radius, radius))
    before, after = jnp.pad(frames[:3], pad, mode="edge"), jnp.pad(frames[3:], pad, mode="edge")
    costs = []
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            a = before[:, radius - dy : radius - dy + height, radius - dx : radius - dx + width]
            b = after[:, radius + dy : radius + dy + height, radius + dx : radius + dx + width]
            costs.append(-jnp.mean(jnp.abs(a - b), axis=0, keepdims=True))
    return jnp.concatenate(costs, axis=0)


def block_matching(frames):
    """`torch_model.block_matching` for one example: (velocity (2, H, W), confidence (1, H, W))."""
    costs = matching_costs(frames)
    weights = jax.nn.softmax(SHARPNESS * costs, axis=0)
    velocity = jnp.einsum("khw,kc->chw", weights, jnp.asarray(CANDIDATES, dtype=weights.dtype))
    return velocity, jnp.max(costs, axis=0, keepdims=True)


class UNet(eqx.Module):
    """inputs (INPUTS, H, W) -> (out, H, W): `torch_model.UNet`'s architecture, one example (the head
    zero at initialisation)."""

    down: list
    up: list
    head: eqx.nn.Conv2d
    scale: float = eqx.field(static=True)

    def __init__(self, out: int, *, width: int = 16, scale: float = 4.0, inputs: int = INPUTS, key, dtype=jnp.float32):
        widths = [width * min(2**k, 4) for k in range(LEVELS + 1)]
        keys = jax.random.split(key, 2 * LEVELS + 2)
        self.down = [_Block(inputs, widths[0], key=keys[0], dtype=dtype)] + [
            _Block(widths[k - 1], widths[k], key=keys[k], dtype=dtype) for k in range(1, LEVELS + 1)
        ]
        self.up = [_Block(widths[k + 1] + widths[k], widths[k], key=keys[LEVELS + 1 + i], dtype=dtype) for i, k in enumerate(reversed(range(LEVELS)))]
        head = eqx.nn.Conv2d(widths[0], out, 1, key=keys[-1], dtype=dtype)
        self.head = eqx.tree_at(lambda c: (c.weight, c.bias), head, (jnp.zeros_like(head.weight), jnp.zeros_like(head.bias)))
        self.scale = scale

    def __call__(self, x):
        skips = []
        for k, block in enumerate(self.down):
            x = block(_pool(x) if k else x)
            skips.append(x)
        for block, skip in zip(self.up, reversed(skips[:-1])):
            x = block(jnp.concatenate([_upsample(x), skip], axis=0))
        return self.scale * self.head(x)


class MotionNet(eqx.Module):
    """`torch_model.MotionNet` in Equinox: block matching and the U-Net (vmapped over the batch) and
    one `jax_impl.MotionBlur` per window of `data.SHUTTERS`; a batch shares one (a static int)."""

    unet: UNet
    blurs: tuple
    method: str = eqx.field(static=True)
    motion: str = eqx.field(static=True)
    residual: bool = eqx.field(static=True)

    def __init__(self, method: str = "bezier", motion: str = "offsets", *, width: int = 8, scale: float = 2.0, residual: bool = True, key, dtype=jnp.float32):
        self.method, self.motion, self.residual = method, motion, residual
        self.unet = UNet(MOTION_CHANNELS[motion], width=width, scale=scale, key=key, dtype=dtype)
        self.blurs = tuple(jax_impl.MotionBlur(method, shutter=window, **BLUR_OPTIONS[method]) for window in SHUTTERS)

    def __call__(self, frames, color, depth, shutter: int = 0, motion=None):
        """(blurred middle frame (B, 3, H, W), predicted motion (B, 2 or 4, H, W)); a given `motion`
        replaces the U-Net's."""
        check_size(frames.shape[-2:])
        if motion is None:
            motion = jax.vmap(self.motion_from)(frames).astype(color.dtype)
        paths = motion_paths(self.method, self.motion, motion)
        return self.blurs[shutter](color, paths.pop("velocity", None), depth if self.method != "gather" else None, **paths), motion


    def motion_from(self, frames):
        """One example's motion (4 or 2, H, W): block matching's, corrected by the U-Net."""
        velocity, confidence = block_matching(frames)
        correction = self.unet(jnp.concatenate([frames, velocity / RADIUS, 10.0 * confidence], axis=0))
        if not self.residual:
            return correction
        return linear_motion(self.motion, velocity, lambda parts: jnp.concatenate(parts, axis=0)) + correction


def from_torch(state: dict, config: TrainConfig, dtype=jnp.float32) -> MotionNet:
    """A MotionNet holding a PyTorch MotionNet's weights: `state` maps the torch parameter names
    (`model.state_dict()` as NumPy arrays) to arrays."""
    model = MotionNet(config.method, config.motion, width=config.width, scale=config.scale, residual=config.residual, key=jax.random.key(0), dtype=dtype)

    def conv(prefix: str, layer: eqx.nn.Conv2d) -> eqx.nn.Conv2d:
        weight = jnp.asarray(state[f"{prefix}.weight"], dtype=dtype)
        bias = jnp.asarray(state[f"{prefix}.bias"], dtype=dtype).reshape(layer.bias.shape)
        return eqx.tree_at(lambda c: (c.weight, c.bias), layer, (weight, bias))

    def block(prefix: str, b: _Block) -> _Block:  # torch's Sequential: conv 0, ReLU 1, conv 2, ReLU 3
        return eqx.tree_at(lambda x: (x.first, x.second), b, (conv(f"{prefix}.0", b.first), conv(f"{prefix}.2", b.second)))

    unet = model.unet
    unet = eqx.tree_at(lambda u: u.down, unet, [block(f"unet.down.{k}", b) for k, b in enumerate(unet.down)])
    unet = eqx.tree_at(lambda u: u.up, unet, [block(f"unet.up.{k}", b) for k, b in enumerate(unet.up)])
    unet = eqx.tree_at(lambda u: u.head, unet, conv("unet.head", unet.head))
    return eqx.tree_at(lambda m: m.unet, model, unet)


def loss_fn(model: MotionNet, frames, color, depth, target, shutter: int, config: TrainConfig = TrainConfig()):
    """`torch_model.loss_fn`: the mean squared error of the blurred middle frame against the blurred
    target, plus config.smoothness x the total variation of the predicted motion (`common.training_loss`)."""
    blurred, motion = model(frames, color, depth, shutter)
    return training_loss(jnp.mean((blurred - target) ** 2), motion, color, config)


@eqx.filter_jit
def train_step(model, state, optimizer, frames, color, depth, target, shutter: int, lr, config: TrainConfig = TrainConfig()):
    """One Adam step on `loss_fn` (the learning rate `lr` is data, so that the schedule does not
    recompile; `config`, a static dataclass, gives the prior's weight)."""
    loss, grads = eqx.filter_value_and_grad(loss_fn)(model, frames, color, depth, target, shutter, config)
    state.hyperparams["learning_rate"] = lr
    updates, state = optimizer.update(grads, state, eqx.filter(model, eqx.is_inexact_array))
    return eqx.apply_updates(model, updates), state, loss


def make_optimizer(lr: float):
    return optax.inject_hyperparams(optax.adam)(learning_rate=lr)


def make_model(config: TrainConfig, dtype=jnp.float32) -> MotionNet:
    """The model before training (seeded by config.seed)."""
    return MotionNet(config.method, config.motion, width=config.width, scale=config.scale, residual=config.residual, key=jax.random.key(config.seed), dtype=dtype)


def train(data: dict, config: TrainConfig, *, log=print, dtype=jnp.float32) -> tuple[MotionNet, dict]:
    """`torch_model.train` in JAX: the same loop (`common.training_loop`: batches, schedule, stopping rule)."""
    model = make_model(config, dtype)
    optimizer = make_optimizer(config.lr)
    carry = {"model": model, "state": optimizer.init(eqx.filter(model, eqx.is_inexact_array))}

    def step(arrays: dict, shutter: int, lr: float) -> float:
        frames, color, depth, target = (jnp.asarray(arrays[name], dtype=dtype) for name in ("frames", "color", "depth", "target"))
        carry["model"], carry["state"], loss = train_step(carry["model"], carry["state"], optimizer, frames, color, depth, target, shutter, jnp.asarray(lr, dtype=dtype), config)
        return float(loss)

    history = training_loop(data, config, step, label="jax", log=log)
    return carry["model"], history


@eqx.filter_jit
def _forward(model, frames, color, depth, shutter: int, motion):
    return model(frames, color, depth, shutter, motion)


def predict(model: MotionNet, data: dict, *, motion: np.ndarray | None = None, batch: int = 16, dtype=jnp.float32) -> tuple[np.ndarray, np.ndarray]:
    """The model on every example (grouped by shutter, in batches of `batch`, the last one padded so
    that every call has one shape): (blurred (N, 3, H, W), motion (N, 2 or 4, H, W)). With `motion`,
    the layers blur by it instead of the U-Net's."""
    count = len(data["shutter"])
    blurred = np.zeros(data["color"].shape, np.float32)
    out_motion = np.zeros((count, MOTION_CHANNELS[model.motion]) + data["color"].shape[2:], np.float32)
    for shutter, index in shutter_batches(data, batch):
        padded = np.concatenate([index, np.repeat(index[-1:], batch - len(index))])
        inputs = (jnp.asarray(data[name][padded], dtype=dtype) for name in ("frames", "color", "depth"))
        given = None if motion is None else jnp.asarray(motion[padded], dtype=dtype)
        out, predicted = _forward(model, *inputs, shutter, given)
        blurred[index], out_motion[index] = np.asarray(out)[: len(index)], np.asarray(predicted)[: len(index)]
    return blurred, out_motion
