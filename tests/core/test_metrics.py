"""Metrics and pictures: PSNR/SSIM on NCHW batches, the velocity colour wheel, error maps."""

from __future__ import annotations

import math

import numpy as np
import pytest
from skimage.metrics import structural_similarity

from diffblur import metrics


def test_psnr_hand_computed():
    target = np.zeros((1, 3, 8, 9))
    prediction = np.full((1, 3, 8, 9), 0.1)  # MSE 0.01
    assert metrics.psnr(prediction, target) == pytest.approx(20.0)
    assert metrics.psnr(prediction, target, data_range=2.0) == pytest.approx(20.0 + 20 * math.log10(2.0))
    assert metrics.psnr(target, target) == math.inf


def test_psnr_averages_over_the_batch():
    target = np.zeros((2, 1, 6, 6))
    prediction = np.stack([np.full((1, 6, 6), 0.1), np.full((1, 6, 6), 0.01)])  # 20 dB and 40 dB
    np.testing.assert_allclose(metrics.psnr(prediction, target, reduction="none"), [20.0, 40.0])
    assert metrics.psnr(prediction, target) == pytest.approx(30.0)


def test_ssim_matches_scikit_image_on_channels_last():
    rng = np.random.default_rng(0)
    target = rng.random((2, 3, 20, 24))
    prediction = np.clip(target + 0.1 * rng.standard_normal(target.shape), 0, 1)
    expected = [
        structural_similarity(t.transpose(1, 2, 0), p.transpose(1, 2, 0), data_range=1.0, channel_axis=-1)
        for p, t in zip(prediction, target)
    ]
    np.testing.assert_allclose(metrics.ssim(prediction, target, reduction="none"), expected, rtol=1e-12)
    assert metrics.ssim(prediction, target) == pytest.approx(np.mean(expected), rel=1e-12)
    assert metrics.ssim(target, target) == pytest.approx(1.0)
    # A larger data range makes the same error look smaller.
    assert metrics.ssim(prediction, target, data_range=4.0) > metrics.ssim(prediction, target)


def test_metric_argument_errors():
    a = np.zeros((1, 3, 8, 8))
    with pytest.raises(ValueError, match=r"prediction must have the shape of target \(1, 3, 8, 9\)"):
        metrics.psnr(a, np.zeros((1, 3, 8, 9)))
    with pytest.raises(ValueError, match="target must be a 4-d"):
        metrics.ssim(a, np.zeros((3, 8, 8)))
    with pytest.raises(TypeError, match="prediction must have a floating dtype"):
        metrics.psnr(np.zeros((1, 3, 8, 8), dtype=np.uint8), a)
    with pytest.raises(ValueError, match="data_range must be > 0, got 0"):
        metrics.psnr(a, a, data_range=0.0)
    with pytest.raises(ValueError, match="win_size must be an odd integer >= 1, got 4"):
        metrics.ssim(a, a, win_size=4)
    with pytest.raises(ValueError, match="win_size must be <= min"):
        metrics.ssim(a, a, win_size=9)
    with pytest.raises(ValueError, match="reduction must be one of 'mean', 'none'; got 'sum'"):
        metrics.psnr(a, a + 0.1, reduction="sum")


def test_velocity_to_color_wheel_directions():
    # One pixel each: +x, +y (down), -x, -y, zero, half speed along +x.
    v = np.array([[1, 0], [0, 1], [-1, 0], [0, -1], [0, 0], [0.5, 0]], dtype=float).T.reshape(1, 2, 1, 6)
    rgb = metrics.velocity_to_color(v, max_magnitude=1.0)[0, :, 0].T
    np.testing.assert_allclose(rgb[0], [1, 0, 0], atol=1e-12)  # red: rightwards
    np.testing.assert_allclose(rgb[1], [0.5, 1, 0], atol=1e-12)  # hue 1/4: downwards
    np.testing.assert_allclose(rgb[2], [0, 1, 1], atol=1e-12)  # cyan: leftwards
    np.testing.assert_allclose(rgb[3], [0.5, 0, 1], atol=1e-12)  # hue 3/4: upwards
    np.testing.assert_allclose(rgb[4], [1, 1, 1], atol=1e-12)  # still: white
    np.testing.assert_allclose(rgb[5], [1, 0.5, 0.5], atol=1e-12)  # half saturation
    # Default scale: the largest speed in the field is fully saturated.
    np.testing.assert_allclose(metrics.velocity_to_color(3 * v)[0, :, 0, 0], [1, 0, 0], atol=1e-12)
    with pytest.raises(ValueError, match=r"velocity must have 2 channel\(s\)"):
        metrics.velocity_to_color(np.zeros((1, 3, 4, 4)))


def test_color_wheel_legend():
    wheel = metrics.color_wheel(33)
    assert wheel.shape == (1, 3, 33, 33)
    np.testing.assert_allclose(wheel[0, :, 16, 16], [1, 1, 1])  # centre: no motion
    np.testing.assert_allclose(wheel[0, :, 16, 32], [1, 0, 0])  # right edge: +x
    np.testing.assert_allclose(wheel[0, :, 32, 16], [0.5, 1, 0])  # bottom edge: +y


def test_to_display_is_srgb():
    linear = np.array([0.0, 0.001, 0.5, 1.0, 1.7]).reshape(1, 1, 1, 5)
    shown = metrics.to_display(linear)
    assert shown.shape == (1, 1, 5, 1)
    expected = [0.0, 12.92 * 0.001, 1.055 * 0.5 ** (1 / 2.4) - 0.055, 1.0, 1.0]
    np.testing.assert_allclose(shown[0, 0, :, 0], expected, rtol=1e-12)


def test_error_map_picture(tmp_path):
    rng = np.random.default_rng(1)
    target = rng.random((2, 3, 16, 20))
    prediction = target.copy()
    prediction[:, :, 4:8, 5:9] += 0.3
    fig = metrics.error_map_figure(prediction, target)
    images = [ax.images[0].get_array() for ax in fig.axes if ax.images]
    # Per row: prediction, target, error; the error map is the channel mean of |difference|.
    assert len(images) == 6
    np.testing.assert_allclose(np.asarray(images[2]), np.abs(prediction - target).mean(axis=1)[0])
    assert "PSNR" in fig.axes[2].get_title()
    path = metrics.save_error_map(tmp_path / "err.png", prediction, target, vmax=0.5)
    with open(path, "rb") as handle:
        assert handle.read(8) == b"\x89PNG\r\n\x1a\n"
