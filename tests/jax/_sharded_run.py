"""Run by tests/jax/test_sharding.py in a subprocess whose XLA_FLAGS give 2 host devices.

Runs the JAX ops batch-sharded over a 2-device mesh (jax.sharding, the engine's own SPMD
partitioner) and unsharded on one device, and prints one JSON line: per op the largest
difference, and the batch size of each device's shard of the output.
"""

from __future__ import annotations

import json
import time

import jax

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")
jax.config.update("jax_numpy_rank_promotion", "raise")

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from jax.sharding import NamedSharding  # noqa: E402
from jax.sharding import PartitionSpec as P  # noqa: E402

import jax_impl  # noqa: E402


def inputs():
    rng = np.random.default_rng(0)
    shape = (4, 3, 12, 13)
    return (
        rng.random(shape),
        rng.normal(size=(4, 2, 12, 13)) * 3.0,
        rng.uniform(1.0, 2.0, size=(4, 1, 12, 13)),
    )


def layer_loss(exposure, color, velocity):
    layer = jax_impl.MotionBlur("gather", samples=5, exposure=0.8, learn_exposure=True)
    layer = eqx.tree_at(lambda m: m.exposure, layer, exposure)
    return jnp.mean(layer(color, velocity) ** 2)


OPS = {
    # The fused CPU kernels run on the host as one piece (pure_callback gathers the batch): sharded
    # runs take the tensor ops.
    "reconstruct": lambda c, v, z: jax_impl.reconstruct(c, v, z, samples=5, max_radius=4.0, impl="tensor"),
    "bezier_scatter": lambda c, v, z: jax_impl.bezier_scatter(c, z, -v, v, samples=5, impl="tensor"),
    # A training step's gradient: the layer's exposure, a mean over the sharded batch.
    "grad MotionBlur": lambda c, v, z: jax.grad(layer_loss)(jnp.asarray(0.8), c, v),
}


def main() -> None:
    devices = jax.devices()
    # Auto axes: XLA propagates the batch sharding through the op (GSPMD). With Explicit axes
    # (sharding in types) tile_max's reshape would need an out_sharding, which the ops do not give.
    mesh = jax.make_mesh((len(devices),), ("batch",), axis_types=(jax.sharding.AxisType.Auto,))
    sharded = NamedSharding(mesh, P("batch"))
    host = [jnp.asarray(a) for a in inputs()]
    on_one = [jax.device_put(a, devices[0]) for a in host]
    on_mesh = [jax.device_put(a, sharded) for a in host]
    report = {"devices": len(devices), "ops": {}}
    for name, fn in OPS.items():
        started, cpu_started = time.perf_counter(), time.process_time()
        compiled = jax.jit(fn)
        single = compiled(*on_one)
        split = compiled(*on_mesh)
        leaves_single, leaves_split = jax.tree.leaves(single), jax.tree.leaves(split)
        report["ops"][name] = {
            "max_difference": max(float(jnp.max(jnp.abs(a - jax.device_put(b, devices[0])))) for a, b in zip(leaves_single, leaves_split)),
            # Batched leaves only (the exposure's gradient is a replicated scalar).
            "shard_batches": sorted({s.data.shape[0] for leaf in leaves_split if leaf.ndim == 4 for s in leaf.addressable_shards}),
            "output_devices": len(leaves_split[-1].sharding.device_set),
            "cpu_seconds": round(time.process_time() - cpu_started, 2),
            "seconds": round(time.perf_counter() - started, 2),
        }
    print(json.dumps(report))


if __name__ == "__main__":
    main()
