"""examples/learn_motion's PyTorch model (U-Net + torch_impl.MotionBlur) in a real training loop: a
batch of different motions, bfloat16 autocast, torch.compile of the whole model, DDP on 2 processes.

tests/torch/test_ddp.py already holds the layer alone (a 3x3 convolution and MotionBlur's exposure)
under DDP; tests/equivalence/test_module*.py compile the layer alone. Here the whole model does.
"""

from __future__ import annotations

import os
import socket
import time
from datetime import timedelta

import numpy as np
import pytest
import torch
import torch.distributed as dist
import torch.multiprocessing as mp

from examples.learn_motion.common import smoothness
from examples.learn_motion.torch_model import MotionNet, loss_fn
from tests.examples._learn_motion import CONFIG, different_motions, scenes


def model(dtype=torch.float64, seed: int = 0) -> MotionNet:
    """The example's model, its head drawn at random (it starts at zero: no gradient would reach the
    layers below it before a first step)."""
    torch.manual_seed(seed)
    net = MotionNet(CONFIG.method, CONFIG.motion, width=CONFIG.width, scale=CONFIG.scale)
    torch.nn.init.normal_(net.unet.head.weight, std=0.3)
    return net.to(dtype)


def tensors(data: dict, dtype=torch.float64, index=slice(None)):
    return tuple(torch.from_numpy(np.ascontiguousarray(data[name][index])).to(dtype) for name in ("frames", "color", "depth", "target"))


def loss_and_grads(net: torch.nn.Module, batch, shutter: int = 0):
    frames, color, depth, target = batch
    net.zero_grad(set_to_none=True)
    blurred, _ = net(frames, color, depth, shutter)
    loss = ((blurred - target) ** 2).mean()
    loss.backward()
    # Parameter names without the wrappers' prefixes (torch.compile's, DDP's).
    return loss.detach(), {_name(name): p.grad.detach().clone() for name, p in net.named_parameters()}


def _name(name: str) -> str:
    return name.removeprefix("_orig_mod.").removeprefix("module.")


def test_a_batch_of_different_motions_equals_each_example_alone():
    """Four scenes with four different motions in one batch: each example's blur and motion are those
    of the example alone, and the batch's gradient is the mean of the examples' (float64, 1e-12)."""
    data = scenes(shutter=2)  # a ramp: the direction of motion shows in the blur
    assert different_motions(data)
    net = model()
    frames, color, depth, target = tensors(data)
    with torch.no_grad():
        blurred, motion = net(frames, color, depth, 2)
        for k in range(len(frames)):
            alone, alone_motion = net(frames[k : k + 1], color[k : k + 1], depth[k : k + 1], 2)
            torch.testing.assert_close(blurred[k : k + 1], alone, rtol=0, atol=1e-12)
            torch.testing.assert_close(motion[k : k + 1], alone_motion, rtol=0, atol=1e-12)
    assert motion.std(dim=(1, 2, 3)).min() > 0 and (motion[0] - motion[1]).abs().max() > 1e-3
    _, batch_grads = loss_and_grads(net, (frames, color, depth, target), 2)
    singles = [loss_and_grads(net, tuple(t[k : k + 1] for t in (frames, color, depth, target)), 2)[1] for k in range(len(frames))]
    for name, grad in batch_grads.items():
        assert grad.abs().max() > 0, name
        torch.testing.assert_close(grad, sum(s[name] for s in singles) / len(singles), rtol=1e-9, atol=1e-12, msg=name)


