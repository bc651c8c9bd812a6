"""The PyTorch layer under DistributedDataParallel: two CPU processes (gloo) training a tiny model
on halves of a batch get the gradients, and after a few steps the parameters, of one process
training on the whole batch.

DDP averages the two processes' gradients; each process's loss is the mean over its half, so
the average equals the gradient of the mean over the whole batch.
"""

from __future__ import annotations

import os
import socket
import time
import warnings
from datetime import timedelta
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
import torch.multiprocessing as mp
from torch import nn

import torch_impl

BATCH, STEPS, WORLD = 4, 3, 2
#: Seconds the workers get to exit after rank 0 saved its results, and to run at all.
TEARDOWN_GRACE, RUN_LIMIT = 30.0, 600.0


class TinyBlurNet(nn.Module):
    """A 3x3 convolution predicts a velocity field from the sharp image; the MotionBlur layer (its
    exposure learnable) blurs the image with it."""

    def __init__(self):
        super().__init__()
        torch.manual_seed(0)
        self.velocity = nn.Conv2d(3, 2, 3, padding=1, dtype=torch.float64)
        self.blur = torch_impl.MotionBlur("reconstruct", samples=5, max_radius=4.0, learn_exposure=True)
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
            # Written whole, then renamed: the test takes the file's existence as "saved".
            torch.save({"grads": grads, "params": params}, out_path + ".part")
            os.replace(out_path + ".part", out_path)
    finally:
        dist.destroy_process_group()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _run_workers(out_path: Path) -> None:
    """mp.spawn of the workers, stopping them if they hang in teardown after rank 0 saved its results.

    ProcessGroupGloo's destructor (in destroy_process_group) joins its worker thread while holding the
    GIL, and that thread can need the GIL to free its last work item: a deadlock inside PyTorch
    (pytorch/pytorch#56297), seen once here, a clean-clone run hanging for minutes. It comes after the
    results are saved, so workers still alive TEARDOWN_GRACE seconds after them are stopped."""
    context = mp.spawn(_worker, args=(_free_port(), str(out_path)), nprocs=WORLD, join=False)
    start, saved = time.monotonic(), None
    while not context.join(timeout=1.0):  # raises if a worker failed
        now = time.monotonic()
        if saved is None and out_path.exists():
            saved = now
        if saved is not None and now - saved > TEARDOWN_GRACE:
            for process in context.processes:
                process.kill()
                process.join()
            warnings.warn(f"the DDP workers hung in teardown for {TEARDOWN_GRACE:.0f} s after saving their results; stopped them", stacklevel=1)
            return
        assert now - start < RUN_LIMIT, f"the DDP workers saved nothing in {RUN_LIMIT} s"


def test_ddp_on_two_processes_equals_one_process(tmp_path):
    out_path = tmp_path / "rank0.pt"
    _run_workers(out_path)
    distributed = torch.load(out_path)
    single_grads, single_params = train(TinyBlurNet(), *data())
    assert set(distributed["grads"]) == {f"module.{n}" for n in single_grads}
    for name, grad in single_grads.items():
        assert grad.abs().max() > 0, f"{name}: no gradient to compare"
        torch.testing.assert_close(distributed["grads"][f"module.{name}"], grad, rtol=1e-10, atol=1e-12, msg=name)
    for name, param in single_params.items():
        torch.testing.assert_close(distributed["params"][f"module.{name}"], param, rtol=1e-10, atol=1e-12, msg=name)
