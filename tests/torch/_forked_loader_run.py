"""Run by tests/torch/test_fork.py in a fresh process: the parent runs every fused op (forward and
backward), then a DataLoader with 2 forked workers builds the same blurred batch, then 2 threads
build it at once (numba's workqueue layer aborts the process on concurrent launches; the kernels
take a lock). Prints one JSON line: the threading layer numba chose and the largest differences.

A fresh process, because the test session's own (pytest, JAX's threads) is no fair parent to fork.
"""

from __future__ import annotations

import json
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import torch

import torch_impl


def sample(index: int) -> torch.Tensor:
    """Item `index`: the three fused ops on a seeded image, stacked."""
    rng = np.random.default_rng(index)
    color = torch.tensor(rng.random((1, 3, 10, 11)))
    velocity = torch.tensor(rng.normal(size=(1, 2, 10, 11)) * 2.0)
    depth = torch.tensor(rng.uniform(1.0, 2.0, size=(1, 1, 10, 11)))
    return torch.cat([
        torch_impl.reconstruct(color, velocity, depth, samples=5, impl="fused"),
        torch_impl.gather_blur(color, velocity, samples=5, impl="fused"),
        torch_impl.bezier_scatter(color, depth, -velocity, velocity, samples=5, impl="fused"),
    ])


class Blurred(torch.utils.data.Dataset):
    def __len__(self) -> int:
        return 4

    def __getitem__(self, index: int) -> torch.Tensor:
        return sample(index)


def main() -> None:
    import numba

    leaf = torch.rand(1, 3, 8, 9, dtype=torch.float64, requires_grad=True)
    torch_impl.reconstruct(leaf, leaf[:, :2], leaf[:, 2:] + 1.0, impl="fused").sum().backward()
    parent = torch.stack([sample(index) for index in range(4)])
    loader = torch.utils.data.DataLoader(Blurred(), batch_size=4, num_workers=2, multiprocessing_context="fork", timeout=120)
    (workers,) = list(loader)
    with ThreadPoolExecutor(2) as pool:
        threads = torch.stack(list(pool.map(sample, [index for _ in range(3) for index in range(4)])))
    print(json.dumps({
        "layer": numba.threading_layer(),
        "max_difference": float((workers - parent).abs().max()),
        "threads_max_difference": float((threads - parent.repeat(3, 1, 1, 1, 1)).abs().max()),
    }))


if __name__ == "__main__":
    main()
