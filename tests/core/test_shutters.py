"""Shutter windows: normalisation, antiderivatives, overlap sums, backends and gradients."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.backends import INSTALLED

if INSTALLED["torch"]:
    import torch
if INSTALLED["jax"]:
    import jax
    import jax.numpy as jnp

#: The windows in the frameworks: the NumPy tests above them run in any install.
needs_torch = pytest.mark.skipif(not INSTALLED["torch"], reason="torch is not installed (pip install 'diffblur[torch]')")
needs_both = pytest.mark.skipif(not all(INSTALLED.values()), reason="compares torch and jax: needs both installed")

from diffblur import shutters
from diffblur.shutters import (
    SHUTTERS,
    Box,
    Gaussian,
    LinearRamp,
    RaisedCosine,
    Tent,
    Trapezoid,
    Tukey,
    get_shutter,
    instants,
    overlap_sum,
)

# Windows with non-default parameters too, including the ends of each family's range.
WINDOWS = [
    Box(),
    Tent(),
    Trapezoid(0.0),
    Trapezoid(0.3),
    Trapezoid(1.0),
    RaisedCosine(),
    Gaussian(0.5),
    Gaussian(0.15),
    Gaussian(3.0),
    Tukey(0.0),
    Tukey(0.4),
    Tukey(1.0),
    LinearRamp(0.0),
    LinearRamp(0.7),
    LinearRamp(-1.0),
]
IDS = [repr(w) for w in WINDOWS]


def _simpson(values: np.ndarray, t: np.ndarray) -> float:
    """Composite Simpson rule on an odd number of equally spaced points."""
    h = t[1] - t[0]
    return float(h / 3 * (values[0] + values[-1] + 4 * values[1:-1:2].sum() + 2 * values[2:-1:2].sum()))


@pytest.mark.parametrize("window", WINDOWS, ids=IDS)
def test_window_integrates_to_one_numerically(window):
    # Interior points only: the box family's jump at |t| = 1 carries no mass.
    t = np.linspace(-1.0, 1.0, 40001)
    values = window.weight(t)
    values[[0, -1]] = window.weight(np.array([-1 + 1e-12, 1 - 1e-12]))
    assert _simpson(values, t) == pytest.approx(1.0, abs=2e-6)
    assert np.all(values >= 0)


@pytest.mark.parametrize("window", WINDOWS, ids=IDS)
def test_window_is_zero_outside_the_exposure(window):
    t = np.array([-3.0, -1.0001, 1.0001, 2.5])
    np.testing.assert_array_equal(window.weight(t), 0.0)


@pytest.mark.parametrize("window", WINDOWS, ids=IDS)
def test_antiderivative_ends_and_derivative(window):
    ends = window.antiderivative(np.array([-5.0, -1.0, 1.0, 5.0]))
    np.testing.assert_array_equal(ends, [0.0, 0.0, 1.0, 1.0])
    # W' = w away from the kinks (t = 0, the edges of ramps and tapers).
    t = np.array([-0.93, -0.61, -0.37, -0.12, 0.08, 0.29, 0.52, 0.77, 0.96])
    h = 1e-6
    derivative = (window.antiderivative(t + h) - window.antiderivative(t - h)) / (2 * h)
    np.testing.assert_allclose(derivative, window.weight(t), rtol=1e-6, atol=1e-7)
    # Monotone: W is the integral of a nonnegative function.
    assert np.all(np.diff(window.antiderivative(np.linspace(-1, 1, 1001))) >= -1e-15)


def test_family_ends_match_the_named_windows():
    t = np.linspace(-0.999, 0.999, 501)
    np.testing.assert_allclose(Trapezoid(0.0).weight(t), Box().weight(t), rtol=0, atol=1e-15)
    np.testing.assert_allclose(Trapezoid(1.0).weight(t), Tent().weight(t), rtol=0, atol=1e-15)
    np.testing.assert_allclose(Tukey(0.0).weight(t), Box().weight(t), rtol=0, atol=1e-15)
    np.testing.assert_allclose(Tukey(1.0).weight(t), RaisedCosine().weight(t), rtol=0, atol=1e-15)
    np.testing.assert_allclose(LinearRamp(0.0).weight(t), Box().weight(t), rtol=0, atol=1e-15)
    # A very wide gaussian is nearly flat, a box.
    np.testing.assert_allclose(Gaussian(200.0).weight(t), 0.5, atol=1e-5)


def test_hand_computed_values():
    assert Box().weight(0.3) == 0.5
    assert Tent().weight(0.25) == pytest.approx(0.75)
    # Trapezoid(0.5): height 1 / 1.5, half way down the ramp at |t| = 0.75.
    assert Trapezoid(0.5).weight(0.2) == pytest.approx(2 / 3)
    assert Trapezoid(0.5).weight(-0.75) == pytest.approx(1 / 3)
    assert RaisedCosine().weight(0.5) == pytest.approx(0.5)
    sigma = 0.5
    norm = sigma * math.sqrt(2 * math.pi) * math.erf(1 / (sigma * math.sqrt(2)))
    assert Gaussian(sigma).weight(0.4) == pytest.approx(math.exp(-0.32) / norm, rel=1e-13)
    assert LinearRamp(0.5).weight(1.0) == pytest.approx(0.75)
    assert LinearRamp(0.5).weight(-1.0) == pytest.approx(0.25)
    assert Tukey(0.5).weight(0.75) == pytest.approx(0.5 / 1.5)


def test_raised_cosine_is_seed_004_formula():
    # Seed 004: s(t) = (1 - cos((t - A) 2 pi / (B - A))) / (B - A) on A < t < B, with
    # A = min F - |F| / 2 and B = max F + |F| / 2. Frame F = [-1/2, 1/2] (|F| = 1) maps to [-1, 1].
    frame_lo, frame_hi = -0.5, 0.5
    a = frame_lo - (frame_hi - frame_lo) / 2
    b = frame_hi + (frame_hi - frame_lo) / 2
    t = np.linspace(-0.99, 0.99, 199)
    seed = (1 - np.cos((t - a) * 2 * np.pi / (b - a))) / (b - a)
    np.testing.assert_allclose(RaisedCosine().weight(t), seed, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize(
    "window",
    [Box(), Tent(), Trapezoid(0.3), Trapezoid(0.8), RaisedCosine(), Tukey(0.4), Tukey(1.0)],
    ids=repr,
)
def test_successive_frames_overlap_and_sum_to_one(window):
    # Grid includes the window edges (multiples of the period and +-1) where a wrong value would show.
    period = window.overlap_period
    t = np.concatenate([np.linspace(-4.0, 4.0, 3201), period * np.arange(-3, 4) + 1.0])
    np.testing.assert_allclose(overlap_sum(window, t), 1.0, rtol=0, atol=1e-12)
    # Written out for the raised cosine of seed 004: frames of period P = 1 in normalised time.
    if isinstance(window, RaisedCosine):
        total = sum(window.weight(t - k) for k in range(-6, 7))
        np.testing.assert_allclose(total, 1.0, atol=1e-12)


def test_overlap_sum_detects_a_wrong_period_and_windows_without_one():
    # The same windows with a period that does not tile are visibly not flat.
    assert np.ptp(overlap_sum(RaisedCosine(), np.linspace(-2, 2, 801), period=1.3)) > 0.05
    assert np.ptp(overlap_sum(Trapezoid(0.3), np.linspace(-2, 2, 801), period=1.5)) > 0.05
    with pytest.raises(ValueError, match="gaussian.*no overlap period"):
        overlap_sum("gaussian", np.zeros(3))
    assert np.ptp(overlap_sum("gaussian", np.linspace(-2, 2, 801), period=1.0)) > 0.01
    with pytest.raises(ValueError, match="period must be > 0, got -1"):
        overlap_sum("box", np.zeros(3), period=-1.0)


@pytest.mark.parametrize("name", SHUTTERS)
def test_instants_weights(name):
    times, weights = instants(name, 64)
    assert times.shape == weights.shape == (64,)
    assert np.all(np.diff(times) > 0) and times[0] > -1 and times[-1] < 1
    assert weights.sum() == pytest.approx(1.0, abs=1e-15)
    assert np.all(weights >= 0)
    # The weighted instants integrate a smooth function like the window does.
    window = get_shutter(name)
    t = np.linspace(-1, 1, 40001)
    exact = _simpson(window.weight(t) * np.cos(2 * t + 0.3), t)
    assert np.sum(weights * np.cos(2 * times + 0.3)) == pytest.approx(exact, abs=1e-3)


def test_single_instant_is_the_sharp_frame():
    times, weights = instants("gaussian", 1)
    assert times.tolist() == [0.0] and weights.tolist() == [1.0]


def test_get_shutter_names_and_objects():
    for name in SHUTTERS:
        assert get_shutter(name).name == name
    window = Tukey(0.25)
    assert get_shutter(window) is window
    assert set(SHUTTERS) >= {"box", "tent", "trapezoid", "raised_cosine", "gaussian", "tukey", "linear_ramp"}


def test_bad_arguments():
    with pytest.raises(ValueError, match="shutter must be one of 'box', 'tent'.*got 'hann'"):
        get_shutter("hann")
    with pytest.raises(TypeError, match="shutter must be a name"):
        get_shutter(3)
    with pytest.raises(ValueError, match=r"ramp must be in \[0.0, 1.0\], got 1.5"):
        Trapezoid(1.5)
    with pytest.raises(ValueError, match=r"taper must be in \[0.0, 1.0\], got -0.1"):
        Tukey(-0.1)
    with pytest.raises(ValueError, match=r"slope must be in \[-1.0, 1.0\], got 2"):
        LinearRamp(2)
    with pytest.raises(ValueError, match="sigma must be > 0, got 0"):
        Gaussian(0.0)
    with pytest.raises(TypeError, match="taper must be a real number"):
        Tukey("wide")
    with pytest.raises(ValueError, match="count must be an integer >= 1, got 0"):
        instants("box", 0)


# --- backends -------------------------------------------------------------------------------------

T_GRID = np.concatenate([np.linspace(-1.3, 1.3, 131), [-1.0, 0.0, 1.0]])


@pytest.mark.parametrize("window", WINDOWS, ids=IDS)
@needs_both
def test_weight_in_torch_and_jax_matches_numpy(window):
    expected = window.weight(T_GRID)
    got_torch = window.weight(torch.tensor(T_GRID, dtype=torch.float64), torch)
    got_jax = window.weight(jnp.asarray(T_GRID, dtype=jnp.float64), jnp)
    assert isinstance(got_torch, torch.Tensor) and got_torch.dtype == torch.float64
    np.testing.assert_allclose(got_torch.numpy(), expected, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(np.asarray(got_jax), expected, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(
        window.antiderivative(torch.tensor(T_GRID, dtype=torch.float64), torch).numpy(),
        window.antiderivative(T_GRID),
        rtol=1e-13,
        atol=1e-15,
    )


FAMILIES = [
    (Trapezoid, "ramp", 0.4),
    (Tukey, "taper", 0.4),
    (Gaussian, "sigma", 0.35),
    (LinearRamp, "slope", 0.3),
]


@pytest.mark.parametrize("cls,field,value", FAMILIES, ids=[f[0].__name__ for f in FAMILIES])
@needs_torch
def test_torch_gradient_wrt_shape_parameter_matches_finite_difference(cls, field, value):
    # Off the kinks (|t| = 1 - ramp, 0), where one-sided derivatives differ; the second moment of the
    # window depends on its shape (the first moment on the slope of the asymmetric one).
    t = torch.tensor(np.linspace(-0.97, 0.97, 40), dtype=torch.float64)
    weights = t + 2 * t**2
    param = torch.tensor(value, dtype=torch.float64, requires_grad=True)
    loss = (cls(**{field: param}).weight(t, torch) * weights).sum()
    (grad,) = torch.autograd.grad(loss, param)
    h = 1e-6
    tn, wn = t.numpy(), weights.numpy()
    fd = (
        (cls(**{field: value + h}).weight(tn) * wn).sum() - (cls(**{field: value - h}).weight(tn) * wn).sum()
    ) / (2 * h)
    assert abs(float(grad)) > 1e-3  # nonzero: the shape matters for this loss
    assert float(grad) == pytest.approx(fd, rel=1e-6)
    # The same through the antiderivative (accumulation weights depend on it).
    loss_w = cls(**{field: param}).antiderivative(t, torch).sum()
    (grad_w,) = torch.autograd.grad(loss_w, param)
    fd_w = (cls(**{field: value + h}).antiderivative(tn).sum() - cls(**{field: value - h}).antiderivative(tn).sum()) / (
        2 * h
    )
    assert float(grad_w) == pytest.approx(fd_w, rel=1e-6, abs=1e-9)


@pytest.mark.parametrize("cls,field,value", FAMILIES, ids=[f[0].__name__ for f in FAMILIES])
@needs_both
def test_jax_gradient_wrt_shape_parameter_matches_torch(cls, field, value):
    t_np = np.linspace(-0.97, 0.97, 40)

    def loss_jax(p):
        return jnp.sum(cls(**{field: p}).weight(jnp.asarray(t_np), jnp) ** 2)

    grad_jax = float(jax.grad(loss_jax)(jnp.asarray(value, dtype=jnp.float64)))
    param = torch.tensor(value, dtype=torch.float64, requires_grad=True)
    (grad_torch,) = torch.autograd.grad((cls(**{field: param}).weight(torch.tensor(t_np), torch) ** 2).sum(), param)
    assert abs(grad_jax) > 1e-3
    assert grad_jax == pytest.approx(float(grad_torch), rel=1e-10)


@pytest.mark.parametrize("cls,field", [(Trapezoid, "ramp"), (Tukey, "taper")])
@needs_both
def test_gradient_is_finite_at_the_box_end_of_the_family(cls, field):
    # At ramp/taper 0 the edge branch divides by zero; `where` must not turn that into a NaN gradient.
    t = torch.tensor(np.linspace(-1.2, 1.2, 49), dtype=torch.float64)
    param = torch.tensor(0.0, dtype=torch.float64, requires_grad=True)
    (grad,) = torch.autograd.grad(cls(**{field: param}).weight(t, torch).sum(), param)
    assert torch.isfinite(grad)
    grad_jax = jax.grad(lambda p: jnp.sum(cls(**{field: p}).weight(jnp.asarray(t.numpy()), jnp)))(
        jnp.asarray(0.0, dtype=jnp.float64)
    )
    assert np.isfinite(float(grad_jax))


@needs_torch
def test_erf_series_matches_math_erf():
    x = np.concatenate([np.linspace(0, 7, 71), [1e-8, 5.999, 6.0, 30.0]])
    got = shutters._erf_series(torch.tensor(x, dtype=torch.float64), torch).numpy()
    np.testing.assert_allclose(got, [math.erf(v) for v in x], rtol=2e-15, atol=1e-16)


@needs_both
def test_erf_uses_each_frameworks_own_and_agrees_with_math_erf():
    """Torch tensors and JAX arrays take the framework's erf (one op, with its derivative
    2/sqrt(pi) exp(-x^2)); the values match math.erf on both signs. JAX's is registered by
    `jax_impl` (the core imports no framework)."""
    import jax_impl  # noqa: F401  (registers jax.scipy.special.erf with diffblur.shutters)

    x = np.concatenate([np.linspace(-7, 7, 57), [1e-8, -1e-8]])
    expected = [math.erf(v) for v in x]
    xt = torch.tensor(x, dtype=torch.float64, requires_grad=True)
    got = shutters._erf(xt, torch)
    assert got.grad_fn is not None and "Erf" in type(got.grad_fn).__name__
    np.testing.assert_allclose(got.detach().numpy(), expected, rtol=1e-15, atol=1e-16)
    (grad,) = torch.autograd.grad(got.sum(), xt)
    np.testing.assert_allclose(grad.numpy(), 2 / math.sqrt(math.pi) * np.exp(-x * x), rtol=1e-14)
    jaxpr = str(jax.make_jaxpr(lambda v: shutters._erf(v, jnp))(jnp.asarray(x)))
    assert "erf" in jaxpr and jaxpr.count("mul") < 10, jaxpr
    np.testing.assert_allclose(np.asarray(shutters._erf(jnp.asarray(x), jnp)), expected, rtol=1e-15, atol=1e-16)