def test_bfloat16_autocast_gives_a_finite_loss_and_float32s_gradients():
    """Under torch.autocast(cpu, bfloat16) the U-Net's convolutions run in bfloat16 and the blur in
    float32 (the model casts the motion to the colour's dtype): the loss is finite and within 2 % of
    float32's; the whole gradient is within 10 % of float32's and each parameter's within 30 %
    (relative to its norm; bfloat16 keeps 8 bits of mantissa through the U-Net's backward)."""
    data = scenes(shutter=0)
    net = model(torch.float32)
    batch = tensors(data, torch.float32)
    loss32, grads32 = loss_and_grads(net, batch)
    seen = []
    hook = net.unet.register_forward_hook(lambda module, inputs, output: seen.append(output.dtype))
    with torch.autocast("cpu", dtype=torch.bfloat16):
        blurred, _ = net(*batch[:3], 0)
        assert seen == [torch.bfloat16] and blurred.dtype == torch.float32
        loss16, grads16 = loss_and_grads(net, batch)
    hook.remove()
    assert torch.isfinite(loss16) and abs(loss16 - loss32) <= 0.02 * loss32, (loss16, loss32)
    for name, grad in grads32.items():
        assert torch.isfinite(grads16[name]).all() and grads16[name].dtype == torch.float32, name
        error = (grads16[name] - grad).norm() / grad.norm()
        assert error < 0.3, (name, float(error))  # measured 0.03-0.23 (bfloat16 keeps 8 bits)
    every16, every32 = (torch.cat([g[name].flatten() for name in grads32]) for g in (grads16, grads32))
    assert (every16 - every32).norm() / every32.norm() < 0.1


def test_torch_compile_of_the_whole_model_equals_eager():
    """torch.compile of U-Net + MotionBlur (fullgraph, backend "aot_eager": AOTAutograd's forward and
    backward graphs without inductor's code generation, which takes minutes here): the loss, every
    gradient and the parameters after an Adam step equal eager's (float32, 1e-6)."""
    data = scenes(shutter=1)
    batch = tensors(data, torch.float32)
    eager, compiled_net = model(torch.float32), model(torch.float32)
    compiled = torch.compile(compiled_net, backend="aot_eager", fullgraph=True)
    results = []
    for net, params in ((eager, eager), (compiled, compiled_net)):
        optimizer = torch.optim.Adam(params.parameters(), lr=1e-2)
        loss, grads = loss_and_grads(net, batch, 1)
        optimizer.step()
        results.append((loss, grads, {n: p.detach().clone() for n, p in params.named_parameters()}))
    (loss_e, grads_e, after_e), (loss_c, grads_c, after_c) = results
    torch.testing.assert_close(loss_c, loss_e, rtol=1e-6, atol=0)
    for name in grads_e:
        assert grads_e[name].abs().max() > 0, name
        torch.testing.assert_close(grads_c[name], grads_e[name], rtol=1e-5, atol=1e-7, msg=name)
        torch.testing.assert_close(after_c[name], after_e[name], rtol=1e-6, atol=1e-7, msg=name)


def total_variation(motion: np.ndarray) -> float:
    """The prior written out by loops: mean |horizontal neighbour difference| + mean |vertical one|."""
    batch, channels, height, width = motion.shape
    across = sum(abs(motion[b, c, y, x + 1] - motion[b, c, y, x]) for b in range(batch) for c in range(channels) for y in range(height) for x in range(width - 1))
    down = sum(abs(motion[b, c, y + 1, x] - motion[b, c, y, x]) for b in range(batch) for c in range(channels) for y in range(height - 1) for x in range(width))
    return across / (batch * channels * height * (width - 1)) + down / (batch * channels * (height - 1) * width)


