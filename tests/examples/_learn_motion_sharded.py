"""Run by tests/examples/test_learn_motion_jax.py in a subprocess whose XLA_FLAGS give 2 host devices.

One `jax_model.train_step` (Adam) of the example's model on a batch of 4 different motions, on one
device and with the batch sharded over a 2-device mesh (Auto axes, docs/scaling.md); prints one JSON
line: the loss and largest parameter difference, how far the step moved the parameters, and the
batch size of each device's shard of the blurred output.
"""

from __future__ import annotations

import json
import time

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)  # standard dtype promotion: optax's Adam raises an int count to a power

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
from jax.sharding import NamedSharding  # noqa: E402
from jax.sharding import PartitionSpec as P  # noqa: E402

from examples.learn_motion.jax_model import make_optimizer, train_step  # noqa: E402
from tests.examples._learn_motion import jax_model, scenes  # noqa: E402

SHUTTER = 2


def main() -> None:
    devices = jax.devices()
    mesh = jax.make_mesh((len(devices),), ("batch",), axis_types=(jax.sharding.AxisType.Auto,))
    data = scenes(shutter=SHUTTER)
    host = [jnp.asarray(data[name], dtype=jnp.float64) for name in ("frames", "color", "depth", "target")]
    net = jax_model(jnp.float64)
    optimizer = make_optimizer(1e-2)
    lr = jnp.asarray(1e-2, dtype=jnp.float64)
    results, seconds = {}, {}
    for name, placement in (("one", devices[0]), ("sharded", NamedSharding(mesh, P("batch")))):
        batch = [jax.device_put(a, placement) for a in host]
        state = optimizer.init(eqx.filter(net, eqx.is_inexact_array))
        started = time.perf_counter()
        stepped, _, loss = train_step(net, state, optimizer, *batch, SHUTTER, lr)
        results[name] = (stepped, float(loss))
        seconds[name] = round(time.perf_counter() - started, 1)
    started = time.perf_counter()
    blurred, _ = eqx.filter_jit(lambda m, *a: m(*a, SHUTTER))(net, *batch[:3])  # the sharded batch
    seconds["sharded forward"] = round(time.perf_counter() - started, 1)
    params = [jax.tree.leaves(eqx.filter(results[k][0], eqx.is_inexact_array)) for k in ("one", "sharded")]
    before = jax.tree.leaves(eqx.filter(net, eqx.is_inexact_array))
    report = {
        "devices": len(devices),
        "loss": results["one"][1],
        "loss_difference": abs(results["one"][1] - results["sharded"][1]),
        "max_parameter_difference": max(float(jnp.max(jnp.abs(a - jax.device_put(b, devices[0])))) for a, b in zip(*params)),
        "max_parameter_change": max(float(jnp.max(jnp.abs(a - b))) for a, b in zip(params[0], before)),
        "shard_batches": sorted({s.data.shape[0] for s in blurred.addressable_shards}),
        "seconds": seconds,
    }
    print(json.dumps(report))


if __name__ == "__main__":
    main()
