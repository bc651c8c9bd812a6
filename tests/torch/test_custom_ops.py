"""The fused CPU kernels as PyTorch custom operators (`torch_impl._fused`, `torch_impl._fused_scatter`).

`torch.library.opcheck` checks each operator's registration (schema, fake implementation against the
real one, autograd registration, AOT dispatch with dynamic shapes) on small float64 inputs. Under
`torch.compile(fullgraph=True)` each op on its fused default keeps the kernel as one call of the
operator in the forward graph and one of its backward operator in the backward graph (no graph
break, no traced taps: the graphs do not grow with the tap count), and gives eager's output and
gradients. The graphs are captured by AOTAutograd and run without code generation; Inductor's build
of them (tens of seconds each with a cold cache) is measured by scripts/measure_compile_vs_eager.py.
"""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("numba")
from functorch.compile import make_boxed_func  # noqa: E402
from torch._dynamo.backends.common import aot_autograd  # noqa: E402

import torch_impl  # noqa: E402
from torch_impl import _fused, _fused_scatter  # noqa: E402

SHAPE = (1, 2, 6, 7)


def _inputs(dtype=torch.float64, seed=0):
    rng = np.random.default_rng(seed)
    batch, channels, height, width = SHAPE
    color = rng.random(SHAPE)
    velocity = rng.normal(size=(batch, 2, height, width)) * 2.0
    velocity[:, :, :2, :2] = 0.0  # still pixels: the scatter's mask and fill see both kinds
    depth = rng.uniform(1.0, 2.0, size=(batch, 1, height, width))
    weights = rng.random(SHAPE)
    return [torch.tensor(a, dtype=dtype) for a in (color, velocity, depth, weights)]


#: op -> (call on colour, velocity, depth with a tap count, the forward and backward operators).
OPS = {
    "reconstruct": (
        lambda c, v, z, taps: torch_impl.reconstruct(c, v, z, samples=taps, max_radius=3.0),
        torch.ops.diffblur.reconstruct_forward,
        torch.ops.diffblur.reconstruct_backward,
    ),
    "gather_blur": (
        lambda c, v, z, taps: torch_impl.gather_blur(c, v, samples=taps),
        torch.ops.diffblur.gather_forward,
        torch.ops.diffblur.gather_backward,
    ),
    "bezier_scatter": (
        # fill="color": the push-pull fill (tensor ops around the kernel) would double the graphs.
        # composite="layers": one kernel pair ("instants", the default, adds the instant kernels and a tensor composite)
        lambda c, v, z, taps: torch_impl.bezier_scatter(c, z, -v, v, samples=taps, fill="color", composite="layers"),
        torch.ops.diffblur.splat_forward,
        torch.ops.diffblur.splat_backward,
    ),
}


def _forward_arguments(op: str, color, velocity, depth):
    """The forward operator's arguments as the op builds them (the tensors the kernel takes)."""
    if op == "reconstruct":
        from torch_impl import neighbor_max, tile_max

        neighbors = neighbor_max(tile_max(velocity, 3))
        counts = torch.full((SHAPE[0], 2, 3), 5, dtype=torch.int32)
        counts[0, 0, 0] = 0  # a tile that returns the image
        jitter = torch.rand(1, 1, *SHAPE[2:], dtype=color.dtype) - 0.5
        return (color, velocity, depth, neighbors.detach().requires_grad_(), counts, jitter, 3, 0.01, 0.5, True)
    if op == "gather_blur":
        masses = torch.tensor(np.full((6, 5), 0.2), dtype=color.dtype, requires_grad=True)
        return (color, velocity, masses, 5, [3, 5], 0.001, 4)
    path = torch.cat([torch.zeros_like(velocity), velocity, 0.3 * velocity, torch.zeros_like(velocity)], dim=1).detach().requires_grad_()
    masses = torch.full((4,), 0.25, dtype=color.dtype, requires_grad=True)
    extent = torch.tensor(0.05, dtype=color.dtype, requires_grad=True)
    moving = velocity.abs().sum(dim=1) > 0
    return (color, depth, path, masses, extent, moving, False, False)


@pytest.mark.parametrize("op", OPS)
def test_opcheck(op):
    color, velocity, depth, _ = _inputs()
    forward, backward = OPS[op][1:]
    arguments = _forward_arguments(op, *(t.requires_grad_() for t in (color, velocity, depth)))
    torch.library.opcheck(forward, arguments)
    # The backward operator, on the forward's saved tensors and an output gradient (no autograd of
    # its own: the fused backward is first order only).
    plain = [a.detach() if isinstance(a, torch.Tensor) else a for a in arguments]
    if op == "reconstruct":
        out, weight = forward(*plain)
        tensors, settings = plain[:6], plain[6:]
        for needs in ((True, True, True), (False, True, False)):
            torch.library.opcheck(backward, (*tensors, out, weight, torch.ones_like(out), *settings, *needs))
    elif op == "gather_blur":
        out = forward(*plain)
        for needs in ((True, True, True), (False, True, False)):
            torch.library.opcheck(backward, (*plain[:3], torch.ones_like(out), *plain[3:], *needs))
    else:
        sums = forward(*plain)
        torch.library.opcheck(backward, (*plain[:6], torch.ones_like(sums), *plain[6:]))


class _Graphs:
    """A torch.compile backend that keeps AOTAutograd's forward and backward graphs and runs them as
    they are (no code generation)."""

    def __init__(self):
        self.forward, self.backward = [], []
        self.backend = aot_autograd(fw_compiler=self._keep(self.forward), bw_compiler=self._keep(self.backward))

    @staticmethod
    def _keep(graphs):
        def compiler(graph_module, example_inputs):
            graphs.append(graph_module.graph)
            return make_boxed_func(graph_module.forward)

        return compiler


def _calls(graph, operator) -> int:
    return sum(node.op == "call_function" and node.target == operator.default for node in graph.nodes)


def _run(fn, taps, dtype):
    color, velocity, depth, weights = _inputs(dtype)
    leaves = [t.requires_grad_() for t in (color, velocity, depth)]
    out = fn(*leaves, taps)
    grads = torch.autograd.grad((out * weights).sum(), leaves, allow_unused=True)
    return out.detach(), grads


@pytest.mark.parametrize("op", OPS)
def test_compiled_fused_op_is_its_kernel_calls_and_matches_eager(op):
    call, forward, backward = OPS[op]
    sizes = []
    for taps in (3, 9):
        graphs = _Graphs()
        torch._dynamo.reset()
        compiled = torch.compile(call, backend=graphs.backend, fullgraph=True, dynamic=False)
        out, grads = _run(compiled, taps, torch.float64)
        assert len(graphs.forward) == len(graphs.backward) == 1
        (forward_graph,), (backward_graph,) = graphs.forward, graphs.backward
        # bezier_scatter's composite="layers" splats three times (its depths, negated, none).
        kernels = 3 if op == "bezier_scatter" else 1
        assert _calls(forward_graph, forward) == kernels and _calls(backward_graph, backward) == kernels
        sizes.append((len(forward_graph.nodes), len(backward_graph.nodes)))
        eager_out, eager_grads = _run(call, taps, torch.float64)
        torch.testing.assert_close(out, eager_out, rtol=0, atol=0)
        for got, expected in zip(grads, eager_grads):
            if expected is None:  # the gather does not read depth
                assert got is None
            else:
                torch.testing.assert_close(got, expected, rtol=0, atol=0)
    # The taps are inside the kernel: 9 taps make the same graphs as 3.
    assert sizes[0] == sizes[1], sizes
