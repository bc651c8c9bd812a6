"""Guards against inductor's wrong code (issue 25), checked without paying for inductor's compile.

`warp_blend` with iterations >= 2 under `torch.compile`: inductor (torch 2.13, CPU) returned the
right output but a colour gradient off by up to 0.76 (float64, 1x3x8x9). Its passes now run eagerly
(a graph break); the test compiles with a backend that records each graph and runs it as traced
(`aot_eager`'s numbers, so the comparison is exact), and checks that no gather reaches a compiled
graph, and that outputs and gradients equal eager's. The inductor comparison itself, minutes of
compile per op, is `scripts/measure_compile_vs_eager.py` (its table is in BENCHMARKS.md).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

import torch_impl


def _inputs():
    rng = np.random.default_rng(0)
    return torch.tensor(rng.random((1, 3, 8, 9)), requires_grad=True), torch.tensor(rng.normal(size=(1, 2, 8, 9)) * 2.0, requires_grad=True)


def _value_and_grads(fn):
    color, velocity = _inputs()
    out = fn(color, velocity)
    weights = torch.tensor(np.random.default_rng(1).random(tuple(out.shape)))
    grads = torch.autograd.grad((out * weights).sum(), (color, velocity))
    return [out.detach(), *grads]


@pytest.mark.parametrize("iterations", [1, 2, 3])
def test_warp_blend_chained_reads_stay_out_of_compiled_graphs(iterations):
    graphs = []

    def recording(graph_module, example_inputs):
        graphs.append(graph_module)
        return graph_module.forward

    fn = lambda color, velocity: torch_impl.warp_blend(color, velocity, iterations=iterations)  # noqa: E731
    torch._dynamo.reset()
    compiled = _value_and_grads(torch.compile(fn, backend=recording, dynamic=False))
    eager = _value_and_grads(fn)
    for got, want in zip(compiled, eager):
        assert torch.equal(got, want)
    gathers = sum(node.target is torch.gather for graph in graphs for node in graph.graph.nodes)
    if iterations == 1:  # one pass has no chained reads: it compiles whole
        assert gathers == 8
    else:
        assert gathers == 0


# A NaN velocity under torch.compile (which skipped the data checks, as it still does off the CPU) made NaN tap positions, whose
# integer indices fell outside the image: eager aten raised, inductor's generated C++ aborted the
# process ("index out of bounds: 0 <= tmp50 < 272" on a 16x17 image). The indices are now clamped.
# The test skips the checks as torch.compile does and runs eagerly (an inductor compile is ~20 s of
# CPU; `scripts/measure_compile_vs_eager.py` has the compiled case): eager aten raised there too.
NAN_CALLS = {
    "bilinear": lambda c, v: torch_impl.gather_blur(c, v, samples=3, impl="tensor"),
    "nearest": lambda c, v: torch_impl.gather_blur(c, v, samples=3, sampling="nearest", impl="tensor"),
    "adaptive": lambda c, v: torch_impl.gather_blur(c, v, samples=3, adaptive=True, impl="tensor"),
    "pyramid": lambda c, v: torch_impl.gather_blur(c, v, samples=3, sampling="pyramid", impl="tensor"),
    # The fused kernels run under torch.compile too (custom operators): they clamp their reads.
    "fused": lambda c, v: torch_impl.gather_blur(c, v, samples=3, impl="fused"),
    "fused adaptive": lambda c, v: torch_impl.gather_blur(c, v, samples=3, adaptive=True, impl="fused"),
    "fused reconstruct": lambda c, v: torch_impl.reconstruct(c, v, torch.ones_like(c[:, :1]), samples=3, max_radius=1.0, impl="fused"),
    "fused scatter": lambda c, v: torch_impl.bezier_scatter(c, torch.ones_like(c[:, :1]), -v, v, samples=3, fill="color", impl="fused"),
}


@pytest.mark.parametrize("op", list(NAN_CALLS))
def test_nan_velocity_with_the_checks_skipped_reads_inside_the_image(op, monkeypatch):
    from torch_impl._backend import TorchBackend

    skipped = staticmethod(lambda name, x, *, carry=None: x if carry is None else carry)
    monkeypatch.setattr(TorchBackend, "check_finite", skipped)  # as under torch.compile on a GPU
    color = torch.rand(1, 3, 16, 17, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    velocity = torch.ones(1, 2, 16, 17, dtype=torch.float64)
    velocity[0, 0, 5, 6] = float("nan")  # x only: with both, the wrapped index of NaN rows and columns happened to be 0
    out = NAN_CALLS[op](color, velocity)
    assert out.shape == color.shape
    assert torch.isfinite(out[..., :3, :]).all()  # rows the NaN pixel's taps cannot reach stay finite


# Under torch.compile on CPU the data checks stay in the graph (torch._assert_async): bad data raises
# RuntimeError with the eager message, also with fullgraph=True. aot_eager traces as inductor does
# (dynamo, then AOTAutograd) without inductor's compile.
COMPILED_BAD_CALLS = {
    "gather NaN velocity": (lambda c, v, z: torch_impl.gather_blur(c, v * float("nan"), samples=3, impl="tensor"), "velocity must be finite everywhere"),
    "fused gather NaN velocity": (lambda c, v, z: torch_impl.gather_blur(c, v * float("nan"), samples=3, impl="fused"), "velocity must be finite everywhere"),
    "reconstruct zero depth": (lambda c, v, z: torch_impl.reconstruct(c, v, z * 0.0, samples=3, max_radius=2.0), "depth must be > 0 everywhere"),
    "scatter NaN colour": (lambda c, v, z: torch_impl.bezier_scatter(c * float("nan"), z, -v, v, samples=3), "color must be finite everywhere"),
}


@pytest.mark.parametrize("op", list(COMPILED_BAD_CALLS))
def test_data_checks_raise_under_torch_compile_with_the_eager_message(op):
    call, message = COMPILED_BAD_CALLS[op]
    c, v, z = torch.ones(1, 3, 6, 7), torch.ones(1, 2, 6, 7), torch.ones(1, 1, 6, 7)
    torch._dynamo.reset()
    compiled = torch.compile(call, backend="aot_eager", fullgraph=True)
    with pytest.raises(RuntimeError, match="^" + message):
        compiled(c, v, z)
    with pytest.raises(ValueError, match="^" + message):
        call(c, v, z)
