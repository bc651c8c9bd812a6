"""Shutter windows w(t) on the normalised exposure t in [-1, 1].

Every window integrates to 1 over [-1, 1] and is 0 outside it. Each has

- ``weight(t, xp=numpy)``: w(t), elementwise. `t` and the window's parameters may be NumPy, PyTorch
  or JAX arrays (pass the matching namespace as `xp`: ``numpy``, ``torch`` or ``jax.numpy``); only
  operations the three share with the same meaning are used (``where``, ``abs``, ``cos``, ``sin``,
  ``exp``, ``sqrt``, arithmetic, comparisons), so a shape parameter held as a tensor gets a gradient.
- ``antiderivative(t, xp=numpy)``: W(t) = integral of w from -1 to t, with W(-1) = 0 and W(1) = 1
  (t is clamped to [-1, 1] first).
- ``overlap_period``: see "Overlapping frames" below; None where no period makes the shifts sum to a
  constant.

Windows are frozen dataclasses; `get_shutter` resolves a name or returns a window unchanged.

Overlapping frames (seed 004). Seed 004 asks that the shutter functions of successive frames overlap
and sum to one. In normalised exposure units the window of frame k is w(t - k P), where P is the frame
period measured in normalised exposure time (the exposure [-1, 1] lasts 2, so P = 2 means the frames
abut, P = 1 means each exposure spans two frame periods and overlaps half of each neighbour). A window
tiles with period P when sum_k w(t - k P) = 1 / P for every t; equivalently, measuring time in frame
periods (u = t / P), the rescaled windows P w(P u) each integrate to 1 and sum to exactly 1, which is
seed 004's condition. `overlap_sum(window, t)` computes P * sum_k w(t - k P) (which is 1 for a window
that tiles). The periods are:

| window | overlap_period P |
|---|---|
| box | 2 (frames abut, no overlap) |
| tent | 1 |
| trapezoid(ramp=f) | 2 - f (successive ramps overlap exactly) |
| raised_cosine | 1 (seed 004's A = min F - abs(F)/2, B = max F + abs(F)/2: the window spans two frames) |
| tukey(taper=a) | 2 - a |
| gaussian, linear_ramp | None (no period gives an exact partition of unity) |
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from diffblur import checks

__all__ = [
    "SHUTTERS",
    "Box",
    "Gaussian",
    "LinearRamp",
    "RaisedCosine",
    "ShutterWindow",
    "Tent",
    "Trapezoid",
    "Tukey",
    "get_shutter",
    "instants",
    "overlap_sum",
    "register_erf",
]

# erf(x) for x >= ERF_SATURATION is 1 to within 2e-17 (erfc(6) = 2.2e-17): the series below stops
# there, which keeps its terms (which peak near exp(x**2)) far from overflow even in float32.
_ERF_SATURATION = 6.0
_ERF_TERMS = 160


def _erf_series(x: Any, xp: Any) -> Any:
    """erf(x) for x >= 0 with only arithmetic and exp, so every backend can differentiate it.

    erf(x) = 2/sqrt(pi) exp(-x^2) sum_n 2^n x^(2n+1) / (1 * 3 * ... * (2n+1)): all terms positive, no
    cancellation. Relative error ~1e-15 in float64 on [0, 6]; 1 beyond (error < 3e-17).
    """
    inside = x < _ERF_SATURATION
    xs = xp.where(inside, x, 0.0 * x)
    term = xs
    total = xs
    x2 = xs * xs
    for n in range(1, _ERF_TERMS):
        term = term * (2.0 * x2 / (2 * n + 1))
        total = total + term
    value = (2.0 / math.sqrt(math.pi)) * xp.exp(-x2) * total
    return xp.where(inside, value, 0.0 * x + 1.0)


#: A framework's own erf, by the name of its array namespace (`xp.__name__`), for namespaces that do
#: not carry one: the backends register theirs when imported (`jax_impl` registers
#: jax.scipy.special.erf for "jax.numpy"), so that this module imports no framework.
_ERF_BY_NAMESPACE: dict[str, Any] = {}


def register_erf(namespace: str, erf: Any) -> None:
    """Use `erf` (elementwise, differentiable) for arrays of the namespace named `namespace`
    (e.g. "jax.numpy") in the Gaussian window, instead of the series."""
    _ERF_BY_NAMESPACE[namespace] = erf


def _erf(x: Any, xp: Any) -> Any:
    """erf for any backend: math.erf for Python numbers, SciPy's for NumPy arrays, the framework's own
    for torch tensors (torch.special.erf, reached through `xp`) and for a namespace whose backend
    registered one (`register_erf`: jax.scipy.special.erf for JAX arrays once `jax_impl` is
    imported), else the series.

    The frameworks' erf are single differentiable ops: the series is 160 of them, which compilers
    (torch.compile, XLA) unroll at great cost when a Gaussian's sigma is fitted."""
    if isinstance(x, numbers.Real):
        return math.erf(float(x))
    if xp is np:
        from scipy.special import erf  # scipy ships with scikit-image, a core dependency

        return erf(x)
    name = getattr(xp, "__name__", "")
    if name == "torch" and isinstance(x, xp.Tensor):
        return xp.special.erf(x)
    if name in _ERF_BY_NAMESPACE:
        return _ERF_BY_NAMESPACE[name](x)
    ax = xp.abs(x)
    value = _erf_series(ax, xp)
    return xp.where(x < 0, -value, value)


