"""`diffblur blur` on photographs: buffers from the command line, readable errors."""

from __future__ import annotations

import re

import numpy as np
import pytest
from PIL import Image

from diffblur.app.blur_image import load_inputs, read_picture
from diffblur.app.cli import main


@pytest.fixture
def photo(tmp_path):
    """A 24x32 sRGB picture of vertical stripes with a horizontal ramp (seeded)."""
    rng = np.random.default_rng(7)
    columns = rng.integers(0, 256, size=(1, 32, 3))
    pixels = np.broadcast_to(columns, (24, 32, 3)).astype(np.uint8)
    path = tmp_path / "photo.png"
    Image.fromarray(np.ascontiguousarray(pixels)).save(path)
    return path


def _painted(tmp_path, red: int, green: int, name="velocity.png"):
    path = tmp_path / name
    Image.fromarray(np.full((3, 4, 3), (red, green, 128), np.uint8)).save(path)
    return path


def test_vertical_motion_leaves_vertical_stripes_alone_and_horizontal_motion_blurs_them(tmp_path, photo):
    still = tmp_path / "still.png"
    assert main(["blur", str(photo), "-o", str(still), "--velocity", "0", "6", "--method", "gather"]) == 0
    assert np.array_equal(np.asarray(Image.open(still)), np.asarray(Image.open(photo)))
    moved = tmp_path / "moved.png"
    assert main(["blur", str(photo), "-o", str(moved), "--velocity", "6", "0", "--method", "gather"]) == 0
    original, blurred = (np.asarray(Image.open(p), dtype=np.float64) for p in (photo, moved))
    assert np.abs(blurred - original).mean() > 10
    # Away from the borders the columns average: less contrast between neighbouring columns.
    assert np.abs(np.diff(blurred[:, 8:24], axis=1)).mean() < 0.5 * np.abs(np.diff(original[:, 8:24], axis=1)).mean()


def test_painted_velocity_picture_is_decoded_and_upsampled(tmp_path, photo):
    inputs = load_inputs(str(photo), velocity_image=str(_painted(tmp_path, 255, 1)), max_speed=12.0)
    assert inputs.velocity.shape == (1, 2, 24, 32)
    np.testing.assert_allclose(inputs.velocity[0, 0], 12.0)
    np.testing.assert_allclose(inputs.velocity[0, 1], -12.0)
    still = load_inputs(str(photo), velocity_image=str(_painted(tmp_path, 128, 128)))
    assert np.all(still.velocity == 0)


def test_painted_depth_white_is_near_and_black_is_far(tmp_path, photo):
    path = tmp_path / "depth.png"
    grey = np.zeros((2, 2), np.uint8)
    grey[0] = 255
    Image.fromarray(grey).save(path)
    depth = load_inputs(str(photo), velocity=(1.0, 0.0), depth_image=str(path)).depth[0, 0]
    assert depth[0, 0] == pytest.approx(1.0) and depth[-1, 0] == pytest.approx(10.0)
    assert np.all(np.diff(depth[:, 0]) >= 0)


def test_photograph_is_decoded_to_linear_light(photo):
    inputs = load_inputs(str(photo), velocity=(0.0, 0.0))
    encoded = read_picture(photo).transpose(2, 0, 1)
    mid = (encoded > 0.2) & (encoded < 0.8)
    assert np.all(inputs.color[0][mid] < encoded[mid])  # sRGB decoding darkens mid-tones


