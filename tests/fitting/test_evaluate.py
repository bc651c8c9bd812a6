"""The held-out family (fitting.heldout) and its evaluation (fitting.evaluate): the family is frozen
and its truths are those of its buffers; the evaluation's rows, summary and BENCHMARKS.md section.
The family renders once (a few seconds); the only fits are two gather fits on a small pan case."""

from __future__ import annotations

import math

import numpy as np
import pytest

import fitting
from fitting import _recover, evaluate, heldout


@pytest.fixture(scope="module")
def cases():
    return heldout.family()


def test_the_family_matches_its_frozen_manifest(cases):
    """family() is what docs/heldout_family.json froze (hashes of color, target, depth and noise,
    truths, shutters): nobody changes the family after tuning without regenerating the file."""
    stored = heldout.frozen()
    current = heldout.manifest(cases)
    assert stored["seed"] == heldout.HELDOUT_SEED == 7_340_021
    assert len(stored["cases"]) == 30
    for frozen_case, case in zip(stored["cases"], current["cases"]):
        assert frozen_case == case, case["name"]
    assert stored == current


def test_a_case_depends_on_its_index_only(cases):
    """Case k is the same whatever `count` is, and rendering it again gives the same arrays."""
    again = heldout.make_case(7)
    assert heldout.case_hash(again) == heldout.case_hash(cases[7])
    assert np.array_equal(again.noise, cases[7].noise)
    short = heldout.family(2)
    assert [heldout.case_hash(c) for c in short] == [heldout.case_hash(c) for c in cases[:2]]
    # A different seed is a different family.
    assert heldout.case_hash(heldout.make_case(0, seed=1)) != heldout.case_hash(cases[0])


def test_the_family_has_every_kind_and_half_box_shutters(cases):
    kinds = [c.kind for c in cases]
    assert {k: kinds.count(k) for k in heldout.KINDS} == {"objects": 10, "pan": 8, "rotation": 6, "zoom": 6}
    box = [c.shutter == "box" for c in cases]
    assert sum(box) == 15
    for kind in heldout.KINDS:  # every kind sees both the box and other windows
        assert {c.shutter == "box" for c in cases if c.kind == kind} == {True, False}
    assert {c.shutter_label.split("(")[0] for c in cases} == {"box", "tent", "raised_cosine", "trapezoid", "linear_ramp"}
    assert [c.name for c in cases[:3]] == ["objects-00", "pan-01", "rotation-02"]


def _grid(size):
    y, x = np.mgrid[0:size, 0:size].astype(np.float64)
    return x, y


def test_every_truth_is_what_the_buffers_show(cases):
    """The truths are the motions the renderer drew: pan (one velocity at every pixel), objects
    (every layer's pixels move by its velocity, at its depth), rotation (sin(angle) R90 (X - c) on
    the turning layer, 0 elsewhere), zoom (the dolly's exact half-spread on the background). Speeds
    are within 2-15 px."""
    for case in cases:
        b, t = case.buffers, case.truth
        v = b.velocity[0]
        size = v.shape[-1]
        x, y = _grid(size)
        assert case.ids.shape == (1, 1, size, size) and case.ids.dtype == np.int64, case.name
        if case.kind == "pan":
            np.testing.assert_allclose(v[0], t["velocity"][0], atol=1e-9, err_msg=case.name)
            np.testing.assert_allclose(v[1], t["velocity"][1], atol=1e-9, err_msg=case.name)
            assert 2.0 <= math.hypot(*t["velocity"]) <= 15.0
        elif case.kind == "objects":
            layers = t["layers"]
            assert layers[0]["velocity"] == [0.0, 0.0] and 10 <= layers[0]["depth"] <= 20
            depths = [layer["depth"] for layer in layers[1:]]
            assert len(depths) in (1, 2, 3) and len(set(depths)) == len(depths) and all(2 <= d <= 6 for d in depths)
            assert int(case.ids.max()) == len(layers) - 1
            for k, layer in enumerate(layers):
                seen = case.ids[0, 0] == k
                assert seen.sum() >= 40, (case.name, k)
                np.testing.assert_allclose(v[:, seen], np.reshape(layer["velocity"], (2, 1)) * np.ones((1, seen.sum())), atol=1e-9, err_msg=f"{case.name} layer {k}")
                np.testing.assert_allclose(b.depth[0, 0][seen], layer["depth"], rtol=1e-9)
                if k:
                    assert 2.0 - 1e-3 <= math.hypot(*layer["velocity"]) <= 15.0 + 1e-3
            assert b.background is not None  # the background is still
        elif case.kind == "rotation":
            cx, cy = t["center"]
            s = math.sin(t["angle"])
            turning = case.ids[0, 0] == 1
            assert turning.sum() > 100
            np.testing.assert_allclose(v[0][turning], -s * (y - cy)[turning], atol=1e-9, err_msg=case.name)
            np.testing.assert_allclose(v[1][turning], s * (x - cx)[turning], atol=1e-9, err_msg=case.name)
            assert np.all(v[:, ~turning] == 0.0)
            assert 2.0 - 1e-3 <= abs(t["angle"]) * t["radius"] <= 15.0 + 1e-3
            assert b.background is not None
        else:
            a, z = t["advance"], t["depth"]
            c = (size - 1) / 2.0
            back = case.ids[0, 0] == 0
            factor = a * z / (z * z - a * a)
            np.testing.assert_allclose(v[0][back], (x - c)[back] * factor, atol=1e-9, err_msg=case.name)
            np.testing.assert_allclose(v[1][back], (y - c)[back] * factor, atol=1e-9, err_msg=case.name)
            assert t["advance_first_order"] == pytest.approx(a * z * z / (z * z - a * a), rel=1e-7)
            speed = np.hypot(v[0], v[1]).max()
            assert 2.0 - 1e-3 <= speed <= 15.0 + 1e-3, (case.name, speed)
        # The noise: sigma 0.01, the case's own.
        assert case.noise.shape == b.target.shape
        assert case.noise.std() == pytest.approx(heldout.NOISE_SIGMA, rel=0.05)
        np.testing.assert_array_equal(case.noisy_target, b.target + case.noise)
        np.testing.assert_allclose(case.target(0.005) - b.target, 0.5 * case.noise)


