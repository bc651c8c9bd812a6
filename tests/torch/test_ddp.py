"""The PyTorch layer under DistributedDataParallel: two CPU processes (gloo) training a tiny model
on halves of a batch get the gradients, and after a few steps the parameters, of one process
training on the whole batch.

DDP averages the two processes' gradients; each process's loss is the mean over its half, so
the average equals the gradient of the mean over the whole batch.
"""

from __future__ import annotations

import socket
from datetime import timedelta

import numpy as np
import torch
import torch.distributed as dist
import torch.multiprocessing as mp
from torch import nn

import torch_impl

BATCH, STEPS, WORLD = 4, 3, 2


class TinyBlurNet(nn.Module):
    """A 3x3 convolution predicts a velocity field from the sharp image; the MotionBlur layer (its
    exposure learnable) blurs the image with it."""

    def __init__(self):
        super().__init__()
        torch.manual_seed(0)
        self.velocity = nn.Conv2d(3, 2, 3, padding=1, dtype=torch.float64)
        self.blur = torch_impl.MotionBlur("reconstruct", samples=5, max_radius=4.0)
        self.blur.exposure.data = self.blur.exposure.data.double()

    def forward(self, color, depth):
        return self.blur(color, 3.0 * self.velocity(color), depth)


def data():
    rng = np.random.default_rng(3)
    color = torch.tensor(rng.random((BATCH, 3, 12, 13)))
    depth = torch.tensor(rng.uniform(1.0, 2.0, size=(BATCH, 1, 12, 13)))
    target = torch.tensor(rng.random((BATCH, 3, 12, 13)))
    return color, depth, target


def train(model, color, depth, target):
    """STEPS of SGD; returns the first step's gradients and the final parameters, by name."""
    optimizer = torch.optim.SGD(model.parameters(), lr=0.1)
    first = None
    for _ in range(STEPS):
        optimizer.zero_grad()
        loss = ((model(color, depth) - target) ** 2).mean()
        loss.backward()
        if first is None:
            first = {n: p.grad.detach().clone() for n, p in model.named_parameters()}
        optimizer.step()
    return first, {n: p.detach().clone() for n, p in model.named_parameters()}


def _worker(rank: int, port: int, out_path: str) -> None:
    torch.set_num_threads(1)
    dist.init_process_group("gloo", init_method=f"tcp://127.0.0.1:{port}", rank=rank, world_size=WORLD, timeout=timedelta(seconds=120))
    try:
        model = nn.parallel.DistributedDataParallel(TinyBlurNet())
        color, depth, target = data()
        part = slice(rank * BATCH // WORLD, (rank + 1) * BATCH // WORLD)
        grads, params = train(model, color[part], depth[part], target[part])
        if rank == 0:  # DDP names parameters "module.<name>"
            torch.save({"grads": grads, "params": params}, out_path)
    finally:
        dist.destroy_process_group()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_ddp_on_two_processes_equals_one_process(tmp_path):
    out_path = str(tmp_path / "rank0.pt")
    mp.spawn(_worker, args=(_free_port(), out_path), nprocs=WORLD, join=True)
    distributed = torch.load(out_path)
    single_grads, single_params = train(TinyBlurNet(), *data())
    assert set(distributed["grads"]) == {f"module.{n}" for n in single_grads}
    for name, grad in single_grads.items():
        assert grad.abs().max() > 0, f"{name}: no gradient to compare"
        torch.testing.assert_close(distributed["grads"][f"module.{name}"], grad, rtol=1e-10, atol=1e-12, msg=name)
    for name, param in single_params.items():
        torch.testing.assert_close(distributed["params"][f"module.{name}"], param, rtol=1e-10, atol=1e-12, msg=name)
