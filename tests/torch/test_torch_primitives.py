"""PyTorch specifics: dtypes and devices kept, non-contiguous and channels-last input, eager
data checks skipped (not wrong) under torch.compile."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import torch_impl

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


def all_ops(velocity):
    depth = velocity[:, :1].abs() + 1.0
    speed = torch_impl.safe_length(velocity)
    return {
        "soft_depth_compare": torch_impl.soft_depth_compare(depth, depth.flip(-1), 0.1),
        "cone": torch_impl.cone(speed.flip(-1), speed),
        "cylinder": torch_impl.cylinder(speed.flip(-1), speed),
        "safe_length": speed,
        "velocity_from_motion": torch_impl.velocity_from_motion(velocity, exposure=0.5),
        "tile_max": torch_impl.tile_max(velocity, 3),
        "neighbor_max": torch_impl.neighbor_max(torch_impl.tile_max(velocity, 3)),
    }


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16, torch.float32, torch.float64])
def test_dtype_and_device_are_kept(dtype, device):
    velocity = (torch.randn(2, 2, 7, 8, generator=torch.Generator().manual_seed(0)) * 3).to(device=device, dtype=dtype)
    for name, out in all_ops(velocity).items():
        assert out.dtype == dtype and out.device.type == device, name
        assert torch.isfinite(out).all(), name
    noise = torch_impl.interleaved_gradient_noise(4, 5, dtype=dtype, device=device)
    assert noise.dtype == dtype and noise.device.type == device


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the CPU fallback message only when no GPU is present")
def test_mismatched_devices_would_be_named():
    from diffblur import checks
    from torch_impl._backend import TORCH

    a = torch.zeros(3)
    b = torch.zeros(3, device="meta")
    with pytest.raises(ValueError, match=r"z_b must be on the device of z_a \(cpu\), got meta"):
        checks.same_dtype_and_device(TORCH, "z_b", b, "z_a", a)


def test_non_contiguous_and_channels_last_inputs_give_the_same_result():
    velocity = torch.randn(2, 2, 9, 10, generator=torch.Generator().manual_seed(1), dtype=torch.float64) * 4
    expected = all_ops(velocity)
    channels_last = velocity.contiguous(memory_format=torch.channels_last)
    transposed = velocity.transpose(2, 3).contiguous().transpose(2, 3)
    assert not transposed.is_contiguous()
    for variant in (channels_last, transposed):
        for name, out in all_ops(variant).items():
            torch.testing.assert_close(out, expected[name], rtol=0, atol=0, msg=name)


def test_reconstruct_under_inference_mode_then_with_gradients():
    """The "noise" jitter is kept between calls (`diffblur.reference.noise_jitter`): what a first
    call under inference mode keeps must not stop a later call from being differentiated."""
    from diffblur import reference

    reference.noise_jitter.cache_clear()  # so the call under inference mode is the one that makes it
    generator = torch.Generator().manual_seed(3)
    color = torch.rand(1, 3, 17, 23, generator=generator)
    velocity = (torch.rand(1, 2, 17, 23, generator=generator) - 0.5) * 8
    depth = torch.rand(1, 1, 17, 23, generator=generator) + 1
    with torch.inference_mode():
        expected = torch_impl.reconstruct(color, velocity, depth)
    velocity.requires_grad_()
    out = torch_impl.reconstruct(color, velocity, depth)
    out.sum().backward()
    torch.testing.assert_close(out.detach(), expected, rtol=0, atol=0)
    assert velocity.grad.abs().sum() > 0


def test_data_checks_are_skipped_not_wrong_under_compile():
    """Under torch.compile the extent sign check is skipped (documented); the result is what the
    formula gives, and eager mode still raises."""
    z = torch.ones(3)
    with pytest.raises(ValueError, match="extent must be > 0 everywhere"):
        torch_impl.soft_depth_compare(z, z, torch.tensor(-1.0))
    compiled = torch.compile(torch_impl.soft_depth_compare, fullgraph=True)
    out = compiled(z, z + 0.05, torch.tensor(0.1))
    np.testing.assert_allclose(out.numpy(), 0.5, rtol=1e-6)


def test_fit_exposure_through_velocity_from_motion():
    """A useful gradient: Adam recovers an exposure of 0.6 from the velocity it produces."""
    displacement = torch.randn(1, 2, 6, 6, generator=torch.Generator().manual_seed(2), dtype=torch.float64) * 8
    target = torch_impl.velocity_from_motion(displacement, exposure=0.6)
    exposure = torch.tensor(1.0, dtype=torch.float64, requires_grad=True)
    optimizer = torch.optim.Adam([exposure], lr=0.05)
    for _ in range(200):
        optimizer.zero_grad()
        loss = ((torch_impl.velocity_from_motion(displacement, exposure=exposure) - target) ** 2).mean()
        loss.backward()
        optimizer.step()
    assert abs(exposure.item() - 0.6) < 1e-3


def _saved_planes(samples: int, height: int = 24, width: int = 40) -> float:
    """Full-resolution planes autograd keeps for reconstruct's backward (unique storages)."""
    rng = np.random.default_rng(0)
    inputs = [rng.random((1, 3, height, width)), rng.normal(size=(1, 2, height, width)) * 4, rng.uniform(1, 2, size=(1, 1, height, width))]
    color, velocity, depth = (torch.tensor(a, dtype=torch.float32, requires_grad=True) for a in inputs)
    storages = {}

    def pack(tensor):
        storages[tensor.untyped_storage().data_ptr()] = tensor.untyped_storage().nbytes()
        return tensor

    with torch.autograd.graph.saved_tensors_hooks(pack, lambda tensor: tensor):
        torch_impl.reconstruct(color, velocity, depth, samples=samples, max_radius=8.0)
    return sum(storages.values()) / (height * width * 4)


def test_reconstruct_backward_memory_does_not_grow_with_taps():
    """Each tap is recomputed in the backward pass (activation checkpointing), so what autograd
    keeps is O(pixels), the same for 3 taps as for 31."""
    few, many = _saved_planes(3), _saved_planes(31)
    # The fused kernel's custom operator also keeps per-tap scalars (a few bytes): far below a plane.
    assert abs(many - few) < 0.01, (few, many)
    assert few < 40
