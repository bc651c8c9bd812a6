"""examples/learn_motion's JAX model (Equinox U-Net + jax_impl.MotionBlur) in a training loop:
`jax.jit` + `jax.vmap` of the whole model, and a training step on a batch sharded over 2 host devices.

tests/jax/test_transforms.py holds the ops' gradients under jit, vmap and checkpoint,
tests/equivalence/test_module.py the layer alone under jit and vmap, tests/jax/test_sharding.py the
ops and the layer's exposure gradient sharded; here the whole model and its optimiser step do.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from tests.examples._learn_motion import different_motions, jax_model, scenes

ROOT = Path(__file__).resolve().parents[2]
NAMES = ("frames", "color", "depth", "target")


def loss_and_blur(net, frames, color, depth, target, shutter: int):
    blurred, _ = net(frames, color, depth, shutter)
    return jnp.mean((blurred - target) ** 2), blurred


def test_jit_and_vmap_of_the_whole_model_equal_the_batched_model():
    """Per-example gradients by jax.jit(jax.vmap(grad)) over a batch of four different motions (each
    example a batch of one inside): their mean is the batch's gradient, and each example's blur is its
    row of the batch's blur (float64, 1e-12)."""
    data = scenes(shutter=2)
    assert different_motions(data)
    batch = [jnp.asarray(data[name], dtype=jnp.float64) for name in NAMES]
    net = jax_model()
    grad = eqx.filter_value_and_grad(loss_and_blur, has_aux=True)
    (loss, blurred), grads = eqx.filter_jit(grad)(net, *batch, 2)

    def one(frames, color, depth, target):
        return grad(net, frames[None], color[None], depth[None], target[None], 2)

    (losses, blurred_each), grads_each = jax.jit(jax.vmap(one))(*batch)
    np.testing.assert_allclose(np.asarray(blurred_each)[:, 0], np.asarray(blurred), rtol=0, atol=1e-12)
    np.testing.assert_allclose(float(jnp.mean(losses)), float(loss), rtol=1e-12)
    leaves, leaves_each = jax.tree.leaves(eqx.filter(grads, eqx.is_inexact_array)), jax.tree.leaves(eqx.filter(grads_each, eqx.is_inexact_array))
    assert len(leaves) == len(leaves_each) == 2 * 2 * 7 + 2  # 7 blocks of 2 convolutions and the head, weights and biases
    for g, each in zip(leaves, leaves_each):
        assert float(jnp.abs(g).max()) > 0
        np.testing.assert_allclose(np.asarray(jnp.mean(each, axis=0)), np.asarray(g), rtol=1e-9, atol=1e-13)


def test_a_training_step_on_a_batch_sharded_over_two_devices_equals_one_device():
    """jax_model.train_step (loss, gradient and the optax Adam update, under eqx.filter_jit) with the
    batch sharded over 2 host devices gives the one-device step (float64). XLA_FLAGS with 2 host
    devices must be set before JAX starts: it runs in a subprocess (tests/examples/_learn_motion_sharded.py)."""
    flags = (os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2").strip()
    # EQX_ON_ERROR=nan (docs/scaling.md): the data checks would gather the batch. Set for the
    # subprocess only: the suite imports the script for its doctests.
    env = {**os.environ, "XLA_FLAGS": flags, "PYTHONPATH": str(ROOT), "JAX_PLATFORMS": "cpu", "EQX_ON_ERROR": "nan"}
    run = subprocess.run([sys.executable, "-m", "tests.examples._learn_motion_sharded"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    report = json.loads(run.stdout.strip().splitlines()[-1])
    assert report["devices"] == 2
    assert report["shard_batches"] == [2], report  # each device held half the batch of 4
    assert report["loss_difference"] <= 1e-12 * report["loss"], report
    assert report["max_parameter_difference"] <= 1e-12 and report["max_parameter_change"] > 1e-4, report