def _as_t(t: Any, xp: Any) -> Any:
    if xp is np:
        t = np.asarray(t)
        if not np.issubdtype(t.dtype, np.floating):
            t = t.astype(np.float64)
    return t


def _zeros(t: Any) -> Any:
    return 0.0 * t


def _clamp_t(t: Any, xp: Any) -> Any:
    """t clamped to [-1, 1], spelled with `where` (the backends' clips differ at ties)."""
    return xp.where(t < -1.0, _zeros(t) - 1.0, xp.where(t > 1.0, _zeros(t) + 1.0, t))


def _inside(t: Any, xp: Any) -> Any:
    return xp.abs(t) <= 1.0


def _check_unit_interval(name: str, value: Any, low: float = 0.0, high: float = 1.0) -> None:
    # Array-valued parameters (tensors being fitted) are the caller's to keep in range.
    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        checks.require_in_interval(name, value, low, high)
    elif isinstance(value, bool) or isinstance(value, (str, bytes)):
        raise TypeError(f"{name} must be a real number in [{low}, {high}], got {value!r}")


def _piecewise(a: Any, edge_width: Any, height: Any, edge_value: Any, xp: Any) -> Any:
    """Flat `height` for |t| < 1 - edge_width, `edge_value` on the edges, 0 beyond 1. With a zero edge
    width the window is a box, whose jump at |t| = 1 takes the midpoint value (see Box)."""
    at_one = xp.where(edge_width > 0, _zeros(a), 0.5 * height + _zeros(a))
    outer = xp.where(a < 1.0, edge_value, xp.where(a == 1.0, at_one, _zeros(a)))
    return xp.where(a < 1.0 - edge_width, height + _zeros(a), outer)


