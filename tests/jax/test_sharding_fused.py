"""The ops that have fused CPU kernels under a batch-sharded `jax.jit` over 2 host devices: on the
default path `bezier_scatter`'s forward and gradient equal the one-device result, and `impl="fused"`
is refused with a ValueError that says why, never a hang.

Before issue 25 the default path took the fused kernel, whose host callback XLA runs on one device:
`bezier_scatter`'s gradient then deadlocked in an all-reduce and XLA aborted the process after 40 s.
The run is a subprocess (the device count is fixed when JAX starts) with a timeout, so a hang fails.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_fused_ops_sharded_equal_unsharded_or_refuse():
    env = {**os.environ, "XLA_FLAGS": (os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2").strip(), "PYTHONPATH": str(ROOT), "JAX_PLATFORMS": "cpu"}
    try:
        run = subprocess.run([sys.executable, "-m", "tests.jax._sharded_fused_run"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=240)
    except subprocess.TimeoutExpired as error:
        raise AssertionError(f"the sharded run hung: {str(error.stderr)[-2000:]}") from None
    assert run.returncode == 0, run.stderr[-3000:]
    report = json.loads(run.stdout.strip().splitlines()[-1])
    assert report["devices"] == 2
    assert set(report["ops"]) == {"reconstruct", "gather_blur", "bezier_scatter"}
    assert report["ops"]["bezier_scatter"]["forward"] <= 1e-12, report
    assert report["ops"]["bezier_scatter"]["gradient"] <= 1e-12, report
    for name, result in report["ops"].items():
        refusal = result["fused=True"]
        assert refusal is not None and refusal.startswith(f"{name}(impl='fused') cannot run: JAX has 2 devices"), (name, refusal)
