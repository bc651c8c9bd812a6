"""The Mitsuba ground truth (`diffblur.scenes.mitsuba`, the optional extra `diffblur[mitsuba]`):
the four scenes at 64 x 64, their buffers in the project's conventions, the projection checked
against the renderer itself, and the on-disk cache."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import maximum_filter

pytest.importorskip("mitsuba")

from diffblur import conventions  # noqa: E402
from diffblur.metrics import psnr  # noqa: E402
from diffblur.scenes.mitsuba import MITSUBA_SCENES, mitsuba_buffers, mitsuba_scene, projection_check, render_mitsuba  # noqa: E402

SIZE = 64


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """Every scene at 64 x 64, box shutter, through the cache (a fresh folder)."""
    cache = tmp_path_factory.mktemp("mitsuba_cache")
    return cache, {name: mitsuba_buffers(name, height=SIZE, width=SIZE, cache_dir=cache) for name in MITSUBA_SCENES}


@pytest.mark.parametrize("name", MITSUBA_SCENES)
def test_buffers_follow_the_conventions(name, rendered):
    b = rendered[1][name]
    assert b.color.shape == b.target.shape == (1, 3, SIZE, SIZE)
    assert b.depth.shape == (1, 1, SIZE, SIZE) and b.velocity.shape == b.offset_prev.shape == b.offset_next.shape == (1, 2, SIZE, SIZE)
    np.testing.assert_allclose(b.velocity, 0.5 * (b.offset_next - b.offset_prev))
    assert 2.0 < b.depth.min() and b.depth.max() <= 12.0  # world units, as the scene is built
    assert b.instants >= 40  # consecutive instants < 1/4 px apart for motions of 8 to 10 px
    speed = np.hypot(*b.velocity[0])
    assert 7.0 < speed.max() < 12.0
    # The target is blurred: it differs from the sharp frame, and where nothing moves it does not.
    moving = np.hypot(*b.offset_prev[0]) + np.hypot(*b.offset_next[0]) > 0.5
    assert psnr(b.color, b.target) < 32.0
    if name != "dolly":
        still = ~moving
        # Still surfaces far from motion (12 px) show the same colour at every instant: the sharp frame's.
        far = still & ~maximum_filter(moving, size=25, mode="nearest")
        assert far.mean() > 0.3
        assert np.abs(b.color - b.target)[..., far].max() < 0.05


@pytest.mark.parametrize("name", [n for n in MITSUBA_SCENES if n != "dolly"])
def test_static_surfaces_carry_float_leftovers_below_the_still_threshold(name, rendered):
    """What a renderer makes: offsets of static surfaces are not exactly 0 (the rotation and
    projection round), but far below STILL_SPEED, so every op counts them as still."""
    b = rendered[1][name]
    length = np.maximum(np.hypot(*b.offset_prev[0]), np.hypot(*b.offset_next[0]))
    still = length < conventions.STILL_SPEED
    assert 0.5 < still.mean() < 1.0
    assert length[still].max() < 1e-3 * conventions.STILL_SPEED * 100  # 1e-4 px at most
    assert np.count_nonzero(length[still]) > 0


@pytest.mark.parametrize("name", MITSUBA_SCENES)
def test_projection_agrees_with_the_renderer(name, rendered):
    """t = 0 hit points project onto their own pixel centres; the renderer's position buffers at
    t = -1, +1, read at X + offset, hold the moved hit points of the moving objects (measured at
    64 x 64: 0.004 to 0.011 px median, 0.008 to 0.14 px at the 90th percentile, where a bilinear read
    straddles a box's edge)."""
    b = rendered[1][name]
    report = projection_check(mitsuba_scene(name, height=SIZE, width=SIZE), b)
    assert report["center_px"] < 1e-3
    assert report["offset_pixels"] > 50  # moving points, both ends counted (96 to 5978 here)
    assert report["offset_px_median"] < 0.03 and report["offset_px_90"] < 0.25, report


def test_projection_check_sees_a_wrong_motion(rendered):
    """The check is not blind: offsets 10 % too long read the renderer 0.4 to 1.0 px away (median)."""
    b = rendered[1]["propeller"]
    wrong = b.__class__(**{**b.__dict__, "offset_prev": 1.1 * b.offset_prev, "offset_next": 1.1 * b.offset_next})
    report = projection_check(mitsuba_scene("propeller", height=SIZE, width=SIZE), wrong)
    assert report["offset_px_median"] > 0.3


def test_cache_returns_what_was_rendered(rendered):
    cache, buffers = rendered
    files = sorted(p.name for p in (cache / "mitsuba").iterdir())
    assert len(files) == len(MITSUBA_SCENES) and all(f.endswith(".npz") for f in files)
    again = mitsuba_buffers("crossing", height=SIZE, width=SIZE, cache_dir=cache)
    for field in ("color", "depth", "offset_prev", "offset_next", "target", "background"):
        np.testing.assert_array_equal(getattr(again, field), getattr(buffers["crossing"], field))
    assert again.instants == buffers["crossing"].instants


def test_render_is_deterministic_for_a_seed():
    scene = mitsuba_scene("crossing", height=16, width=16)
    a, b = (render_mitsuba(scene, instants=3) for _ in range(2))
    np.testing.assert_array_equal(a.target, b.target)
    np.testing.assert_array_equal(a.color, b.color)


def test_benchmark_section_is_written_and_replaced(tmp_path):
    """`python -m diffblur.app.mitsuba_bench` in small (one scene, 24 x 24): every method, the targets' tables,
    written into a markdown file in place of an older section, and kept by `kept_section`."""
    from diffblur.app.mitsuba_bench import BEGIN, END, METHODS, kept_section, measure, section, write_section

    results = measure(size=24, backends=("torch",), scenes=("crossing",), cache_dir=tmp_path, repeats=1)
    assert {r["method"] for r in results["rows"]} == set(METHODS)
    assert all(np.isfinite(r["psnr"]) and r["ms"] > 0 for r in results["rows"])
    assert len(results["bands"]) == 2 and len(results["leftovers"]) == len(METHODS)
    # The leftovers change nothing (still means below STILL_SPEED).
    assert max(r["change_db"] for r in results["leftovers"]) < 0.05
    text = section(results)
    path = tmp_path / "BENCHMARKS.md"
    path.write_text("# Benchmarks\n\nother tables\n")
    write_section(str(path), text)
    write_section(str(path), text.replace("Targets", "Targets again"))
    written = path.read_text()
    assert written.count(BEGIN) == 1 and written.count(END) == 1 and "Targets again" in written
    assert written.startswith("# Benchmarks\n\nother tables\n")
    assert kept_section(str(path)) == text.replace("Targets", "Targets again")