class ShutterWindow:
    """Base of the shutter windows: w(t) >= 0 on [-1, 1], integral 1, zero outside."""

    name: ClassVar[str] = ""

    def weight(self, t: Any, xp: Any = np) -> Any:  # pragma: no cover - abstract
        """w(t), elementwise, same shape as t; zero outside [-1, 1]."""
        raise NotImplementedError

    def antiderivative(self, t: Any, xp: Any = np) -> Any:
        """W(t) = integral of w over [-1, t]; exactly 0 for t <= -1 and 1 for t >= 1."""
        t = _clamp_t(_as_t(t, xp), xp)
        inner = self._antiderivative(t, xp)
        # Pin the ends exactly (sin(pi) is 1.2e-16, not 0) so that accumulation weights telescope.
        return xp.where(t <= -1.0, _zeros(t), xp.where(t >= 1.0, _zeros(t) + 1.0, inner))

    def _antiderivative(self, t: Any, xp: Any) -> Any:  # pragma: no cover - abstract
        """W(t) for t already clamped to [-1, 1]."""
        raise NotImplementedError

    @property
    def overlap_period(self) -> float | None:
        """Frame period P (normalised time) with sum_k w(t - k P) = 1 / P, or None (module docstring)."""
        return None


@dataclass(frozen=True)
class Box(ShutterWindow):
    """w(t) = 1/2 on [-1, 1]: the shutter open at full efficiency the whole exposure."""

    name: ClassVar[str] = "box"

    def weight(self, t: Any, xp: Any = np) -> Any:
        t = _as_t(t, xp)
        a = xp.abs(t)
        # At the jumps |t| = 1 the value is the midpoint 1/4, so shifted boxes sum to 1/P everywhere.
        return xp.where(a < 1.0, _zeros(t) + 0.5, xp.where(a == 1.0, _zeros(t) + 0.25, _zeros(t)))

    def _antiderivative(self, t: Any, xp: Any) -> Any:
        return 0.5 * (t + 1.0)

    @property
    def overlap_period(self) -> float:
        return 2.0


@dataclass(frozen=True)
class Tent(ShutterWindow):
    """w(t) = 1 - |t| on [-1, 1]."""

    name: ClassVar[str] = "tent"

    def weight(self, t: Any, xp: Any = np) -> Any:
        t = _as_t(t, xp)
        return xp.where(_inside(t, xp), 1.0 - xp.abs(t), _zeros(t))

    def _antiderivative(self, t: Any, xp: Any) -> Any:
        return xp.where(t < 0, 0.5 * (1.0 + t) * (1.0 + t), 1.0 - 0.5 * (1.0 - t) * (1.0 - t))

    @property
    def overlap_period(self) -> float:
        return 1.0


@dataclass(frozen=True)
class Trapezoid(ShutterWindow):
    """Flat top for |t| <= 1 - ramp, linear ramps to 0 over the outer `ramp` of each half.

    ramp in [0, 1] is the fraction of each half-exposure spent opening (closing): 0 is the box, 1 the
    tent. Height 1 / (2 - ramp). The ramp is differentiable where 0 < ramp <= 1.
    """

    ramp: Any = 0.5
    name: ClassVar[str] = "trapezoid"

    def __post_init__(self) -> None:
        _check_unit_interval("ramp", self.ramp)

    def weight(self, t: Any, xp: Any = np) -> Any:
        t = _as_t(t, xp)
        f = self.ramp + _zeros(t)
        # A zero ramp (the box) would divide by zero in the branch `where` discards; a NaN there
        # still poisons the gradient, so the divisor is made safe first.
        f_safe = xp.where(f > 0, f, _zeros(t) + 1.0)
        a = xp.abs(t)
        height = 1.0 / (2.0 - f)
        ramp_value = height * (1.0 - a) / f_safe
        return _piecewise(a, f, height, ramp_value, xp)

    def _antiderivative(self, t: Any, xp: Any) -> Any:
        f = self.ramp + _zeros(t)
        f_safe = xp.where(f > 0, f, _zeros(t) + 1.0)
        u = xp.abs(t)
        s = u - (1.0 - f)
        g_flat = u / (2.0 - f)
        g_ramp = ((1.0 - f) + s - s * s / (2.0 * f_safe)) / (2.0 - f)
        g = xp.where(u <= 1.0 - f, g_flat, g_ramp)
        return xp.where(t < 0, 0.5 - g, 0.5 + g)

    @property
    def overlap_period(self) -> float:
        return 2.0 - float(self.ramp)


