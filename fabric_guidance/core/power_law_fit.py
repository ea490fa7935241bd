"""Eq. 1 in the form the fit solves, and the fit's uncertainty.

P = a*theta^b + c is poorly conditioned as (a, b, c): a spans decades with b, and a small b
makes a*theta^b + c the difference of two large numbers (a law near a logarithm, a = 1.25e5,
b = 0.0019, c = -1.25e5, is 237*ln(theta) computed by cancellation). The fit therefore solves
the same law written around a reference angle theta_r inside the measured range, with the
angle and the pressure scaled (u = theta/theta_r, y = P/s, s = P_MAX):

    y = q + g * (u^b - 1)/b

q = f(theta_r)/s is the scaled pressure at theta_r, g = theta_r*f'(theta_r)/s the scaled slope
there, b the exponent: three unknowns of one scale (order 1) that each mean something, and
(u^b - 1)/b stays finite as b -> 0 (it tends to ln u), so a law near a logarithm is an ordinary
point of the solver and visible as a small b rather than as huge a and c. Back to Eq. 1:

    a = s*g / (b*theta_r^b),   c = s*(q - g/b).

Everything here is plain numpy; the solver call and the checks are in power_law.py.
"""
from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np

#: Bounds of the exponent in the solver. b > 0 with g >= 0 is the paper's requirement that the
#: pressure rises with the angle; the upper bound keeps f finite over 0..180 deg. They are
#: wider than what the acceptance passes (core.calibration.Acceptance) so that a fit pushing
#: against them is seen, reported and refused, not silently reshaped.
FIT_B_MIN = 0.05
FIT_B_MAX = 10.0
#: Largest b*ln(u) evaluated: u^b up to 1e100. Beyond it a trial step of the solver is far off
#: anyway; the cap keeps every residual, and its square, finite.
MAX_B_LOG_U = 230.0
#: The exponents of the start's grid (each a linear least-squares fit of q and g).
START_GRID = np.geomspace(FIT_B_MIN, FIT_B_MAX, 33)
#: Pressures at which the fit report gives the fitted pressure and its band, deg.
BAND_ANGLES_DEG = (10.0, 20.0, 30.0)
#: Coverage of the band: two-sided, Student t with n - 3 degrees of freedom.
BAND_COVERAGE = 0.95


class Scaled(NamedTuple):
    """The fit's unknowns x = (q, g, b) and the scales that make them of order 1."""

    theta_r: float   # reference angle, deg (> 0)
    s: float         # pressure scale, kPa (> 0)


def reference_angle(theta: np.ndarray) -> float:
    """theta_r: the median of the positive measured angles (inside the measured range whatever
    the angles' order of magnitude); 1 deg when none is positive."""
    pos = theta[theta > 0.0]
    return float(np.median(pos)) if pos.size else 1.0


def log_u(theta: np.ndarray, theta_r: float) -> tuple[np.ndarray, np.ndarray]:
    """(ln(theta/theta_r) where theta > 0 else 0, mask of theta > 0)."""
    pos = theta > 0.0
    safe = np.where(pos, theta, theta_r)
    return np.log(safe) - math.log(theta_r), pos


