"""Accuracy against the rendered ground truth, and short fits through the filter on it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import torch_impl
from diffblur import metrics
from diffblur.scenes import ImageTexture, Layer, Scene, Translation, make_scene, photo, render_buffers


@pytest.fixture(scope="module")
def scenes():
    return {name: make_scene(name, height=128, width=128) for name in ("translate", "crossing")}


@pytest.mark.parametrize("name", ["translate", "crossing"])
@pytest.mark.parametrize("sampling", ["bilinear", "nearest"])
def test_reconstruct_beats_gather_and_the_sharp_frame(scenes, name, sampling):
    """Seed 000's claim on its own cases: the filter blurs moving silhouettes over still
    backgrounds, which the per-pixel gather cannot. S = 15 as in the paper."""
    scene = scenes[name]
    color, velocity, depth = (torch.from_numpy(a) for a in (scene.color, scene.velocity, scene.depth))
    filtered = torch_impl.reconstruct(color, velocity, depth, samples=15, sampling=sampling).numpy()
    gathered = torch_impl.gather_blur(color, velocity, samples=15, sampling=sampling).numpy()
    psnr = {label: metrics.psnr(image, scene.target) for label, image in (("filter", filtered), ("gather", gathered), ("sharp", scene.color))}
    assert psnr["filter"] > psnr["gather"] > psnr["sharp"], psnr


def _global_translation(velocity=(3.0, -1.5), size=40):
    texture = ImageTexture(photo("coffee", size + 24, size + 24), origin=(-12, -12))
    scene = Scene(size, size, (Layer(texture, 5.0, Translation(velocity)),))
    return render_buffers(scene, shutter="box")


def test_short_fit_recovers_a_global_velocity_from_ground_truth():
    """Adam on one velocity vector for the whole image, through the differentiable filter,
    against the accumulated ground truth of a translating photograph (border cropped).

    Seed 000's taps sit at t = mix(-1, 1, (i + j + 1) / (S + 1)), so with the centre tap they span
    S / (S + 1) of the exposure: the filter under-blurs by that factor, and the velocity that
    matches the truth is the true one times (S + 1) / S (10/9 here)."""
    truth = _global_translation()
    color, depth, target = (torch.from_numpy(a) for a in (truth.color, truth.depth, truth.target))
    velocity = torch.tensor([1.0, 0.5], dtype=torch.float64, requires_grad=True)  # away from the v = 0 saddle
    optimizer = torch.optim.Adam([velocity], lr=0.1)
    crop = (slice(None), slice(None), slice(6, -6), slice(6, -6))
    for _ in range(90):
        optimizer.zero_grad()
        field = velocity.reshape(1, 2, 1, 1).expand(1, 2, *color.shape[2:])
        out = torch_impl.reconstruct(color, field, depth, samples=9, max_radius=8.0)
        loss = ((out - target)[crop] ** 2).mean()
        loss.backward()
        optimizer.step()
    recovered = velocity.detach().numpy()
    expected = np.array([3.0, -1.5]) * 10 / 9
    # A symmetric shutter blurs +v like -v: the velocity is recovered up to sign.
    assert min(np.abs(recovered - expected).max(), np.abs(recovered + expected).max()) < 0.1, recovered


def test_short_fit_recovers_the_exposure_on_a_preset(scenes):
    """The exposure (a scale on the scene's true velocity) fitted against the ground truth of
    `translate` comes out near 1, from a start at 0.4."""
    scene = scenes["translate"]
    color, velocity, depth, target = (torch.from_numpy(a) for a in (scene.color, scene.velocity, scene.depth, scene.target))
    layer = torch_impl.MotionBlur("reconstruct", samples=9, exposure=0.4, learn_exposure=True).double()
    optimizer = torch.optim.Adam(layer.parameters(), lr=0.05)
    for _ in range(60):
        optimizer.zero_grad()
        loss = ((layer(color, velocity, depth) - target) ** 2).mean()
        loss.backward()
        optimizer.step()
    assert abs(layer.exposure.item() - 1.0) < 0.1, layer.exposure.item()


def test_reconstruct_gradients_are_finite_at_the_extremes(backend):
    """Velocity exactly 0, far beyond the tile, and depths that tie everywhere."""
    rng = np.random.default_rng(4)
    color = backend.array(rng.random((1, 3, 12, 13)))
    ties = backend.array(np.full((1, 1, 12, 13), 2.0))
    for velocity in (np.zeros((1, 2, 12, 13)), np.full((1, 2, 12, 13), 50.0), rng.normal(size=(1, 2, 12, 13)) * 3):
        grads = backend.grad(lambda c, v, z: backend.ops.reconstruct(c, v, z, samples=5, max_radius=4.0), color, backend.array(velocity), ties)
        for g in grads:
            assert np.all(np.isfinite(g))
        assert np.abs(grads[0]).sum() > 0