@dataclass(frozen=True)
class RaisedCosine(ShutterWindow):
    """Seed 004's sinusoid: w(t) = (1 + cos(pi t)) / 2 on [-1, 1] (a Hann window)."""

    name: ClassVar[str] = "raised_cosine"

    def weight(self, t: Any, xp: Any = np) -> Any:
        t = _as_t(t, xp)
        return xp.where(_inside(t, xp), 0.5 * (1.0 + xp.cos(math.pi * t)), _zeros(t))

    def _antiderivative(self, t: Any, xp: Any) -> Any:
        return 0.5 * (t + 1.0) + xp.sin(math.pi * t) / (2.0 * math.pi)

    @property
    def overlap_period(self) -> float:
        return 1.0


@dataclass(frozen=True)
class Gaussian(ShutterWindow):
    """exp(-t^2 / (2 sigma^2)) truncated to [-1, 1] and renormalised to integrate to 1.

    sigma > 0 in normalised exposure units; differentiable in sigma.
    """

    sigma: Any = 0.5
    name: ClassVar[str] = "gaussian"

    def __post_init__(self) -> None:
        if isinstance(self.sigma, numbers.Real) or isinstance(self.sigma, bool):
            checks.require_positive_number("sigma", self.sigma)

    def _erf_edge(self, xp: Any) -> Any:
        return _erf(1.0 / (self.sigma * math.sqrt(2.0)), xp)

    def weight(self, t: Any, xp: Any = np) -> Any:
        t = _as_t(t, xp)
        sigma = self.sigma
        norm = sigma * math.sqrt(2.0 * math.pi) * self._erf_edge(xp)
        value = xp.exp(-(t * t) / (2.0 * sigma * sigma)) / norm
        return xp.where(_inside(t, xp), value, _zeros(t))

    def _antiderivative(self, t: Any, xp: Any) -> Any:
        edge = self._erf_edge(xp)
        return 0.5 * (_erf(t / (self.sigma * math.sqrt(2.0)), xp) + edge) / edge


@dataclass(frozen=True)
class Tukey(ShutterWindow):
    """Symmetric family from the box (taper 0) to the raised cosine (taper 1): a Tukey window.

    Flat for |t| <= 1 - taper, cosine tapers on the outer `taper` of each half; height
    1 / (2 - taper). Continuous and differentiable in taper on [0, 1].
    """

    taper: Any = 0.5
    name: ClassVar[str] = "tukey"

    def __post_init__(self) -> None:
        _check_unit_interval("taper", self.taper)

    def weight(self, t: Any, xp: Any = np) -> Any:
        t = _as_t(t, xp)
        alpha = self.taper + _zeros(t)
        alpha_safe = xp.where(alpha > 0, alpha, _zeros(t) + 1.0)  # safe divisor, see Trapezoid
        a = xp.abs(t)
        height = 1.0 / (2.0 - alpha)
        s = (a - (1.0 - alpha)) / alpha_safe
        taper_value = height * 0.5 * (1.0 + xp.cos(math.pi * s))
        return _piecewise(a, alpha, height, taper_value, xp)

    def _antiderivative(self, t: Any, xp: Any) -> Any:
        alpha = self.taper + _zeros(t)
        alpha_safe = xp.where(alpha > 0, alpha, _zeros(t) + 1.0)
        u = xp.abs(t)
        s = (u - (1.0 - alpha)) / alpha_safe
        g_flat = u / (2.0 - alpha)
        g_taper = ((1.0 - alpha) + 0.5 * alpha * (s + xp.sin(math.pi * s) / math.pi)) / (2.0 - alpha)
        g = xp.where(u <= 1.0 - alpha, g_flat, g_taper)
        return xp.where(t < 0, 0.5 - g, 0.5 + g)

    @property
    def overlap_period(self) -> float:
        return 2.0 - float(self.taper)