def test_error_of_each_model():
    """Errors in the model's unit, up to sign only under a symmetric shutter."""
    assert evaluate.error_of("global", {"velocity": [-3.0, 1.1]}, {"velocity": [3.0, -1.0]}, True)[0] == pytest.approx(0.1)
    assert evaluate.error_of("global", {"velocity": [-3.0, 1.1]}, {"velocity": [3.0, -1.0]}, False)[0] == pytest.approx(6.0)
    truth = {"layers": [{"depth": 15.0, "velocity": [0.0, 0.0]}, {"depth": 3.0, "velocity": [4.0, -2.0]}, {"depth": 5.0, "velocity": [-1.0, 6.0]}]}
    error, extra = evaluate.error_of("motion_ids", {"palette": [[0.01, 0.0], [-4.0, 2.2], [1.0, -6.0]]}, truth, True)
    assert extra["per_layer_px"] == pytest.approx([0.01, 0.2, 0.0]) and error == pytest.approx(0.2)
    # layers: matched by the nearest depth, whatever the order of the fitted layers.
    error, extra = evaluate.error_of("layers", {"palette": [[-1.0, 6.3], [0.0, 0.05], [4.0, -2.0]], "depths": [4.8, 14.0, 3.1]}, truth, False)
    assert extra["matched"] == [1, 2, 0] and extra["per_layer_px"] == pytest.approx([0.05, 0.0, 0.3]) and error == pytest.approx(0.3)
    assert evaluate.error_of("exposure", {"exposure": 0.606}, {}, True)[0] == pytest.approx(1.0)
    error, extra = evaluate.error_of("rotation", {"angle": 0.49, "center": [10.0, 12.5]}, {"angle": -0.5, "center": [10.0, 12.0]}, True)
    assert error == pytest.approx(2.0) and extra["center_px"] == pytest.approx(0.5)
    assert evaluate.error_of("rotation", {"angle": 0.49, "center": [10.0, 12.0]}, {"angle": -0.5, "center": [10.0, 12.0]}, False)[0] == pytest.approx(198.0)
    error, extra = evaluate.error_of("camera", {"pan": [2.0, -1.0], "advance": -1.1, "roll": 0.0}, {"advance": 1.0, "advance_first_order": 1.1, "depth": 10.0}, True)
    assert error == pytest.approx(0.0) and extra["pan_px"] == pytest.approx(0.2) and extra["advance_vs_camera_pct"] == pytest.approx(10.0)


