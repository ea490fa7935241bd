"""The calibration fit and acceptance as they were before the fit was reparametrised (kept as a
reference for `python -m fabric_guidance.experiments.calibration_sweep`, the "before" column):
Levenberg-Marquardt on (ln a, ln b, c) from a log-log start, accepted on R^2, RMSE, span and
reversal only. Not used for guidance.
"""
from __future__ import annotations

import math

import numpy as np

from ..core.calibration import Acceptance
from ..core.power_law import THETA_EPS, CalibrationFitError, FitReport, PowerLaw, _check_points

#: The acceptance before: R^2, span, reversal, RMSE; none of the shape checks.
LEGACY_ACCEPTANCE = Acceptance(0.8, 5.0, 2.0, 37.5, *[None] * 6)


def legacy_guess(theta: np.ndarray, pressure: np.ndarray) -> PowerLaw:
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


def legacy_fit(theta, pressure, p_max: float) -> FitReport:
    """The fit as it was: LM on x = (ln a, ln b, c), unscaled."""
    from scipy import optimize
    t, p = _check_points(theta, pressure, p_max)
    guess = legacy_guess(t, p)
    log_t = np.log(np.maximum(t, np.finfo(float).tiny))
    zero = t <= 0.0

    def powers(beta):
        b = math.exp(min(max(beta, -30.0), 5.0))
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
        return np.column_stack([a * tb, np.where(zero, 0.0, a * tb * log_t * b), np.ones_like(t)])

    x0 = np.array([math.log(guess.a), math.log(guess.b), guess.c])
    with np.errstate(over='ignore', invalid='ignore'):
        result = optimize.least_squares(residuals, x0, jac=jacobian, method='lm', xtol=1e-10, ftol=1e-10,
                                        max_nfev=2000)
    alpha, beta, c = result.x
    if not (np.all(np.isfinite(result.x)) and alpha < 700.0 and beta < 5.0):
        raise CalibrationFitError(f'the fit diverged ({result.message})')
    try:
        law = PowerLaw(math.exp(alpha), math.exp(beta), c)
    except ValueError as exc:
        raise CalibrationFitError(f'the fit left the model\'s valid range: {exc}') from None
    res = p - law.pressure(t)
    rmse = float(np.sqrt(np.mean(res ** 2)))
    ss_tot = float(np.sum((p - p.mean()) ** 2))
    r2 = 1.0 - float(np.sum(res ** 2)) / ss_tot if ss_tot > 0 else 0.0
    return FitReport(law=law, initial_guess=guess, residuals=res, rmse=rmse, r2=r2, n_points=int(t.size),
                     nfev=int(result.nfev), message=str(result.message), theta=t, pressure=p,
                     p_max=float(p_max))