def test_torch_and_jax_backends_write_the_same_picture(tmp_path, photo):
    velocity = tmp_path / "velocity.npy"
    np.save(velocity, np.random.default_rng(1).normal(0, 3, size=(2, 24, 32)))
    outputs = []
    for backend in ("torch", "jax"):
        out = tmp_path / f"{backend}.png"
        assert main(["blur", str(photo), "-o", str(out), "--velocity-file", str(velocity), "--backend", backend, "--samples", "5"]) == 0
        outputs.append(np.asarray(Image.open(out), dtype=np.int16))
    assert np.abs(outputs[0] - outputs[1]).max() <= 1


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--velocity-file", "{tmp}/missing.npy"], "no such velocity file"),
        (["--velocity-file", "{tmp}/small.npy"], r"has shape \(2, 4, 4\); the photograph needs \(2, 24, 32\)"),
        (["--velocity", "1", "1", "--depth-file", "{tmp}/negative.npy"], "must be > 0 everywhere"),
        (["--velocity-image", "{tmp}/grey.png"], "is grey; paint x in red and y in green"),
        (["--velocity", "1", "1", "--max-speed", "0"], "max_speed must be a finite number > 0"),
        (["--velocity-file", "{tmp}/notanimage.npy", "--method", "gather"], "has shape"),
    ],
)
def test_bad_files_give_readable_errors(tmp_path, photo, capsys, extra, message):
    np.save(tmp_path / "small.npy", np.zeros((2, 4, 4)))
    np.save(tmp_path / "negative.npy", -np.ones((24, 32)))
    np.save(tmp_path / "notanimage.npy", np.zeros(3))
    Image.fromarray(np.zeros((2, 2), np.uint8)).save(tmp_path / "grey.png")
    args = ["blur", str(photo), "-o", str(tmp_path / "out.png")] + [a.format(tmp=tmp_path) for a in extra]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("diffblur blur: error:") and re.search(message, err)


def test_missing_or_unreadable_photograph(tmp_path, capsys):
    assert main(["blur", str(tmp_path / "none.png"), "-o", str(tmp_path / "o.png"), "--velocity", "1", "0"]) == 2
    assert "no such image file" in capsys.readouterr().err
    text = tmp_path / "text.png"
    text.write_text("not an image")
    assert main(["blur", str(text), "-o", str(tmp_path / "o.png"), "--velocity", "1", "0"]) == 2
    assert "is not an image file" in capsys.readouterr().err


def test_samples_sets_accumulates_instants_and_max_radius_reaches_reconstruct(tmp_path, photo):
    from diffblur.app.blur_image import blur_image, write_picture

    out = tmp_path / "acc.png"
    assert main(["blur", str(photo), "-o", str(out), "--velocity", "5", "0", "--method", "accumulate", "--samples", "5"]) == 0
    inputs = load_inputs(str(photo), velocity=(5.0, 0.0))
    expected = np.asarray(Image.open(out), dtype=np.int16)
    write_picture(tmp_path / "direct.png", blur_image(inputs, method="accumulate", instants=5))
    assert np.array_equal(np.asarray(Image.open(tmp_path / "direct.png"), dtype=np.int16), expected)
    # max_radius sizes reconstruct's tiles, which matters where the velocity varies.
    field = tmp_path / "velocity.npy"
    np.save(field, np.random.default_rng(2).normal(0, 4, size=(2, 24, 32)))
    small, large = tmp_path / "r2.png", tmp_path / "r20.png"
    for path, radius in ((small, "2"), (large, "20")):
        assert main(["blur", str(photo), "-o", str(path), "--velocity-file", str(field), "--method", "reconstruct", "--max-radius", radius]) == 0
    assert not np.array_equal(np.asarray(Image.open(small)), np.asarray(Image.open(large)))


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--method", "warp_blend", "--samples", "5"], r"--samples does not apply to method 'warp_blend'; it sets an option of reconstruct, gather"),
        (["--method", "gather", "--max-radius", "5"], r"--max-radius does not apply to method 'gather'"),
        (["--method", "gather", "--iterations", "2"], r"--iterations does not apply to method 'gather'; it sets an option of warp_blend"),
        (["--method", "gather", "--depth-image", "{photo}"], r"--depth-image: method 'gather' does not read depth; use --method reconstruct or bezier"),
        (["-o", "{tmp}/x.jpgx"], r"cannot write '.*x.jpgx': '.jpgx' is not an image format PIL writes; use e.g. .png"),
        (["-o", "{tmp}/no/such/folder/x.png"], r"no such folder for the output picture"),
    ],
)
def test_command_line_mistakes_are_caught_before_the_blur_runs(tmp_path, photo, capsys, monkeypatch, extra, message):
    import diffblur.app.blur_image

    def must_not_run(*args, **kwargs):
        raise AssertionError("the blur ran before the command line was checked")

    monkeypatch.setattr(diffblur.app.blur_image, "blur_image", must_not_run)
    monkeypatch.setattr(diffblur.app.blur_image, "load_inputs", must_not_run)
    args = ["blur", str(photo), "-o", str(tmp_path / "out.png"), "--velocity", "2", "0"] + [a.format(tmp=tmp_path, photo=photo) for a in extra]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("diffblur blur: error:") and re.search(message, err), err


