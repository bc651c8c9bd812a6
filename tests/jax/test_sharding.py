"""The JAX ops batch-sharded over 2 host devices (jax.sharding, XLA's SPMD partitioner) give the
unsharded result, outputs and gradients.

XLA_FLAGS=--xla_force_host_platform_device_count=2 must be set before JAX initialises, and this
test session's JAX (and pytest-xdist's workers) already has: the ops run in a subprocess, with
XLA's backend optimisation off (it halves the compile time; the results are compared exactly).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_batch_sharded_ops_equal_unsharded():
    env = {**os.environ, "XLA_FLAGS": (os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2").strip(), "PYTHONPATH": str(ROOT), "JAX_PLATFORMS": "cpu"}
    run = subprocess.run([sys.executable, "-m", "tests.jax._sharded_run"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    report = json.loads(run.stdout.strip().splitlines()[-1])
    assert report["devices"] == 2
    assert set(report["ops"]) == {"reconstruct", "bezier_scatter", "grad MotionBlur"}
    for name, result in report["ops"].items():
        # The result equals the one-device result, and each device holds half the batch of 4.
        assert result["max_difference"] <= 1e-12, (name, result)
        if name != "grad MotionBlur":  # the exposure's gradient is one number, on both devices
            assert result["output_devices"] == 2, (name, result)
            assert result["shard_batches"] == [2], (name, result)
