"""Memory bounded by the image, not by its aspect: `bezier_scatter` (the op reported at more than
5 GB in bfloat16 on a 4097x1 image with mixed speeds, issue 25) on 1x4097 and 4097x1 images in every
dtype, forward and backward, peaks within 128 MB + 64 x the inputs' bytes.

Measured (scripts/measure_degenerate_memory.py, every op, both frameworks, in docs/robustness.md):
at most ~75 MB here, the half types' constant chunk of splat points; the 5 GB case did not recur on
this code. The peak is the resident-set high-water mark above the resting RSS, after a warm-up call.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

import torch_impl
from diffblur.app.bench import _peak_rss_mb


@pytest.mark.parametrize("shape", [(1, 4097), (4097, 1)], ids=["1x4097", "4097x1"])
@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16, torch.float32, torch.float64], ids=str)
def test_bezier_scatter_memory_on_a_line_image(dtype, shape):
    rng = np.random.default_rng(0)
    height, width = shape
    speed = np.where(rng.random((1, 1, height, width)) < 0.5, 0.0, rng.uniform(0.0, 40.0, size=(1, 1, height, width)))
    angle = rng.uniform(0.0, 2 * np.pi, size=(1, 1, height, width))
    host = [rng.random((1, 3, height, width)), np.concatenate([speed * np.cos(angle), speed * np.sin(angle)], axis=1), rng.uniform(1.0, 2.0, size=(1, 1, height, width))]

    def run():
        color, velocity, depth = (torch.tensor(a, dtype=dtype, requires_grad=True) for a in host)
        torch_impl.bezier_scatter(color, depth, -velocity, velocity, fill="color").float().sum().backward()

    run()
    peak = _peak_rss_mb(run)
    if peak is None:
        pytest.skip("no /proc/self/clear_refs on this system: the high-water mark cannot be reset")
    input_mb = sum(a.size for a in host) * torch.finfo(dtype).bits / 8 / 2**20
    assert peak <= 128 + 64 * input_mb, (peak, input_mb)
