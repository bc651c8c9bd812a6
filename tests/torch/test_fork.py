"""The fused kernels in forked workers: a DataLoader with 2 `fork` workers, started after the parent
process ran the fused ops, gives the parent's batch.

Before issue 25 numba used GNU OpenMP, which is not fork-safe: the workers died ("Terminating: fork()
called from a process already using GNU OpenMP") and the DataLoader raised. `diffblur.kernels.shared` now
pins a fork-safe threading layer, and runs one kernel at a time (the workqueue layer aborts the
process when two threads launch at once): the same run then has 2 threads build the batch together.
The run is a subprocess with a timeout, so a hang fails.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_dataloader_with_forked_workers_after_the_parent_used_the_fused_ops():
    env = {key: value for key, value in os.environ.items() if key != "NUMBA_THREADING_LAYER"}
    env["PYTHONPATH"] = str(ROOT)
    try:
        run = subprocess.run([sys.executable, "-m", "tests.torch._forked_loader_run"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=240)
    except subprocess.TimeoutExpired as error:
        raise AssertionError(f"the forked DataLoader hung: {str(error.stderr)[-2000:]}") from None
    assert run.returncode == 0, run.stderr[-3000:]
    report = json.loads(run.stdout.strip().splitlines()[-1])
    assert report["layer"] in ("tbb", "workqueue"), report  # the fork-safe layers on Linux
    assert report["max_difference"] == 0.0, report
    assert report["threads_max_difference"] == 0.0, report
