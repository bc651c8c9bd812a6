"""`diffblur blur` on photographs: buffers from the command line, readable errors."""

from __future__ import annotations

import re

import numpy as np
import pytest
from PIL import Image

from diffblur.blur_image import load_inputs, read_picture
from diffblur.cli import main


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
