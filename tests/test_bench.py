"""The benchmark command never rots: the quick sweep on tiny inputs gives finite numbers in every row
and writes its three files (no timing is asserted)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from diffblur.app import bench
from diffblur.app.cli import main


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    torch = pytest.importorskip("torch", reason="the benchmark runs both backends")
    before = torch.get_num_threads()
    out = tmp_path_factory.mktemp("bench")
    results = bench.run_benchmarks(out_dir=out, quick=True, height=16, width=16, scenes=("uniform",), threads=1, progress=False)
    assert torch.get_num_threads() == before  # the one-thread measurement leaves the process as it was
    return out, results


def _numbers(row: dict) -> list[float]:
    keys = ["psnr_db", "ssim", "forward_ms"]
    if row["backend"] != "numpy":  # the accumulation peer has no backward
        keys += ["backward_ms", "peak_mb"]
    if row["backend"] == "jax":
        keys += ["compile_s", "compile_backward_s", "xla_temp_mb"]
    return [row[k] for k in keys]


@pytest.mark.slow
def test_quick_bench_rows_are_finite(quick):
    _, results = quick
    rows = results["rows"]
    methods = {(r["method"], r["backend"]) for r in rows}
    # every quick entry ran in each of its backends, and the accumulation peer ran
    expected = {(s.method, b) for s in bench.SETTINGS if s.quick for b in s.backends}
    assert expected | {("accumulation (renderer)", "numpy")} == methods
    for row in rows:
        for value in _numbers(row):
            assert isinstance(value, float) and math.isfinite(value), row
        assert 0.0 < row["ssim"] <= 1.0, row
    # the brute-force peer at each method's time budget is recorded (0 instants where none fits)
    assert all(r["brute_force_instants"] is not None for r in rows if r["backend"] != "numpy")


@pytest.mark.slow
def test_quick_bench_writes_its_files(quick):
    out, results = quick
    assert (out / "docs" / "pareto.png").stat().st_size > 1000
    assert json.loads((out / "docs" / "benchmarks.json").read_text())["rows"] == json.loads(json.dumps(results["rows"]))
    markdown = (out / "BENCHMARKS.md").read_text()
    assert "## Scene `uniform` (16x16)" in markdown
    assert results["machine"]["cpu"] in markdown
    assert f"OMP_WAIT_POLICY '{results['machine']['omp_wait_policy']}'" in markdown  # the timings' thread environment
    for row in results["rows"]:
        assert f"| {row['setting']} | {row['backend']} |" in markdown


def test_pareto_front_keeps_only_undominated_points():
    points = [(1.0, 20.0), (2.0, 25.0), (3.0, 24.0), (0.5, 10.0), (4.0, 30.0), (2.0, 22.0)]
    assert sorted(bench.pareto_front(points)) == [0, 1, 3, 4]


def test_bench_rejects_unknown_scene(capsys):
    assert main(["bench", "--quick", "--scenes", "nowhere", "--out", "unused"]) == 2
    assert "scenes" in capsys.readouterr().err


def test_timed_calls_take_turns():
    """median_ms_each interleaves its functions (so drift reaches all alike), warm-up rounds first."""
    from diffblur.app.timing import median_ms_each

    calls = []
    times = median_ms_each([lambda: calls.append("forward"), lambda: calls.append("backward")], repeats=3, warmup=1)
    assert calls == ["forward", "backward"] * 4
    assert len(times) == 2 and all(t >= 0 for t in times)


def test_the_targets_settings_take_turns_in_one_loop():
    """The targets pass times every setting's forward and forward+backward in one round-robin
    (kornia's and reconstruct's calls alternate), so their ratios see the same machine speed."""
    from types import SimpleNamespace

    calls = []
    target = np.zeros((1, 3, 8, 8))

    class Runner:
        def prepare(self, setting, x):
            return dict(output=target, forward=lambda: calls.append((setting.method, "forward")), backward=lambda: calls.append((setting.method, "backward")))

    settings = [bench.Setting(method, "label", None, (), ()) for method in ("reconstruct", "kornia.motion_blur")]
    bar = SimpleNamespace(set_postfix_str=lambda text: None, update=lambda: None)
    buffers = SimpleNamespace(name="uniform", target=target)
    rows = bench._measure_in_turns({"torch": Runner()}, [(s, "torch") for s in settings], buffers, {}, "8x8", 2, bar)
    one_round = [("reconstruct", "forward"), ("reconstruct", "backward"), ("kornia.motion_blur", "forward"), ("kornia.motion_blur", "backward")]
    # a warm-up round, two timed rounds, then one forward+backward each for the peak memory
    assert calls[:12] == one_round * 3
    assert [(r.method, r.backend) for r in rows] == [("reconstruct", "torch"), ("kornia.motion_blur", "torch")]
    assert all(r.forward_ms >= 0 and r.backward_ms >= 0 for r in rows)


def test_a_new_run_keeps_the_other_commands_sections(quick, tmp_path):
    """BENCHMARKS.md also holds sections other commands write (held-out recovery, renderer scenes,
    compile against eager, soak): a new bench run replaces its own and keeps theirs, in order."""
    _, results = quick
    path = tmp_path / "BENCHMARKS.md"
    others = "<!-- heldout:after:start -->\n## Held-out recovery (after)\nrows\n<!-- heldout:after:end -->\n\n## Soak\nfigures\n"
    path.write_text("# Benchmarks\n\n## Targets (old)\nold\n\n## Scene `uniform` (8x8)\nold rows\n\n" + others)
    bench._write(tmp_path, results)
    text = path.read_text()
    assert text.endswith(others) and "old rows" not in text and "## Scene `uniform`" in text


def test_a_measurement_script_replaces_its_section_in_place(tmp_path):
    path = tmp_path / "BENCHMARKS.md"
    path.write_text("# Benchmarks\n\n## Soak\n\nold\n\n## Later\n\nkept\n")
    bench.replace_section(str(path), "## Soak", "## Soak\n\nnew\n")
    assert path.read_text() == "# Benchmarks\n\n## Soak\n\nnew\n\n## Later\n\nkept\n"
    bench.replace_section(str(path), "## Compiled against eager", "## Compiled against eager\n\nrows\n")
    assert path.read_text().endswith("kept\n\n## Compiled against eager\n\nrows\n")