def test_the_plan_follows_the_models_and_methods_present(cases):
    """global and camera through every method (the non-default ones on the first backend only), other
    models through their default; noise on the default method and the first backend; models and
    methods that fitting lacks are skipped, those it gains come in."""
    fits = evaluate.plan(cases)
    methods = tuple(_recover.METHODS)
    defaults = getattr(_recover, "DEFAULT_METHODS", {})
    for kind, model, count in (("pan", "global", 8), ("zoom", "camera", 6)):
        mine = [f for f in fits if f["case"].kind == kind]
        assert len(mine) == count * (len(methods) + 2), kind  # every method on torch, the default on JAX too, one noisy
        assert {f["method"] for f in mine if f["noise"] == 0} == set(methods)
        assert {f["method"] for f in mine if f["backend"] == "jax"} == {defaults.get(model, methods[0])}
    noisy = [f for f in fits if f["noise"] > 0]
    assert {f["backend"] for f in noisy} == {"torch"}
    for f in noisy:  # the default method: what recover takes without one
        assert f["method"] == ("arc" if f["model"] == "rotation" else defaults.get(f["model"], methods[0])), f["model"]
    assert [f["method"] for f in noisy if f["model"] == "global"] == [defaults.get("global", methods[0])] * 8
    assert {f["method"] for f in fits if f["model"] == "rotation"} == {"arc"}
    objects_models = {f["model"] for f in fits if f["case"].kind == "objects"}
    assert objects_models == {m for m in ("motion_ids", "layers", "exposure") if m in fitting.MODELS}
    others = sum(len([m for m in evaluate.KIND_MODELS[c.kind] if m in fitting.MODELS]) for c in cases if c.kind in ("objects", "rotation"))
    assert len(fits) == 8 * (len(methods) + 2) + 6 * (len(methods) + 2) + 3 * others  # 2 backends noise-free + 1 noisy
    only = evaluate.plan(cases[:2], backends=("jax",), models=["global"], methods=["gather"], noise=(0.0,))
    assert [(f["case"].name, f["model"], f["method"], f["backend"]) for f in only] == [("pan-01", "global", "gather", "jax")]
    with pytest.raises(ValueError, match="unknown method"):
        evaluate.plan(cases[:2], methods=["nope"])


def test_evaluate_returns_a_row_per_fit():
    """Two gather fits (noise-free and noisy) on a small pan case: rows with the fields, an error that
    is the velocity's, and a summary of them."""
    case = heldout.make_case(26, size=32)  # pan-26, box shutter, (0.55, -2.35) px
    assert case.kind == "pan"
    rows = evaluate.evaluate([case], backends=("torch",), models=["global"], methods=["gather"], progress=False)
    assert [(r["case"], r["noise"], r["model"], r["method"], r["backend"]) for r in rows] == [("pan-26", 0.0, "global", "gather", "torch"), ("pan-26", 0.01, "global", "gather", "torch")]
    fields = {"case", "kind", "shutter", "symmetric", "noise", "model", "method", "backend", "unit", "error", "extra", "within", "converged", "solver", "steps", "loss", "params", "failed", "message", "seconds", "truth"}
    for row in rows:
        assert fields <= set(row), fields - set(row)
        assert not row["failed"] and row["message"] == "" and row["symmetric"] and row["unit"] == "px"
        assert row["error"] == pytest.approx(evaluate.error_of("global", row["params"], case.truth, True)[0])
        assert row["seconds"] > 0 and row["steps"] > 0
        assert row["within"] == (row["error"] <= (0.1 if row["noise"] == 0 else 0.5))
    assert rows[0]["error"] < 1.0  # a 2.4 px pan through the gather it blurs with
    summary = evaluate.summarize(rows)
    assert [(s["noise"], s["count"], s["median"]) for s in summary] == [(0.0, 1, rows[0]["error"]), (0.01, 1, rows[1]["error"])]


def test_a_failing_fit_is_a_row(monkeypatch, cases):
    def boom(*args, **kwargs):
        raise RuntimeError("solver exploded")

    monkeypatch.setattr(fitting, "recover", boom)
    rows = evaluate.evaluate(cases[1:2], backends=("torch",), methods=["gather"], noise=(0.0,), progress=False)
    assert len(rows) == 1
    assert rows[0]["failed"] and rows[0]["error"] == math.inf and rows[0]["converged"] is False
    assert rows[0]["message"] == "RuntimeError: solver exploded"
    (s,) = evaluate.summarize(rows)
    assert s["failed"] == 1 and s["median"] == math.inf and s["converged"] == "n/a" and s["met"] is False