def test_the_training_loss_is_the_blur_error_plus_the_smoothness_prior_in_both_frameworks():
    """torch_model.loss_fn = mean squared error of the blur + config.smoothness x the total variation of
    the predicted motion (checked against loops, float64, 1e-12); with smoothness 0 the blur's error
    alone; the prior's gradient reaches the U-Net; and jax_model.loss_fn on the same weights gives the
    same loss (float64, 1e-6)."""
    from dataclasses import replace

    data = scenes(shutter=2)
    net = model()
    frames, color, depth, target = tensors(data)
    assert CONFIG.smoothness > 0
    loss = loss_fn(net, frames, color, depth, target, 2, CONFIG)
    with torch.no_grad():
        blurred, motion = net(frames, color, depth, 2)
    mse = float(((blurred - target) ** 2).mean())
    prior = total_variation(motion.numpy())
    assert prior > 0.01 and abs(float(smoothness(motion)) - prior) <= 1e-12 * prior
    # The edge-aware variant (tried on the validation split, not the default) counts colour edges less.
    assert float(smoothness(motion, color, edge=10.0)) < prior and float(smoothness(motion, color, edge=0.0)) == float(smoothness(motion))
    np.testing.assert_allclose(float(loss.detach()), mse + CONFIG.smoothness * prior, rtol=1e-12)
    np.testing.assert_allclose(float(loss_fn(net, frames, color, depth, target, 2, replace(CONFIG, smoothness=0.0)).detach()), mse, rtol=1e-12)
    net.zero_grad(set_to_none=True)
    (loss - ((net(frames, color, depth, 2)[0] - target) ** 2).mean()).backward()  # the prior's gradient alone
    assert net.unet.head.weight.grad.abs().max() > 0 and net.unet.down[0][0].weight.grad.abs().max() > 0

    import jax.numpy as jnp  # float64: the root conftest enables x64

    from examples.learn_motion import jax_model

    jnet = jax_model.from_torch({name: value.detach().numpy() for name, value in net.state_dict().items()}, CONFIG, dtype=jnp.float64)
    jloss = jax_model.loss_fn(jnet, *(jnp.asarray(data[name], dtype=jnp.float64) for name in ("frames", "color", "depth", "target")), 2, CONFIG)
    # 1e-6: the two models' motions differ by about 1e-6 px here even in float64 (loss: 5e-8 relative).
    np.testing.assert_allclose(float(jloss), float(loss.detach()), rtol=1e-6)


# DDP: two gloo processes, each the half of a batch of 4, one Adam step; rank 0 writes its parameters.
WORLD, STEPS = 2, 2


def _train(net: torch.nn.Module, batch, steps: int = STEPS) -> dict:
    optimizer = torch.optim.Adam(net.parameters(), lr=1e-2)
    for _ in range(steps):
        loss_and_grads(net, batch, 2)
        optimizer.step()
    return {_name(name): p.detach().clone() for name, p in net.named_parameters()}


def _ddp_worker(rank: int, port: int, out: str, data: dict) -> None:
    torch.set_num_threads(1)
    dist.init_process_group("gloo", init_method=f"tcp://127.0.0.1:{port}", rank=rank, world_size=WORLD, timeout=timedelta(seconds=120))
    try:
        half = slice(2 * rank, 2 * rank + 2)
        params = _train(torch.nn.parallel.DistributedDataParallel(model()), tensors(data, index=half))
        if rank == 0:
            torch.save(params, out + ".part")
            os.replace(out + ".part", out)
    finally:
        dist.destroy_process_group()


def test_ddp_on_two_processes_equals_one_process(tmp_path):
    """DDP (gloo, 2 CPU processes by torch.multiprocessing spawn) training the whole model on halves
    of a batch of 4 different motions: after 2 Adam steps the parameters are those of one process on
    the whole batch (float64, 1e-10). Workers still alive 30 s after rank 0 wrote its result are
    stopped (gloo's teardown can hang, see tests/torch/test_ddp.py)."""
    out = tmp_path / "rank0.pt"
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    data = scenes(shutter=2)
    context = mp.spawn(_ddp_worker, args=(port, str(out), data), nprocs=WORLD, join=False)
    deadline, written = time.monotonic() + 300, None
    while not context.join(timeout=1.0):
        if written is None and out.exists():
            written = time.monotonic()
        if written is not None and time.monotonic() - written > 30:
            for process in context.processes:
                process.kill()
            break
        assert time.monotonic() < deadline, "the DDP workers wrote nothing in 300 s"
    distributed = torch.load(out)
    single = _train(model(), tensors(data))
    initial = dict(model().named_parameters())
    assert set(distributed) == set(single)
    for name, param in single.items():
        assert (param - initial[name]).abs().max() > 1e-4, name  # the step moved it
        torch.testing.assert_close(distributed[name], param, rtol=1e-10, atol=1e-12, msg=name)
