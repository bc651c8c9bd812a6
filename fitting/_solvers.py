"""Solver loops on one flat parameter vector.

The default, "lbfgs", is one framework-neutral loop: SciPy's L-BFGS-B driven by the framework's loss
and exact gradient (`lbfgs_solve`), so PyTorch and JAX take the same steps up to float rounding and
stop by the same criterion. The others are each framework's own: torch's Adam, and optimistix's
least-squares and quasi-Newton solvers (with optax's Adam) in JAX.

Every loop calls `on_step(loss)` once per step (the loss history and the progress bar) and returns a
`Solved`: the parameters, whether the solver's own stopping criterion was met, and why it stopped.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from typing import NamedTuple

import numpy as np

TORCH_SOLVERS = ("lbfgs", "adam")
JAX_SOLVERS = ("lbfgs", "lm", "dogleg", "bfgs", "adam")
#: Least-squares solvers (they see the residual vector, not only its squared sum).
LEAST_SQUARES = ("lm", "dogleg")


def default_solver(backend: str, model: str) -> str:
    """"lbfgs" for every backend and model: the one loop both frameworks share (`lbfgs_solve`), so
    that they reach the same minimum, and one that stops by a criterion instead of after a fixed
    step count (PyTorch's Adam stopped 0.49 px off an exact blur after its 60 steps)."""
    return "lbfgs"


class Solved(NamedTuple):
    """A solver's answer: y (flat parameters), converged (its stopping criterion was met), message."""

    y: np.ndarray
    converged: bool
    message: str


#: lbfgs_solve's tolerances, on the loss divided by its value at the start and on parameters scaled
#: to pixels of motion: tight enough that both frameworks stop at the same minimum within 1e-3.
LBFGS_FTOL = 1e-13
LBFGS_GTOL = 1e-10
#: lbfgs_solve also stops after LBFGS_STILL_STEPS steps in a row that each move no scaled parameter
#: more than LBFGS_XTOL pixels of motion: the parameters have settled far below the 0.01 px at
#: which PyTorch and JAX must agree, and the loss only creeps on by rounding (a 40 x 40 fit of three
#: crossing layers took 36 more steps and 146 evaluations after its steps fell below 1e-8).
LBFGS_XTOL = 1e-6
LBFGS_STILL_STEPS = 2


def lbfgs_solve(value_and_grad: Callable[[np.ndarray], tuple[float, np.ndarray]], y0: np.ndarray, *, scale: np.ndarray, iterations: int, on_step: Callable[[float], None], fixed: np.ndarray | None = None) -> Solved:
    """SciPy's L-BFGS-B on `value_and_grad(y) -> (loss, dloss/dy)` (NumPy in and out, float64).

    The solver sees x = y * scale (`scale`: the pixels of motion one unit of each parameter makes, so
    that all are steps of comparable size) and the loss divided by its starting value (so the
    tolerances mean the same on any image). converged: SciPy's own criterion (relative reduction of
    the loss below LBFGS_FTOL, or projected gradient below LBFGS_GTOL), or steps that settled
    (LBFGS_XTOL, LBFGS_STILL_STEPS); a line search that can make
    no progress counts as converged only where a step of 0.01 px would change the loss by less than
    1e-4 of its value: flat to far below the 0.1 px a fit aims at.
    """
    from scipy.optimize import minimize

    scale = np.asarray(scale, dtype=np.float64)
    f0, g0 = value_and_grad(np.asarray(y0, dtype=np.float64))
    if not np.isfinite(f0) or not np.all(np.isfinite(g0)):
        return Solved(np.asarray(y0, dtype=np.float64), False, f"the loss or its gradient is not finite at the start (loss {f0})")
    norm = f0 if f0 > 0 else 1.0
    last = {"f": f0, "g": g0 / scale / norm}

    def fun(x):
        f, g = value_and_grad(x / scale)
        last["f"], last["g"] = f, g / scale / norm
        if not np.isfinite(f) or not np.all(np.isfinite(g)):
            return np.inf, np.zeros_like(x)
        return f / norm, g / scale / norm

    x0 = np.asarray(y0, dtype=np.float64) * scale
    settled = {"x": x0.copy(), "still": 0}

    def callback(intermediate_result):
        on_step(float(intermediate_result.fun) * norm)
        x = np.asarray(intermediate_result.x, dtype=np.float64)
        settled["still"] = settled["still"] + 1 if np.max(np.abs(x - settled["x"])) <= LBFGS_XTOL else 0
        settled["x"] = x.copy()
        if settled["still"] >= LBFGS_STILL_STEPS:
            raise StopIteration

    bounds = None if fixed is None else [(x, x) if hold else (None, None) for x, hold in zip(x0, np.asarray(fixed, dtype=bool))]
    result = minimize(fun, x0, jac=True, method="L-BFGS-B", bounds=bounds, callback=callback, options={"maxiter": iterations, "maxcor": 20, "ftol": LBFGS_FTOL, "gtol": LBFGS_GTOL})
    message = str(result.message)
    converged = bool(result.success)
    if settled["still"] >= LBFGS_STILL_STEPS:
        converged, message = True, f"{LBFGS_STILL_STEPS} steps in a row moved no parameter more than {LBFGS_XTOL:g} px"
    if not converged and "ABNORMAL" in message.upper():
        # The line search found no decrease: at a minimum the loss's rounding noise does that too.
        # Converged if a step of a hundredth of a pixel would change the loss by under 1e-4 of it.
        converged = bool(np.max(np.abs(result.jac)) * 0.01 <= 1e-4 * max(float(result.fun), 1e-300))
    if result.nit >= iterations and not result.success:
        message = f"stopped after the most iterations allowed ({iterations}) before its stopping criterion"
    return Solved(np.asarray(result.x, dtype=np.float64) / scale, converged, message)


def torch_adam(be: Any, residuals: Callable, y0: np.ndarray, *, iterations: int, learning_rate: float, on_step: Callable[[float], None]) -> Solved:
    """torch.optim.Adam for `iterations` steps; the best parameters seen. Adam has no stopping
    criterion of its own: converged means the gradient fell to 1e-4 of its starting norm."""
    torch = be.torch
    y = torch.tensor(y0, dtype=be.dtype, requires_grad=True)
    best = (np.inf, y0.copy())
    norms: list[float] = []

    def evaluate() -> Any:
        nonlocal best
        loss = (residuals(y) ** 2).sum()
        value = float(loss.detach())
        if value < best[0]:
            best = (value, y.detach().cpu().numpy().astype(np.float64).copy())
        on_step(value)
        return loss

    optimizer = torch.optim.Adam([y], lr=learning_rate)
    for _ in range(iterations):
        optimizer.zero_grad()
        evaluate().backward()
        norms.append(float(y.grad.norm()))
        optimizer.step()
    with torch.no_grad():
        evaluate()  # the last step's parameters too
    converged = len(norms) > 1 and norms[-1] <= 1e-4 * max(norms[0], 1e-300)
    return Solved(best[1], converged, "gradient at 1e-4 of its start" if converged else f"adam ran its {iterations} steps; it has no stopping criterion (try solver='lbfgs')")


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
) -> Solved:
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
    stopped = False
    for _ in range(iterations):
        y, state, aux, done = step(y, state)
        value = float(aux)
        on_step(value)
        if bool(done):
            stopped = True
            break
    # optimistix evaluates a trial point per step (aux is the loss there); take the accepted iterate.
    final = float(loss_at(y))
    if np.isfinite(final):
        best = (final, np.asarray(y, dtype=np.float64).copy())
    on_step(final)
    message = f"optimistix {solver}: " + ("its tolerances were met" if stopped else f"stopped after the most steps allowed ({iterations}) before its tolerances")
    return Solved(best[1], stopped and np.isfinite(final), message)