@dataclass(frozen=True)
class LinearRamp(ShutterWindow):
    """Asymmetric family: w(t) = (1 + slope t) / 2 on [-1, 1], slope in [-1, 1].

    slope > 0 weighs the end of the exposure more than its start, so the blur of a velocity +v
    differs from that of -v (a symmetric window cannot tell them apart). slope 0 is the box.
    """

    slope: Any = 0.5
    name: ClassVar[str] = "linear_ramp"

    def __post_init__(self) -> None:
        _check_unit_interval("slope", self.slope, -1.0, 1.0)

    def weight(self, t: Any, xp: Any = np) -> Any:
        t = _as_t(t, xp)
        return xp.where(_inside(t, xp), 0.5 * (1.0 + self.slope * t), _zeros(t))

    def _antiderivative(self, t: Any, xp: Any) -> Any:
        return 0.5 * (t + 1.0) + 0.25 * self.slope * (t * t - 1.0)


_WINDOWS: dict[str, type[ShutterWindow]] = {
    cls.name: cls for cls in (Box, Tent, Trapezoid, RaisedCosine, Gaussian, Tukey, LinearRamp)
}

#: Names `get_shutter` accepts, each giving the window with its default parameters.
SHUTTERS: tuple[str, ...] = tuple(_WINDOWS)


def get_shutter(shutter: str | ShutterWindow) -> ShutterWindow:
    """A window from its name (default parameters) or the window itself, unchanged.

    >>> get_shutter("trapezoid")
    Trapezoid(ramp=0.5)
    """
    if isinstance(shutter, ShutterWindow):
        return shutter
    if isinstance(shutter, str):
        if shutter not in _WINDOWS:
            raise ValueError(
                f"shutter must be one of {', '.join(repr(n) for n in SHUTTERS)} or a ShutterWindow; "
                f"got {shutter!r}"
            )
        return _WINDOWS[shutter]()
    raise TypeError(f"shutter must be a name (str) or a ShutterWindow, got {type(shutter).__name__}: {shutter!r}")


def instants(shutter: str | ShutterWindow, count: int) -> tuple[np.ndarray, np.ndarray]:
    """Stratified instants and their weights for accumulating over the exposure.

    [-1, 1] is cut into `count` equal strata; each instant is its stratum's midpoint and its weight is
    the window's exact integral over the stratum (W(b) - W(a)), renormalised to sum to 1 exactly.
    Returns (times (count,), weights (count,)), float64. count = 1 gives t = 0 with weight 1.
    """
    window = get_shutter(shutter)
    count = checks.require_positive_int("count", count)
    edges = np.linspace(-1.0, 1.0, count + 1)
    times = 0.5 * (edges[:-1] + edges[1:])
    cumulative = np.asarray(window.antiderivative(edges), dtype=np.float64)
    weights = np.diff(cumulative)
    return times, weights / weights.sum()


def overlap_sum(shutter: str | ShutterWindow, t: Any, *, period: float | None = None) -> np.ndarray:
    """P * sum_k w(t - k P): 1 everywhere for a window whose shifts by the frame period P tile.

    `period` defaults to the window's `overlap_period` (module docstring); pass one for a window that
    has none. t: any shape, normalised exposure time (NumPy). Returns an array of t's shape.
    """
    window = get_shutter(shutter)
    if period is None:
        period = window.overlap_period
        if period is None:
            raise ValueError(
                f"shutter {window.name!r} has no overlap period that sums to one; pass period= explicitly"
            )
    period = checks.require_positive_number("period", period)
    t = np.asarray(t, dtype=np.float64)
    # w(t - k P) is nonzero only for |t - k P| <= 1.
    k_low = math.floor((float(np.min(t)) - 1.0) / period) - 1
    k_high = math.ceil((float(np.max(t)) + 1.0) / period) + 1
    total = np.zeros_like(t)
    for k in range(k_low, k_high + 1):
        total = total + window.weight(t - k * period)
    return period * total
