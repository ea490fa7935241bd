"""The paper's pressure-angle model P = f_k(theta) = a * theta**b + c (Eq. 1) and its fit.

Units: pressure in kPa, angle in degrees. The model is defined for every angle: a negative
angle (the wearer moved the other way) counts as 0, so f(theta <= 0) = c. Coefficients are
kept in a range where f is finite for every angle up to 180 degrees: a > 0, 0 < b <= B_MAX.

The fit is Algorithm 1's least-squares step (Eq. 3-4), solved in a well-conditioned form of
the same law (core/power_law_fit.py: the pressure and slope at a reference angle inside the
measured range, and b; angles and pressures scaled) by scipy.optimize.least_squares with
method='trf' and its analytic Jacobian. The paper names Levenberg-Marquardt; 'trf' is the
trust-region form of the same Gauss-Newton step that also takes bounds, and two bounds are
physical: the pressure rises with the angle (slope >= 0, b > 0) and b stays where f is finite
(docs/calibration.md). At an interior minimum both solvers find the same least-squares point.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Sequence

import numpy as np

from . import power_law_fit as plf

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
        # p - c is capped at a*THETA_MAX**b (finite by the constructor) before the division
        # and the power: ((p - c) / a)**(1/b) then stays <= ~THETA_MAX, where a tiny a or b
        # would overflow it. (p - c cannot overflow: |c| <= exp(LOG_F_MAX).)
        ratio = np.minimum(np.maximum(p - self.c, 0.0), self.a * THETA_MAX ** self.b) / self.a
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


def _finite_or_none(v):
    return float(v) if v is not None and math.isfinite(v) else None


@dataclass(frozen=True)
class FitReport:
    """What the fit found, how well it explains the points and how well they determine it."""

    law: PowerLaw
    initial_guess: PowerLaw
    residuals: np.ndarray = field(repr=False)  # measured minus fitted pressure, kPa
    rmse: float  # kPa
    r2: float
    n_points: int
    nfev: int
    message: str
    #: The points as fitted (angles clipped to [0, THETA_MAX]) and the pressure range.
    theta: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    pressure: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    p_max: float = math.nan
    #: The fit's reference angle theta_r, deg (core/power_law_fit.py).
    reference_angle: float = math.nan
    #: Standard errors of a, b, c (None: not estimable with n = 3; inf: not identified).
    std_errors: dict = field(default_factory=dict)
    #: angle (deg) -> (fitted pressure, half-width of the 95 % band), kPa, at BAND_ANGLES_DEG.
    band_kpa: dict = field(default_factory=dict)
    #: The largest standard error of the fitted pressure at the measured angles, kPa (None: n = 3).
    max_se_at_points_kpa: float | None = None

    def as_dict(self) -> dict:
        return {
            'rmse_kpa': self.rmse,
            'r2': self.r2,
            'n_points': self.n_points,
            'residuals_kpa': [float(r) for r in self.residuals],
            'initial_guess': self.initial_guess.as_dict(),
            'function_evaluations': self.nfev,
            'solver_message': self.message,
            'reference_angle_deg': self.reference_angle,
            # None: not estimable (n = 3) or not identified (infinite); plain floats for YAML.
            'std_errors': {k: _finite_or_none(v) for k, v in self.std_errors.items()},
            'pressure_band_kpa': {float(t): [_finite_or_none(p), _finite_or_none(w)]
                                  for t, (p, w) in self.band_kpa.items()},
            'max_se_at_points_kpa': _finite_or_none(self.max_se_at_points_kpa),
        }


#: An angle below this fraction of the largest measured angle counts as no movement (0).
MIN_ANGLE_RATIO = 1e-9


def resolved(theta: np.ndarray) -> np.ndarray:
    """The angles as the solver takes them: one below MIN_ANGLE_RATIO of the largest is no
    movement (0). No tracker resolves it, and a ratio beyond that would put u^b of the fit's
    scaled model past what the solver's products hold (overflow). Residuals and R^2 are
    computed at the angles as measured."""
    top = float(np.max(theta)) if theta.size else 0.0
    return np.where(theta < MIN_ANGLE_RATIO * top, np.minimum(theta, 0.0), theta) if top > 0 else theta


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
    # Angles at or below 0 all mean "no movement": they count as one angle (and so does one
    # too small to resolve: resolved()).
    distinct = np.unique(np.clip(resolved(t), 0.0, THETA_MAX)).size
    if distinct < MIN_POINTS:
        raise CalibrationFitError(
            f'need at least {MIN_POINTS} distinct angles to fit a, b and c, got {distinct} '
            '(the wearer did not move with the pressure steps)')
    if np.max(t) > THETA_MAX:
        raise CalibrationFitError(f'angle {np.max(t):g} deg exceeds {THETA_MAX:g} deg')
    from scipy import stats   # here, not at import: only a fit needs scipy (docs/benchmarks.md, RSS)
    # Spearman's rho: Pearson's r of the ranks (ties share their mean rank).
    rp, rt = stats.rankdata(p), stats.rankdata(t)
    rp, rt = rp - rp.mean(), rt - rt.mean()
    rho = float(rp @ rt) / math.sqrt(float(rp @ rp) * float(rt @ rt))
    if not rho > 0:
        raise CalibrationFitError(
            f'angles do not increase with pressure (Spearman rho = {rho:.2f}): the power law cannot fit them')
    return np.clip(t, 0.0, THETA_MAX), p


def load_fit_libraries() -> None:
    """Import what a fit needs (scipy: 1-2 s). A node that fits live calls this when it starts,
    so that the import never lands inside a control step; everything else never pays for it."""
    from scipy import optimize, stats  # noqa: F401


def fit_power_law(theta: Sequence[float], pressure: Sequence[float], p_max: float,
                  xtol: float = 1e-10, ftol: float = 1e-10, min_r2: float | None = None) -> FitReport:
    """Fit P = a*theta**b + c to calibration points by least squares (Algorithm 1, Eq. 4).

    theta: angles reached at each step, degrees; pressure: the step pressures, kPa, strictly
    increasing within [0, p_max]. xtol/ftol: the solver's stopping tolerances (a knob of the
    accuracy/time trade-off). min_r2: refuse a fit that explains less than this.

    Solved as y = q + g*(u**b - 1)/b (u = theta/theta_r, y = P/p_max; power_law_fit.py), so
    the same points give the same law whatever their order of magnitude. Raises
    CalibrationFitError with the reason for data it cannot fit.
    """
    t, p = _check_points(theta, pressure, p_max)
    from scipy import optimize   # here, not at import: only a fit needs scipy
    tr = resolved(t)
    sc = plf.Scaled(plf.reference_angle(tr), float(p_max))
    lu, pos = plf.log_u(tr, sc.theta_r)
    y = p / sc.s
    x0 = plf.start(lu, pos, y)
    result = optimize.least_squares(
        lambda x: plf.model(x, lu, pos) - y, x0, jac=lambda x: plf.jacobian(x, lu, pos),
        bounds=([-np.inf, 0.0, plf.FIT_B_MIN], [np.inf, np.inf, plf.FIT_B_MAX]),
        method='trf', xtol=xtol, ftol=ftol, max_nfev=2000)
    if not np.all(np.isfinite(result.x)):
        raise CalibrationFitError(f'the fit diverged ({result.message})')
    abc = plf.to_abc(result.x, sc)
    if abc is None:
        raise CalibrationFitError('the fitted curve is flat (a = 0 or beyond a float): the angles do not '
                                  'rise with the pressure as a power law does')
    try:
        law = PowerLaw(*abc)
    except ValueError as exc:
        raise CalibrationFitError(f'the fit left the model\'s valid range: {exc}') from None
    start_abc = plf.to_abc(x0, sc)
    try:
        guess = PowerLaw(*start_abc) if start_abc is not None else law
    except ValueError:
        guess = law
    res = p - law.pressure(t)
    if not np.all(np.isfinite(res)):
        raise CalibrationFitError('the fitted curve is not finite at the measured angles')
    rmse = float(np.sqrt(np.mean(res ** 2)))
    ss_tot = float(np.sum((p - p.mean()) ** 2))
    r2 = 1.0 - float(np.sum(res ** 2)) / ss_tot if ss_tot > 0 else 0.0
    if min_r2 is not None and not r2 >= min_r2:
        raise CalibrationFitError(f'fit too poor: R^2 = {r2:.3f} < {min_r2:.3f} (RMSE {rmse:.1f} kPa)')
    unc = plf.uncertainty(result.x, sc, t, y)
    return FitReport(law=law, initial_guess=guess, residuals=res, rmse=rmse, r2=r2, n_points=int(t.size),
                     nfev=int(result.nfev), message=str(result.message), theta=t, pressure=p,
                     p_max=float(p_max), reference_angle=sc.theta_r, std_errors=unc.std_errors,
                     band_kpa=unc.band_kpa, max_se_at_points_kpa=unc.max_se_at_points_kpa)


def law_uncertainty(law: PowerLaw, theta: Sequence[float], pressure: Sequence[float],
                    p_max: float, angles: Sequence[float] = plf.BAND_ANGLES_DEG) -> plf.Uncertainty:
    """Standard errors of `law` and its pressure band at `angles`, given the points it was
    fitted to (e.g. read back from a calibration file): the same computation as the fit's."""
    t = np.clip(np.asarray(theta, dtype=float), 0.0, THETA_MAX)
    sc = plf.Scaled(plf.reference_angle(t), float(p_max))
    return plf.uncertainty(plf.from_abc(law.a, law.b, law.c, sc), sc, t,
                           np.asarray(pressure, dtype=float) / sc.s, angles)
