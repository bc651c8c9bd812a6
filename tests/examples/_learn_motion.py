"""What the tests of examples/learn_motion share: a few tiny scenes drawn with a seed of the tests' own."""

from __future__ import annotations

import functools

import numpy as np

from examples.learn_motion.common import TrainConfig
from examples.learn_motion.data import dataset

#: A U-Net 4 channels wide; scenes of 16 x 16 pixels.
CONFIG = TrainConfig(width=4, batch=4)
SIZE = 16
#: The tests' scenes: a seed of their own (not the example's training or test seed).
SEED = 3


@functools.lru_cache(maxsize=1)
def _scenes() -> dict:
    return dataset(SEED, 4, SIZE, log=None)


def scenes(shutter: int | None = None) -> dict:
    """4 scenes, each with its own motion; `shutter` replaces their windows by one (a batch shares one)."""
    data = {name: value.copy() for name, value in _scenes().items()}
    if shutter is not None:
        data["shutter"][:] = shutter
    return data


def jax_model(dtype=None):
    """The example's JAX model, its head drawn at random (it starts at zero)."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    from examples.learn_motion.jax_model import MotionNet

    net = MotionNet(CONFIG.method, CONFIG.motion, width=CONFIG.width, scale=CONFIG.scale, key=jax.random.key(0), dtype=dtype or jnp.float64)
    weight = 0.3 * jax.random.normal(jax.random.key(1), net.unet.head.weight.shape, dtype=net.unet.head.weight.dtype)
    return eqx.tree_at(lambda m: m.unet.head.weight, net, weight)


def different_motions(data: dict) -> bool:
    """Every two examples of the batch move differently somewhere."""
    motion = np.concatenate([data["offset_prev"], data["offset_next"]], axis=1)
    return all(np.abs(motion[i] - motion[j]).max() > 0.5 for i in range(len(motion)) for j in range(i))