def test_default_method_is_gather_without_depth_and_reconstruct_with_it(tmp_path, photo, capsys):
    """Without depth nothing separates by depth and the gather is the closest to the exact blur
    (scripts/measure_blur_methods_on_photo.py); with depth, reconstruct keeps smears behind what is in front."""
    from diffblur.app.blur_image import default_method

    assert default_method(False) == "gather" and default_method(True) == "reconstruct"
    assert main(["blur", str(photo), "-o", str(tmp_path / "a.png"), "--velocity", "2", "0"]) == 0
    assert "with gather on torch" in capsys.readouterr().out
    np.save(tmp_path / "depth.npy", np.ones((24, 32)))
    assert main(["blur", str(photo), "-o", str(tmp_path / "b.png"), "--velocity", "2", "0", "--depth-file", str(tmp_path / "depth.npy")]) == 0
    assert "with reconstruct on torch" in capsys.readouterr().out


def test_fit_boundary_reaches_the_model_and_is_refused_where_it_means_nothing(tmp_path, capsys, monkeypatch):
    import fitting._recover

    np.save(tmp_path / "sharp.npy", np.zeros((1, 1, 8, 8)))
    np.save(tmp_path / "ids.npy", np.zeros((8, 8), np.int64))
    seen = {}

    class Stop(Exception):
        pass

    def fake_recover(sharp, target, **kwargs):
        seen.update(kwargs)
        raise Stop

    monkeypatch.setattr(fitting._recover, "recover", fake_recover)
    files = [str(tmp_path / "sharp.npy"), str(tmp_path / "sharp.npy")]
    with pytest.raises(Stop):
        main(["fit", *files, "--model", "motion_ids", "--ids", str(tmp_path / "ids.npy"), "--boundary", "3", "--no-progress"])
    assert type(seen["model"]).__name__ == "MotionIds" and seen["model"].boundary == 3.0
    assert main(["fit", *files, "--model", "global", "--boundary", "3", "--no-progress"]) == 2
    assert "--boundary is an option of models motion_ids and layers, not of 'global'" in capsys.readouterr().err


@pytest.mark.parametrize(
    "velocity, exposure, warned",
    [(("1e9", "0"), "1", True), (("20", "0"), "2", True), (("20", "0"), "1", False), (("0", "-33"), "1", True), (("3", "4"), "1", False)],
)
def test_a_blur_longer_than_the_photograph_is_written_with_a_warning(tmp_path, photo, capsys, velocity, exposure, warned):
    """The 32x24 photo: a reach (speed x exposure) over 32 px warns on stderr, and the picture is
    still written (the ops take any finite velocity)."""
    out = tmp_path / "out.png"
    assert main(["blur", str(photo), "-o", str(out), "--velocity", *velocity, "--exposure", exposure]) == 0
    err = capsys.readouterr().err
    assert out.exists()
    if warned:
        assert re.search(r"warning: the blur reaches [\d.e+]+ px each way \(velocity x exposure\), more than the 32x24 photograph", err), err
    else:
        assert "warning" not in err, err
