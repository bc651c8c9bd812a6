"""The equivalence harness: every op in NumPy, PyTorch and JAX on the same seeded inputs.

For each Case in `cases.CASES`: outputs against the NumPy reference (float64 and float32), PyTorch
against JAX directly (outputs and gradients), gradients against finite differences of the
reference, each framework's own finite-difference check (gradcheck, check_grads), compiled against
eager, and a check that the gradients are useful (nonzero where a change moves the output).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import torch
from jax.test_util import check_grads

import torch_impl
from tests.equivalence.cases import CASES, Case
from tests.tolerances import tolerance

CASES_BY_NAME = {case.name: case for case in CASES}

DTYPES = ("float32", "float64")
FD_STEP = 1e-6

case_ids = [case.name for case in CASES]
#: Cases whose gradients finite differences can check (see Case.on_kinks).
SMOOTH_CASES = [case for case in CASES if not case.on_kinks]
smooth_ids = [case.name for case in SMOOTH_CASES]


def output_tolerance(case: Case, dtype: str) -> tuple[float, float]:
    return tolerance(dtype, "output")


def torch_inputs(case: Case, inputs: dict, dtype: str) -> dict[str, torch.Tensor]:
    out = {}
    for name, value in inputs.items():
        tensor = torch.tensor(value, dtype=getattr(torch, dtype))
        out[name] = tensor.requires_grad_(name in case.differentiable)
    return out


def jax_inputs(inputs: dict, dtype: str) -> dict[str, jax.Array]:
    return {name: jnp.asarray(value, dtype=dtype) for name, value in inputs.items()}


def torch_vjp(case: Case, inputs: dict, cotangent: np.ndarray, dtype: str) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    args = torch_inputs(case, inputs, dtype)
    out = case.torch_op(**args)
    grads = torch.autograd.grad((out * torch.tensor(cotangent, dtype=out.dtype)).sum(), [args[n] for n in case.differentiable])
    return out.detach().numpy(), {n: g.numpy() for n, g in zip(case.differentiable, grads)}


def jax_vjp(case: Case, inputs: dict, cotangent: np.ndarray, dtype: str, *, jit: bool = False) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    args = jax_inputs(inputs, dtype)
    fixed = {n: v for n, v in args.items() if n not in case.differentiable}

    def run(*diff_values):
        return case.jax_op(**fixed, **dict(zip(case.differentiable, diff_values)))

    def output_and_grads(*diff_values):
        out, pullback = jax.vjp(run, *diff_values)
        return out, pullback(jnp.asarray(cotangent, dtype=out.dtype))

    fn = jax.jit(output_and_grads) if jit else output_and_grads
    out, grads = fn(*[args[n] for n in case.differentiable])
    return np.asarray(out), {n: np.asarray(g) for n, g in zip(case.differentiable, grads)}


def random_cotangent(case: Case, inputs: dict) -> np.ndarray:
    shape = case.reference(**inputs).shape
    return np.random.default_rng(7).normal(size=shape)


def assert_close(actual, expected, tolerance, what):
    atol, rtol = tolerance
    np.testing.assert_allclose(actual, expected, atol=atol, rtol=rtol, err_msg=what)


# ----- outputs ---------------------------------------------------------------------------------


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("backend", ["torch", "jax"])
@pytest.mark.parametrize("case", CASES, ids=case_ids)
def test_output_matches_numpy_reference(case, backend, dtype):
    inputs = case.inputs()
    expected = case.reference(**inputs)
    if backend == "torch":
        actual = case.torch_op(**torch_inputs(case, inputs, dtype)).detach().numpy()
    else:
        actual = np.asarray(case.jax_op(**jax_inputs(inputs, dtype)))
    assert actual.dtype == np.dtype(dtype), "the op must keep the input dtype"
    assert actual.shape == expected.shape
    assert_close(actual, expected, output_tolerance(case, dtype), f"{case.name} {backend} {dtype}")


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("case", CASES, ids=case_ids)
def test_torch_matches_jax(case, dtype):
    """Outputs and gradients, PyTorch against JAX directly, with the same cotangent."""
    inputs = case.inputs()
    cotangent = random_cotangent(case, inputs)
    torch_out, torch_grads = torch_vjp(case, inputs, cotangent, dtype)
    jax_out, jax_grads = jax_vjp(case, inputs, cotangent, dtype)
    assert_close(torch_out, jax_out, output_tolerance(case, dtype), f"{case.name} output")
    for name in case.differentiable:
        assert torch_grads[name].shape == jax_grads[name].shape == np.shape(inputs[name])
        assert_close(torch_grads[name], jax_grads[name], tolerance(dtype, "gradient"), f"{case.name} d/d{name}")


# ----- gradients ---------------------------------------------------------------------------------


def reference_directional_derivative(case: Case, inputs: dict, name: str, direction: np.ndarray, cotangent: np.ndarray) -> float:
    plus = dict(inputs, **{name: inputs[name] + FD_STEP * direction})
    minus = dict(inputs, **{name: inputs[name] - FD_STEP * direction})
    return float(np.sum(cotangent * (case.reference(**plus) - case.reference(**minus))) / (2 * FD_STEP))


@pytest.mark.parametrize("backend", ["torch", "jax"])
@pytest.mark.parametrize("case", SMOOTH_CASES, ids=smooth_ids)
def test_gradient_matches_reference_finite_differences(case, backend):
    """float64 vector-Jacobian products against central differences of the NumPy reference, along
    random directions; the directional derivatives must also be clearly nonzero (useful)."""
    inputs = case.inputs()
    cotangent = random_cotangent(case, inputs)
    vjp = torch_vjp if backend == "torch" else jax_vjp
    _, grads = vjp(case, inputs, cotangent, "float64")
    rng = np.random.default_rng(3)
    for name in case.differentiable:
        assert np.all(np.isfinite(grads[name]))
        for _ in range(3):
            direction = rng.normal(size=np.shape(inputs[name]))
            expected = reference_directional_derivative(case, inputs, name, direction, cotangent)
            actual = float(np.sum(grads[name] * direction))
            assert abs(expected) > 1e-6, f"{case.name}: d/d{name} should not vanish on these inputs"
            np.testing.assert_allclose(actual, expected, rtol=1e-6, atol=1e-8, err_msg=f"{case.name} d/d{name}")


@pytest.mark.parametrize("backend", ["torch", "jax"])
@pytest.mark.parametrize("case", [c for c in CASES if c.elementwise], ids=[c.name for c in CASES if c.elementwise])
def test_gradient_nonzero_exactly_where_output_moves(case, backend):
    """Per element: where a small change of the input changes the output, the gradient is that
    change (so nonzero); where it does not (a clamp), the gradient is 0."""
    inputs = case.inputs()
    ones = np.ones_like(case.reference(**inputs))
    vjp = torch_vjp if backend == "torch" else jax_vjp
    _, grads = vjp(case, inputs, ones, "float64")
    for name in case.elementwise:
        plus = dict(inputs, **{name: inputs[name] + FD_STEP})
        minus = dict(inputs, **{name: inputs[name] - FD_STEP})
        per_element = (case.reference(**plus) - case.reference(**minus)) / (2 * FD_STEP)
        moves = np.abs(per_element) > 1e-6
        assert moves.any() and not moves.all(), "the inputs should cover both moving and clamped elements"
        assert np.all(grads[name][moves] != 0)
        np.testing.assert_allclose(grads[name], per_element, rtol=1e-5, atol=1e-7)


#: Per op with a fused kernel, the case whose full Jacobian torch's gradcheck compares element by
#: element; the op's other cases compare random projections of it.
FULL_JACOBIAN = ("reconstruct_bilinear", "gather_blur_bilinear", "bezier_scatter_linear_paper")


@pytest.mark.parametrize("case", SMOOTH_CASES, ids=smooth_ids)
def test_torch_gradcheck(case):
    inputs = case.inputs()
    args = torch_inputs(case, inputs, "float64")
    names = list(case.differentiable)

    def fn(*diff_values):
        return case.torch_op(**dict(args, **dict(zip(names, diff_values))))

    # The full numerical Jacobian costs two forward passes per input element: 10-48 s for each case
    # of reconstruct, the gather and the scatter. One case per op keeps it; the others check random
    # projections of the Jacobian, as JAX's check_grads does, which can miss an error confined to a
    # single element.
    fast = case.name.startswith(FUSED_OPS) and case.name not in FULL_JACOBIAN
    assert torch.autograd.gradcheck(
        fn, [args[n] for n in names], eps=1e-6, atol=1e-6, rtol=1e-5, fast_mode=fast
    )


#: Ops whose default CPU path is a fused kernel (diffblur.kernels), by case-name prefix.
FUSED_OPS = ("reconstruct", "gather_blur", "bezier_scatter")


@pytest.mark.parametrize("case", SMOOTH_CASES, ids=smooth_ids)
def test_jax_check_grads(case):
    args = jax_inputs(case.inputs(), "float64")
    names = list(case.differentiable)
    fixed = {n: v for n, v in args.items() if n not in names}

    def fn(*diff_values):
        return case.jax_op(**fixed, **dict(zip(names, diff_values)))

    values = [args[n] for n in names]
    if not case.name.startswith(FUSED_OPS):
        check_grads(fn, values, order=1, modes=("fwd", "rev"), eps=1e-6, atol=1e-6, rtol=1e-5)
        return
    # These ops' default CPU path is a fused kernel with a reverse-mode rule only (a custom_vjp),
    # checked against finite differences of the reference by
    # test_gradient_matches_reference_finite_differences. Here: their tensor ops (the GPU path and
    # forward mode's), compiled. JAX derives reverse mode by transposing the forward mode's
    # linearisation, so one mode checks both; one case per op checks the two separately.
    def tensor_ops(*diff_values):
        return case.jax_op(**fixed, **dict(zip(names, diff_values)), impl="tensor")

    modes = ("fwd", "rev") if case.name in FULL_JACOBIAN else ("rev",)
    check_grads(jax.jit(tensor_ops), values, order=1, modes=modes, eps=1e-6, atol=1e-6, rtol=1e-5)


# ----- compiled against eager ----------------------------------------------------------------------


def _compiled_against_eager(cases: list[Case], backend: str) -> None:
    """Run `cases` in one function (one compilation), forward and backward, compiled and eager.
    The ops with a fused CPU kernel run their tensor ops (impl="tensor"): what torch.compile traces on
    other devices. Their fused default, one custom operator in the graph, is checked in
    tests/torch/test_custom_ops.py."""
    prepared = {case.name: (case, case.inputs()) for case in cases}

    def run_all(tensors):
        return {name: case.torch_op(**tensors[name], **({"impl": "tensor"} if name.startswith(FUSED_OPS) else {})) for name, (case, _) in prepared.items()}

    torch._dynamo.reset()
    compiled = torch.compile(run_all, backend=backend, fullgraph=True, dynamic=False)
    results = {}
    for label, fn in (("eager", run_all), ("compiled", compiled)):
        tensors = {name: torch_inputs(case, inputs, "float32") for name, (case, inputs) in prepared.items()}
        outs = fn(tensors)
        sum((out * out).sum() for out in outs.values()).backward()
        results[label] = {
            name: (outs[name].detach().numpy(), {n: tensors[name][n].grad.numpy() for n in case.differentiable})
            for name, (case, _) in prepared.items()
        }
    for name, (case, _) in prepared.items():
        compiled_out, compiled_grads = results["compiled"][name]
        eager_out, eager_grads = results["eager"][name]
        assert_close(compiled_out, eager_out, (1e-6, 1e-5), f"{name} compiled output")
        for n in case.differentiable:
            assert_close(compiled_grads[n], eager_grads[n], (1e-5, 1e-4), f"{name} compiled d/d{n}")


PRIMITIVE_CASES = ["soft_depth_compare", "cone", "cylinder", "safe_length", "velocity_from_motion", "tile_max", "neighbor_max"]


def _one_case_per_op() -> list[Case]:
    """One case per op and sampling mode: tracing is slow, and the other options change no
    control flow that the eager tests do not already cover."""
    names = PRIMITIVE_CASES + ["gather_blur_bilinear", "gather_blur_nearest", "reconstruct_bilinear", "reconstruct_nearest"]
    scatter = [case for case in CASES if case.name.startswith("bezier")][:1]
    return [CASES_BY_NAME[name] for name in names] + scatter


def test_torch_compile_captures_every_op_whole():
    """One case per op and sampling mode, traced by Dynamo into one graph (fullgraph) with
    AOTAutograd's backward, run without code generation (backend "aot_eager"): no graph breaks,
    same values. The image ops on their tensor ops (see `_compiled_against_eager`)."""
    _compiled_against_eager(_one_case_per_op(), "aot_eager")


def test_torch_compile_inductor_matches_eager():
    """The generated kernels (Inductor, the default backend) for the primitives and the gather's
    tensor ops. Inductor's C++ build of even a 3-tap reconstruct on its tensor ops takes about 170 s
    on two cores with a cold cache (as in CI), so the filter's compiled-against-eager check under Inductor is in
    `scripts/measure_compile_vs_eager.py` (BENCHMARKS.md); here it runs under aot_eager
    (`test_torch_compile_captures_every_op_whole`)."""
    primitives = [CASES_BY_NAME[name] for name in PRIMITIVE_CASES]
    _compiled_against_eager([*primitives, CASES_BY_NAME["gather_blur_bilinear"]], "inductor")


@pytest.mark.parametrize("case", CASES, ids=case_ids)
def test_jax_jit_matches_eager(case):
    inputs = case.inputs()
    cotangent = random_cotangent(case, inputs)
    eager_out, eager_grads = jax_vjp(case, inputs, cotangent, "float32")
    jit_out, jit_grads = jax_vjp(case, inputs, cotangent, "float32", jit=True)
    # XLA fuses multiply-adds under jit, so float32 results move by a few ulps.
    assert_close(jit_out, eager_out, (1e-6, 1e-5), "jit output")
    for name in case.differentiable:
        assert_close(jit_grads[name], eager_grads[name], tolerance("float32", "gradient"), f"jit d/d{name}")


# ----- the jitter ---------------------------------------------------------------------------------


@pytest.mark.parametrize("shape", [(1, 1), (7, 13), (720, 1280)])
def test_interleaved_gradient_noise_identical_in_all_three(shape):
    import jax_impl
    import torch_impl
    from diffblur import reference

    expected = reference.interleaved_gradient_noise(*shape)
    np.testing.assert_array_equal(torch_impl.interleaved_gradient_noise(*shape, dtype=torch.float64).numpy(), expected)
    np.testing.assert_array_equal(np.asarray(jax_impl.interleaved_gradient_noise(*shape, dtype=jnp.float64)), expected)
    np.testing.assert_array_equal(torch_impl.interleaved_gradient_noise(*shape, dtype=torch.float32).numpy(), expected.astype(np.float32))
    np.testing.assert_array_equal(np.asarray(jax_impl.interleaved_gradient_noise(*shape, dtype=jnp.float32)), expected.astype(np.float32))
    assert expected.min() >= 0 and expected.max() < 1