def _row(error, *, model="global", method="gather", backend="torch", noise=0.0, converged=None, failed=False, seconds=1.0):
    return {"model": model, "method": method, "backend": backend, "noise": noise, "unit": evaluate.UNITS[model], "error": error, "converged": converged, "failed": failed, "seconds": seconds}


def test_summarize_by_hand():
    """Medians and 90th percentiles (linear between order statistics), within, converged, met."""
    rows = [_row(e, seconds=s) for e, s in ((0.4, 5.0), (0.1, 1.0), (10.0, 2.0), (0.3, 4.0), (0.2, 3.0))]
    rows += [_row(0.05, noise=0.01, converged=True), _row(0.08, noise=0.01, converged=False), _row(math.inf, noise=0.01, failed=True)]
    rows += [_row(0.5, model="exposure", method="reconstruct"), _row(1.5, model="exposure", method="reconstruct", backend="jax")]
    summary = evaluate.summarize(rows)
    keys = [(s["model"], s["method"], s["backend"], s["noise"]) for s in summary]
    assert keys == [("global", "gather", "torch", 0.0), ("global", "gather", "torch", 0.01), ("exposure", "reconstruct", "jax", 0.0), ("exposure", "reconstruct", "torch", 0.0)]
    clean, noisy, exposure_jax, exposure_torch = summary
    # sorted: 0.1 0.2 0.3 0.4 10; p90 at position 3.6: 0.4 + 0.6 * (10 - 0.4) = 6.16
    assert clean["count"] == 5 and clean["median"] == pytest.approx(0.3) and clean["p90"] == pytest.approx(6.16)
    assert clean["within"] == pytest.approx(0.2)  # only 0.1 <= 0.1 px
    assert clean["seconds"] == pytest.approx(3.0) and clean["converged"] == "n/a" and clean["met"] is False
    assert clean["target"] == "median <= 0.1 px, p90 <= 0.25 px" and clean["unit"] == "px"
    # noisy: 0.05 0.08 inf; median 0.08; p90 at 1.8 reaches inf; converged 1 of 3 (the failure counts)
    assert noisy["median"] == pytest.approx(0.08) and noisy["p90"] == math.inf
    assert noisy["within"] == pytest.approx(2 / 3) and noisy["converged"] == pytest.approx(1 / 3) and noisy["failed"] == 1
    assert noisy["met"] is True  # the noisy target is the median's only
    assert exposure_torch["met"] is True and exposure_jax["met"] is False and exposure_torch["unit"] == "%"
    assert evaluate.percentile([3.0, 1.0, 2.0, 4.0], 50) == pytest.approx(2.5) == np.percentile([3.0, 1.0, 2.0, 4.0], 50)
    table = evaluate.markdown_table(summary)
    assert table.count("\n") == 1 + len(summary)
    assert "| global | gather | torch | 0 | 5 | 0 | px | 0.300 | 6.160 | 20 % | n/a | 3.0 | median <= 0.1 px, p90 <= 0.25 px | no |" in table
    assert "| global | gather | torch | 0.01 | 3 | 1 | px | 0.080 | inf | 67 % | 33 % |" in table


def test_the_section_writer_replaces_only_its_own_section(tmp_path):
    path = tmp_path / "BENCHMARKS.md"
    head = "# Benchmarks\n\nSome table\n\n| a | b |\n|---|---|\n"
    path.write_text(head)
    evaluate.write_section(path, "## Held-out recovery (before)\nold numbers", label="before")
    first = path.read_text()
    assert first.startswith(head)
    assert "<!-- heldout:before:start -->\n## Held-out recovery (before)\nold numbers\n<!-- heldout:before:end -->" in first
    evaluate.write_section(path, "after numbers", label="after")
    evaluate.write_section(path, "unlabelled", label=None)
    path.write_text(path.read_text() + "\n## Trailing section\n")
    evaluate.write_section(path, "new before numbers", label="before")
    text = path.read_text()
    assert text.startswith(head) and text.endswith("\n## Trailing section\n")
    assert "old numbers" not in text and text.count("new before numbers") == 1
    assert text.index("heldout:before:start") < text.index("heldout:after:start") < text.index("<!-- heldout:start -->")
    assert "after numbers" in text and "unlabelled" in text
    # Writing the same again changes nothing.
    evaluate.write_section(path, "new before numbers", label="before")
    assert path.read_text() == text
    # A missing file is created with the section.
    fresh = tmp_path / "new.md"
    evaluate.write_section(fresh, "table")
    assert fresh.read_text() == "<!-- heldout:start -->\ntable\n<!-- heldout:end -->\n"
