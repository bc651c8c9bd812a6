"""Run by tests/jax/test_sharding_fused.py in a subprocess whose XLA_FLAGS give 2 host devices.

Each op that has a fused CPU kernel, with `impl="fused"` on the sharded batch (the error it raised),
and `bezier_scatter` on its default path (`impl="auto"`), forward and gradient under `jax.jit`,
batch-sharded over the 2 devices and on one device (the other two ops' tensor paths are sharded in
`_sharded_run`; their gradients' compile costs ~30 s of CPU). Prints one JSON line.
"""

from __future__ import annotations

import json

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from jax.sharding import NamedSharding  # noqa: E402
from jax.sharding import PartitionSpec as P  # noqa: E402

import jax_impl  # noqa: E402

OPS = {
    "reconstruct": lambda c, v, z, **o: jax_impl.reconstruct(c, v, z, samples=3, max_radius=3.0, **o),
    "gather_blur": lambda c, v, z, **o: jax_impl.gather_blur(c, v, samples=3, **o),
    "bezier_scatter": lambda c, v, z, **o: jax_impl.bezier_scatter(c, z, -v, v, samples=3, **o),
}


def main() -> None:
    rng = np.random.default_rng(0)
    # The shape of the report in issue 25 (a 2x3x6x7 batch did not deadlock).
    host = (rng.random((4, 3, 24, 26)), rng.normal(size=(4, 2, 24, 26)) * 3.0, rng.uniform(1.0, 2.0, size=(4, 1, 24, 26)))
    devices = jax.devices()
    mesh = jax.make_mesh((len(devices),), ("batch",), axis_types=(jax.sharding.AxisType.Auto,))
    on_one = [jax.device_put(jnp.asarray(a), devices[0]) for a in host]
    on_mesh = [jax.device_put(jnp.asarray(a), NamedSharding(mesh, P("batch"))) for a in host]
    report = {"devices": len(devices), "ops": {}}
    for name, op in OPS.items():
        loss = lambda c, v, z: jnp.sum(op(c, v, z) ** 2)  # noqa: E731
        result = {}
        for kind, fn in (("forward", op), ("gradient", jax.grad(loss, argnums=(0, 1, 2)))) if name == "bezier_scatter" else ():
            compiled = jax.jit(fn)
            single, split = jax.tree.leaves(compiled(*on_one)), jax.tree.leaves(compiled(*on_mesh))
            result[kind] = max(float(np.max(np.abs(np.asarray(a) - np.asarray(b)))) for a, b in zip(single, split))
        try:
            jax.jit(lambda c, v, z: op(c, v, z, impl="fused"))(*on_mesh)
            result["fused=True"] = None
        except ValueError as error:
            result["fused=True"] = str(error).splitlines()[0]
        report["ops"][name] = result
    print(json.dumps(report))


if __name__ == "__main__":
    main()
