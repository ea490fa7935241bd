"""The paper's pressure-angle model P = f_k(theta) = a * theta**b + c (Eq. 1) and its fit.

Units: pressure in kPa, angle in degrees. The model is defined for every angle: a negative
angle (the wearer moved the other way) counts as 0, so f(theta <= 0) = c. Coefficients are
kept in a range where f is finite for every angle up to 180 degrees: a > 0, 0 < b <= B_MAX.

The fit is Algorithm 1's least-squares step (Eq. 3-4): scipy.optimize.least_squares with
method='lm' (MINPACK's Levenberg-Marquardt). LM is unconstrained, so a and b are fitted as
logarithms (a = exp(alpha), b = exp(beta)): the solver cannot leave a > 0, b > 0, where the
model is increasing as the paper requires.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Sequence

import numpy as np

#: Largest exponent accepted; 180**20 * a stays far from float overflow for any sane a.
B_MAX = 20.0
#: Smallest exponent accepted; below it the curve is a step, which no wearer is.
B_MIN = 1e-3
#: Angle range of the model, degrees: angles beyond 180 do not exist after wrapping.
THETA_MAX = 180.0
#: Derivatives are evaluated no closer to 0 than this (degrees), so they stay bounded
#: where b < 1 (f' ~ theta**(b-1)) or b > 1 (the inverse's derivative ~ theta**(1-b)).
THETA_EPS = 0.01
#: Smallest a accepted: far below any real wearer (a = 375 / 180**20 is ~1e-43), far above
#: the subnormal range where 1 / (a*b) overflows.
A_MIN = 1e-100
#: Largest d(theta)/dP reported, deg/kPa: the whole angle range per 1e-4 kPa.
INVERSE_SLOPE_MAX = 1e6
#: log of the largest |f| the model may reach (about 1e260 kPa): keeps sums and differences of f finite.
LOG_F_MAX = 600.0
#: Smallest number of distinct angles the three coefficients can be fitted to.
MIN_POINTS = 3


class CalibrationFitError(ValueError):
    """Calibration data that cannot be fitted, with the reason in the message."""


@dataclass(frozen=True)
class PowerLaw:
    """P = a * max(theta, 0)**b + c, pressure in kPa, theta in degrees."""

    a: float
    b: float
    c: float

    def __post_init__(self) -> None:
        for name in ('a', 'b', 'c'):
            value = getattr(self, name)
            if not isinstance(value, (int, float, np.floating, np.integer)) or not math.isfinite(value):
                raise ValueError(f'power law coefficient {name} must be a finite number, got {value!r}')
        if not self.a >= A_MIN:
            raise ValueError(f'power law coefficient a must be >= {A_MIN:g} (pressure rises with angle), got {self.a}')
        if not B_MIN <= self.b <= B_MAX:
            raise ValueError(f'power law exponent b must be within [{B_MIN}, {B_MAX}], got {self.b}')
        # f must stay finite over the whole angle range: a * 180**b + c far from float overflow.
        if math.log(self.a) + self.b * math.log(THETA_MAX) > LOG_F_MAX or abs(self.c) > math.exp(LOG_F_MAX):
            raise ValueError(f'power law coefficients a={self.a:g}, b={self.b:g}, c={self.c:g} overflow '
                             f'before {THETA_MAX:g} deg')
        object.__setattr__(self, 'a', float(self.a))
        object.__setattr__(self, 'b', float(self.b))
        object.__setattr__(self, 'c', float(self.c))

    def pressure(self, theta):
        """f(theta) in kPa; theta <= 0 (or NaN-free negative) gives c. Accepts scalars or arrays."""
        if type(theta) is float:  # the control loop's case: the same formula in scalar math
            t = 0.0 if theta < 0.0 else (THETA_MAX if theta > THETA_MAX else theta)
            if t == t:
                return self.a * t ** self.b + self.c
        t = np.clip(np.asarray(theta, dtype=float), 0.0, THETA_MAX)
        if np.any(np.isnan(t)):
            raise ValueError('angle is NaN')
        out = self.a * np.power(t, self.b) + self.c
        return float(out) if np.ndim(out) == 0 else out

    def theta(self, pressure, p_max: float):
        """The inverse: the angle in degrees that f maps to `pressure`.

        Below c it is 0 (no movement is expected); above p_max it saturates at f^-1(p_max)
        (the suit cannot press harder). Defined for every finite pressure.
        """
        p = np.asarray(pressure, dtype=float)
        if np.any(np.isnan(p)):
            raise ValueError('pressure is NaN')
        p = np.minimum(p, p_max)
        ratio = np.maximum(p - self.c, 0.0) / self.a
        out = np.minimum(np.power(ratio, 1.0 / self.b), THETA_MAX)
        return float(out) if np.ndim(out) == 0 else out

    def slope(self, theta):
        """df/dtheta in kPa/deg, bounded: theta is floored at THETA_EPS."""
        t = np.clip(np.asarray(theta, dtype=float), THETA_EPS, THETA_MAX)
        out = self.a * self.b * np.power(t, self.b - 1.0)
        return float(out) if np.ndim(out) == 0 else out

    def inverse_slope(self, pressure, p_max: float):
        """d(theta)/dP in deg/kPa of the inverse, bounded: evaluated at theta >= THETA_EPS and
        capped at INVERSE_SLOPE_MAX."""
        t = np.maximum(np.asarray(self.theta(pressure, p_max), dtype=float), THETA_EPS)
        with np.errstate(over='ignore', divide='ignore'):
            out = np.minimum(1.0 / (self.a * self.b * np.power(t, self.b - 1.0)), INVERSE_SLOPE_MAX)
        return float(out) if np.ndim(out) == 0 else out

    def as_dict(self) -> dict:
        return {'a': self.a, 'b': self.b, 'c': self.c}


@dataclass(frozen=True)
class FitReport:
    """What the fit found and how well it explains the points."""

    law: PowerLaw
    initial_guess: PowerLaw
    residuals: np.ndarray = field(repr=False)  # measured minus fitted pressure, kPa
    rmse: float  # kPa
    r2: float
    n_points: int
    nfev: int
    message: str

    def as_dict(self) -> dict:
        return {
            'rmse_kpa': self.rmse,
            'r2': self.r2,
            'n_points': self.n_points,
            'residuals_kpa': [float(r) for r in self.residuals],
            'initial_guess': self.initial_guess.as_dict(),
            'function_evaluations': self.nfev,
            'solver_message': self.message,
        }


def _check_points(theta: Sequence[float], pressure: Sequence[float], p_max: float):
    t = np.asarray(theta, dtype=float).ravel()
    p = np.asarray(pressure, dtype=float).ravel()
    if t.shape != p.shape:
        raise CalibrationFitError(f'{t.size} angles but {p.size} pressures: one angle per pressure step')
    if not (math.isfinite(p_max) and p_max > 0):
        raise CalibrationFitError(f'maximum pressure must be finite and > 0, got {p_max}')
    if not np.all(np.isfinite(t)):
        raise CalibrationFitError(f'non-finite angle at step(s) {np.flatnonzero(~np.isfinite(t)).tolist()}')
    if not np.all(np.isfinite(p)):
        raise CalibrationFitError(f'non-finite pressure at step(s) {np.flatnonzero(~np.isfinite(p)).tolist()}')
    if np.any(p < 0) or np.any(p > p_max):
        raise CalibrationFitError(f'pressures must lie within [0, {p_max}] kPa, got {p.min():g}..{p.max():g}')
    if p.size >= 2 and not np.all(np.diff(p) > 0):
        bad = int(np.flatnonzero(np.diff(p) <= 0)[0])
        raise CalibrationFitError(
            f'pressures must increase step by step (Algorithm 1): step {bad + 1} is {p[bad + 1]:g} kPa '
            f'after {p[bad]:g} kPa')
    # Angles at or below 0 all mean "no movement": they count as one angle.
    distinct = np.unique(np.clip(t, 0.0, THETA_MAX)).size
    if distinct < MIN_POINTS:
        raise CalibrationFitError(
            f'need at least {MIN_POINTS} distinct angles to fit a, b and c, got {distinct} '
            '(the wearer did not move with the pressure steps)')
    if np.max(t) > THETA_MAX:
        raise CalibrationFitError(f'angle {np.max(t):g} deg exceeds {THETA_MAX:g} deg')
    from scipy import stats   # here, not at import: only a fit needs scipy (docs/benchmarks.md, RSS)
    rho = stats.spearmanr(p, t).statistic
    if not rho > 0:
        raise CalibrationFitError(
            f'angles do not increase with pressure (Spearman rho = {rho:.2f}): the power law cannot fit them')
    return np.clip(t, 0.0, THETA_MAX), p


def load_fit_libraries() -> None:
    """Import what a fit needs (scipy: 1-2 s). A node that fits live calls this when it starts,
    so that the import never lands inside a control step; everything else never pays for it."""
    from scipy import optimize, stats  # noqa: F401


def initial_guess(theta: np.ndarray, pressure: np.ndarray) -> PowerLaw:
    """A deliberate start for LM: c a little below the smallest pressure, then a and b from
    a straight-line fit of log(P - c) against log(theta) over the positive angles."""
    span = float(pressure.max() - pressure.min()) or 1.0
    c0 = float(pressure.min()) - 0.1 * span
    pos = theta > THETA_EPS
    b0, a0 = 1.0, max(span / max(float(theta.max()), 1.0), 1e-12)
    if np.count_nonzero(pos) >= 2 and np.unique(theta[pos]).size >= 2:
        slope, intercept = np.polyfit(np.log(theta[pos]), np.log(pressure[pos] - c0), 1)
        if math.isfinite(slope) and slope > 0:
            b0 = float(np.clip(slope, 0.05, 5.0))
            a0 = float(math.exp(np.clip(intercept, -50.0, 50.0)))
    return PowerLaw(a0, b0, c0)


def fit_power_law(theta: Sequence[float], pressure: Sequence[float], p_max: float,
                  xtol: float = 1e-10, ftol: float = 1e-10, min_r2: float | None = None) -> FitReport:
    """Fit P = a*theta**b + c to calibration points by Levenberg-Marquardt (Algorithm 1).

    theta: angles reached at each step, degrees; pressure: the step pressures, kPa, strictly
    increasing within [0, p_max]. xtol/ftol: the solver's stopping tolerances (a knob of the
    accuracy/time trade-off). min_r2: refuse a fit that explains less than this.

    Raises CalibrationFitError with the reason for data it cannot fit.
    """
    t, p = _check_points(theta, pressure, p_max)
    try:
        guess = initial_guess(t, p)
    except ValueError as exc:
        raise CalibrationFitError(f'no usable starting point for the fit: {exc}') from None
    log_t = np.log(np.maximum(t, np.finfo(float).tiny))
    zero = t <= 0.0

    def powers(beta):
        # LM may try wild steps; clipping keeps exp() finite, and the result is validated after.
        b = math.exp(min(max(beta, -30.0), 5.0))
        # exp(b*log t) with the exponent clipped: never overflows; t = 0 gives exactly 0.
        tb = np.exp(np.clip(b * log_t, -745.0, 700.0))
        tb[zero] = 0.0
        return b, tb

    def residuals(x):
        alpha, beta, c = x
        _, tb = powers(beta)
        return math.exp(min(alpha, 700.0)) * tb + c - p

    def jacobian(x):
        alpha, beta, _ = x
        b, tb = powers(beta)
        a = math.exp(min(alpha, 700.0))
        d_alpha = a * tb
        # d/dbeta of a*t**exp(beta) = a * t**b * log(t) * b; the limit at t = 0 is 0.
        d_beta = np.where(zero, 0.0, a * tb * log_t * b)
        return np.column_stack([d_alpha, d_beta, np.ones_like(t)])

    x0 = np.array([math.log(guess.a), math.log(guess.b), guess.c])
    with np.errstate(over='ignore', invalid='ignore'):
        from scipy import optimize   # (as above)
        result = optimize.least_squares(residuals, x0, jac=jacobian, method='lm', xtol=xtol, ftol=ftol,
                                        max_nfev=2000)
    alpha, beta, c = result.x
    if not (np.all(np.isfinite(result.x)) and alpha < 700.0 and beta < 5.0):
        raise CalibrationFitError(f'the fit diverged ({result.message})')
    try:
        law = PowerLaw(math.exp(alpha), math.exp(beta), c)
    except ValueError as exc:
        raise CalibrationFitError(f'the fit left the model\'s valid range: {exc}') from None
    res = p - law.pressure(t)
    if not np.all(np.isfinite(res)):
        raise CalibrationFitError('the fitted curve is not finite at the measured angles')
    rmse = float(np.sqrt(np.mean(res ** 2)))
    ss_tot = float(np.sum((p - p.mean()) ** 2))
    r2 = 1.0 - float(np.sum(res ** 2)) / ss_tot if ss_tot > 0 else 0.0
    if min_r2 is not None and not r2 >= min_r2:
        raise CalibrationFitError(f'fit too poor: R^2 = {r2:.3f} < {min_r2:.3f} (RMSE {rmse:.1f} kPa)')
    return FitReport(law=law, initial_guess=guess, residuals=res, rmse=rmse, r2=r2, n_points=int(t.size),
                     nfev=int(result.nfev), message=str(result.message))