def basis(b: float, lu: np.ndarray, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(h, dh/db) with h = (u^b - 1)/b; u = 0 (theta <= 0) gives h = -1/b, dh/db = 1/b^2."""
    bl = np.minimum(b * lu, MAX_B_LOG_U)
    e = np.exp(bl)                       # u^b; underflows to 0 far below theta_r, as it should
    h = np.expm1(bl) / b                 # no cancellation for b*ln(u) near 0
    dh = (lu * e - h) / b
    h = np.where(pos, h, -1.0 / b)
    dh = np.where(pos, dh, 1.0 / (b * b))
    return h, dh


def model(x: np.ndarray, lu: np.ndarray, pos: np.ndarray) -> np.ndarray:
    q, g, b = x
    h, _ = basis(b, lu, pos)
    return q + g * h


def jacobian(x: np.ndarray, lu: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """d(model)/d(q, g, b), analytic."""
    _, g, b = x
    h, dh = basis(b, lu, pos)
    return np.column_stack([np.ones_like(h), h, g * dh])


def start(lu: np.ndarray, pos: np.ndarray, y: np.ndarray) -> np.ndarray:
    """A deliberate start: for each b of a grid, q and g by linear least squares (the model is
    linear in them: a straight line of y against h); the b with the smallest squared error and
    a rising curve (g > 0). All b at once, one row each."""
    b = START_GRID[:, None]
    h = np.where(pos, np.expm1(np.minimum(b * lu, MAX_B_LOG_U)) / b, -1.0 / b)
    hm = h.mean(axis=1, keepdims=True)
    hc = h - hm
    yc = y - y.mean()
    shh = np.einsum('ij,ij->i', hc, hc)
    ok = shh > 0.0
    g = np.where(ok, hc @ yc / np.where(ok, shh, 1.0), 0.0)
    q = y.mean() - g * hm[:, 0]
    sse = np.einsum('ij,ij->i', q[:, None] + g[:, None] * h - y, q[:, None] + g[:, None] * h - y)
    sse = np.where(ok & (g > 0.0) & np.isfinite(sse), sse, np.inf)
    k = int(np.argmin(sse))
    if not math.isfinite(sse[k]):  # no rising line at any b: start flat-ish at b = 1
        return np.array([float(np.mean(y)), 1e-3, 1.0])
    return np.array([float(q[k]), float(g[k]), float(START_GRID[k])])


@functools.lru_cache(maxsize=64)
def t_quantile(dof: int) -> float:
    """The two-sided BAND_COVERAGE quantile of Student's t with dof degrees of freedom."""
    from scipy import stats  # only a fit or a report needs it
    return float(stats.t.ppf(0.5 + BAND_COVERAGE / 2.0, dof))


def to_abc(x: np.ndarray, sc: Scaled) -> tuple[float, float, float] | None:
    """(a, b, c) of Eq. 1, or None when a is not a positive number a float can hold."""
    q, g, b = (float(v) for v in x)
    if not (g > 0.0 and b > 0.0):
        return None
    log_a = math.log(sc.s) + math.log(g) - math.log(b) - b * math.log(sc.theta_r)
    if not -700.0 < log_a < 700.0:
        return None
    return math.exp(log_a), b, sc.s * (q - g / b)


def from_abc(a: float, b: float, c: float, sc: Scaled) -> np.ndarray:
    """x = (q, g, b) of a law (a, b, c): q = f(theta_r)/s, g = theta_r*f'(theta_r)/s."""
    at = math.exp(math.log(a) + b * math.log(sc.theta_r))   # a*theta_r^b, without overflow
    return np.array([(at + c) / sc.s, at * b / sc.s, b])


class Uncertainty(NamedTuple):
    """How well the points determine the law (ordinary least-squares covariance)."""

    dof: int                    # n - 3
    std_errors: dict            # {'a', 'b', 'c'} -> standard error, or None (not estimable)
    band_kpa: dict              # angle (deg) -> (fitted P, half-width of the band) in kPa
    max_se_at_points_kpa: float | None     # the largest standard error at the measured angles


def uncertainty(x: np.ndarray, sc: Scaled, theta: np.ndarray, y: np.ndarray,
                angles=BAND_ANGLES_DEG) -> Uncertainty:
    """Standard errors of a, b, c, of the fitted pressure at the measured angles, and the
    BAND_COVERAGE band of the fitted pressure at `angles`, from the Jacobian at x and the
    residual variance (n - 3 degrees of freedom). With n = 3 nothing can
    be estimated (None); a singular Jacobian gives an infinite band (not identified)."""
    lu, pos = log_u(theta, sc.theta_r)
    n = theta.size
    dof = n - 3
    abc = to_abc(x, sc)
    none = Uncertainty(dof, {'a': None, 'b': None, 'c': None},
                       {float(t): (None, None) for t in angles}, None)
    if dof <= 0 or abc is None:
        return none
    r = model(x, lu, pos) - y
    s2 = float(np.sum(r * r)) / dof
    jac = jacobian(x, lu, pos)
    # Pseudo-inverse as scipy's curve_fit does: singular directions are not identified.
    _, sv, vt = np.linalg.svd(jac, full_matrices=False)
    if not (sv.size == 3 and sv[-1] > np.finfo(float).eps * max(jac.shape) * sv[0]):
        inf = math.inf
        return Uncertainty(dof, {'a': inf, 'b': inf, 'c': inf},
                           {float(t): (None, inf) for t in angles}, inf)
    # cov(q, g, b) = m @ m.T with m = V / sv * sqrt(s2): a variance is a squared norm of
    # grad @ m, whose entries stay far from overflow even when the fit is barely identified.
    m = vt.T / sv * math.sqrt(s2)
    k = t_quantile(dof)

    def std_error(th: np.ndarray) -> np.ndarray:
        grad = jacobian(x, *log_u(th, sc.theta_r))
        return sc.s * np.linalg.norm(grad @ m, axis=1)

    a, b, c = abc
    q, g, _ = x
    # Delta method from (q, g, b). For a, in logs: se(a) = a * se(ln a) and
    # a * d(ln a)/dg = s / (b * theta_r^b), so neither a huge a nor a tiny g overflows.
    lr = math.log(sc.theta_r)
    se_b = float(np.linalg.norm(m[2]))
    se_c = sc.s * float(np.linalg.norm(np.array([1.0, -1.0 / b, g / (b * b)]) @ m))
    inner = float(np.linalg.norm(np.array([0.0, 1.0, -g * (1.0 / b + lr)]) @ m))
    if inner > 0.0:
        log_se_a = math.log(sc.s) - math.log(b) - b * lr + math.log(inner)
        se_a = math.exp(log_se_a) if log_se_a < 700.0 else math.inf
    else:
        se_a = 0.0
    se = {'a': se_a, 'b': se_b, 'c': se_c}
    grid = np.asarray(angles, dtype=float)
    fitted = model(x, *log_u(grid, sc.theta_r)) * sc.s
    band = {float(t): (float(p), k * float(w)) for t, p, w in zip(grid, fitted, std_error(grid))}
    return Uncertainty(dof, se, band, float(np.max(std_error(np.maximum(theta, 0.0)))))
