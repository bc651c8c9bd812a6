"""Solver loops on one flat parameter vector: torch optimizers, and optimistix (with optax) in JAX.

Both loops call `on_step(loss)` once per step (the loss history and the progress bar) and return
the best parameters seen.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

TORCH_SOLVERS = ("adam", "lbfgs")
JAX_SOLVERS = ("lm", "dogleg", "bfgs", "lbfgs", "adam")
#: Least-squares solvers (they see the residual vector, not only its squared sum).
LEAST_SQUARES = ("lm", "dogleg")


def default_solver(backend: str, model: str) -> str:
    """Adam in PyTorch; in JAX the Dogleg trust region for few parameters and L-BFGS for a dense
    field (a least-squares solver's dense QR of a (pixels x 2 pixels) Jacobian is hopeless there).
    Dogleg rather than Levenberg-Marquardt: through the reconstruction filter LM (optimistix 0.1.0)
    wandered off in 12 to 20 steps where Dogleg, BFGS and L-BFGS converge (fitting/measure.py)."""
    if backend == "torch":
        return "adam"
    return "lbfgs" if model == "dense" else "dogleg"


def torch_solve(be: Any, residuals: Callable, y0: np.ndarray, *, solver: str, iterations: int, learning_rate: float, on_step: Callable[[float], None]) -> np.ndarray:
    torch = be.torch
    y = torch.tensor(y0, dtype=be.dtype, requires_grad=True)
    best = (np.inf, y0.copy())

    def evaluate() -> Any:
        nonlocal best
        loss = (residuals(y) ** 2).sum()
        value = float(loss.detach())
        if value < best[0]:
            best = (value, y.detach().cpu().numpy().astype(np.float64).copy())
        on_step(value)
        return loss

    if solver == "adam":
        optimizer = torch.optim.Adam([y], lr=learning_rate)
        for _ in range(iterations):
            optimizer.zero_grad()
            evaluate().backward()
            optimizer.step()
    else:
        optimizer = torch.optim.LBFGS([y], lr=1.0, max_iter=iterations, max_eval=2 * iterations, history_size=10, line_search_fn="strong_wolfe", tolerance_grad=1e-12, tolerance_change=1e-15)

        def closure():
            optimizer.zero_grad()
            loss = evaluate()
            loss.backward()
            return loss

        optimizer.step(closure)
    with torch.no_grad():
        evaluate()  # the last step's parameters too
    return best[1]


def _optimistix_solver(solver: str, learning_rate: float, matrix_free: bool) -> Any:
    import lineax as lx
    import optax
    import optimistix as optx

    rtol, atol = 1e-9, 1e-12
    if solver == "lm":
        # Matrix-free for many parameters: conjugate gradients on the normal equations, which only
        # need Jacobian-vector products and their transposes, instead of a dense QR.
        linear = lx.Normal(lx.CG(rtol=1e-6, atol=1e-9, max_steps=50)) if matrix_free else lx.QR()
        return optx.LevenbergMarquardt(rtol=rtol, atol=atol, linear_solver=linear)
    if solver == "dogleg":
        return optx.Dogleg(rtol=rtol, atol=atol)
    if solver == "bfgs":
        return optx.BFGS(rtol=rtol, atol=atol)
    if solver == "lbfgs":
        return optx.LBFGS(rtol=rtol, atol=atol)
    return optx.OptaxMinimiser(optax.adam(learning_rate), rtol=rtol, atol=atol)


def jax_solve(
    be: Any,
    residuals: Callable,
    y0: np.ndarray,
    *,
    solver: str,
    iterations: int,
    learning_rate: float,
    on_step: Callable[[float], None],
    jac: str = "fwd",
    matrix_free: bool = False,
) -> np.ndarray:
    """optimistix's step-by-step interface (init / step / terminate), one jitted step per call.

    jac: how LM and Dogleg get the Jacobian, "fwd" (forward mode, one JVP per parameter) or "bwd"
    (reverse mode, needed for a function with a custom_vjp)."""
    import equinox as eqx
    import jax

    least_squares = solver in LEAST_SQUARES

    def fn(y, args):
        r = residuals(y)
        loss = (r * r).sum()
        return (r if least_squares else loss), loss

    optim = _optimistix_solver(solver, learning_rate, matrix_free)
    options = {"jac": jac} if least_squares else {}
    tags = frozenset()
    y = be.array(y0)
    f_struct, aux_struct = jax.eval_shape(lambda v: fn(v, None), y)
    state = optim.init(fn, y, None, options, f_struct, aux_struct, tags)

    @eqx.filter_jit
    def step(y, state):
        y, state, aux = optim.step(fn, y, None, options, state, tags)
        done, _ = optim.terminate(fn, y, None, options, state, tags)
        return y, state, aux, done

    @eqx.filter_jit
    def loss_at(y):
        return fn(y, None)[1]

    best = (np.inf, np.asarray(y0, dtype=np.float64).copy())
    for _ in range(iterations):
        y, state, aux, done = step(y, state)
        value = float(aux)
        on_step(value)
        if bool(done):
            break
    # optimistix evaluates a trial point per step (aux is the loss there); take the accepted iterate.
    final = float(loss_at(y))
    if np.isfinite(final):
        best = (final, np.asarray(y, dtype=np.float64).copy())
    on_step(final)
    return best[1]
