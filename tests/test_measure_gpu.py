"""scripts/measure_gpu.py, the one command a lent GPU machine runs, works before a lease spends
minutes on it: here on the CPU (`--device cpu`, a tiny size), where its device side is the ops'
default path (the fused kernels) against the tensor ops."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("torch")
pytest.importorskip("jax")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

import measure_gpu  # noqa: E402

CASES = ("reconstruct", "gather_blur", "MotionBlur reconstruct", "reconstruct jitter='none'")


@pytest.mark.slow
def test_the_script_checks_times_and_writes_its_section(tmp_path, monkeypatch, capsys):
    run = subprocess.run(
        [sys.executable, "scripts/measure_gpu.py", "--out", str(tmp_path), "--device", "cpu", "--sizes", "24x32", "--repeats", "1", "--no-compile", "--only", ",".join(CASES)],
        cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True, timeout=600,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    results = json.loads((tmp_path / "gpu.json").read_text())
    assert [row["case"] for row in results["checks"]] == [case for case in measure_gpu.CHECKS if case in CASES]
    for row in results["checks"]:
        assert row["passed"] and row["jax_hostless"] == "ok" and row["torch_hostless"] == measure_gpu.NOT_ON_CPU, row
        assert max(row["torch"], row["jax"], row["torch_vs_jax"]) <= measure_gpu.TOLERANCE
    expected = measure_gpu.timing_jobs(((24, 32),), ("torch", "jax"), kornia=True, compile_=False)
    assert [(tuple(r["size"]), r["method"], r["setting"], r["framework"], r["mode"]) for r in results["timings"]] == [
        ((24, 32), j["method"], j["setting"], j["framework"], j["mode"]) for j in expected
    ]
    assert all(r["forward_ms"] > 0 and r["backward_ms"] > 0 for r in results["timings"]), results["timings"]
    section = (tmp_path / "gpu.md").read_text()
    assert section.startswith("## GPU\n") and section == run.stdout
    assert all(f"| {case} |" in section for case in CASES)
    assert "under 1 ms" not in section  # the target line is for 1920x1080 only
    monkeypatch.setattr(sys, "argv", ["measure_gpu.py", "--render", str(tmp_path / "gpu.json")])
    assert measure_gpu.main() == 0
    assert capsys.readouterr().out == section


def test_a_difference_on_the_device_fails_the_check(monkeypatch):
    import torch_impl

    exact = torch_impl.gather_blur

    def off_on_the_device(*args, **options):
        out = exact(*args, **options)
        return out if options.get("impl") == "tensor" else out * (1 + 1e-6)

    monkeypatch.setattr(torch_impl, "gather_blur", off_on_the_device)
    row = measure_gpu.check_case("gather_blur", "cpu", ("torch",))
    assert not row["passed"] and 5e-7 < row["torch"] < 2e-6


def test_an_error_is_reported_in_the_row(monkeypatch):
    import torch_impl

    def broken(*args, **options):
        raise RuntimeError("no kernel for this device")

    monkeypatch.setattr(torch_impl, "cone", broken)
    row = measure_gpu.check_case("cone", "cpu", ("torch",))
    assert not row["passed"] and row["torch_error"] == "RuntimeError: no kernel for this device"
    assert "RuntimeError: no kernel for this device" in measure_gpu.markdown({**_empty(), "checks": [row]})


def test_past_the_budget_the_timings_say_they_were_not_run(tmp_path, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["measure_gpu.py", "--out", str(tmp_path), "--device", "cpu", "--frameworks", "torch", "--only", "cone", "--budget", "0", "--sizes", "24x32"])
    assert measure_gpu.main() == 0
    timings = json.loads((tmp_path / "gpu.json").read_text())["timings"]
    assert timings and all(row["skipped"] == "not run: past the 0 s budget" for row in timings)
    assert "not run: past the 0 s budget" in (tmp_path / "gpu.md").read_text()


def _empty() -> dict:
    return {"environment": measure_gpu.environment("cpu", ()), "repeats": 1, "checks": [], "timings": [], "seconds": 0.0}


def test_a_host_callback_in_the_compiled_program_is_found(monkeypatch):
    import jax

    import jax_impl

    exact = jax_impl.cone

    def through_the_host(*args, **options):
        out = exact(*args, **options)
        jax.debug.callback(lambda values: None, out)  # e.g. a check that reads values on the host
        return out

    assert measure_gpu.jax_host_callbacks("cone", "cpu") == []
    monkeypatch.setattr(jax_impl, "cone", through_the_host)
    found = measure_gpu.jax_host_callbacks("cone", "cpu")
    assert len(found) == 1 and measure_gpu.HOST_CALLBACK.fullmatch(found[0])
