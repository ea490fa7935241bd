"""The strategies, settings and checks the property tests of the core share
(test_core_properties.py: the power law and its fit; test_guidance_properties.py: geometry, the
feedback law, the channel map, speech and Algorithm 1's procedure)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, event, settings, strategies as st

from fabric_guidance.core.feedback import PAPER_P_MAX
from fabric_guidance.core.geometry import MIN_NORM
from fabric_guidance.core.power_law import (
    B_MAX, B_MIN, THETA_MAX, CalibrationFitError, FitReport, PowerLaw, fit_power_law,
)

P_MAX = PAPER_P_MAX
CHANNEL_MAP = Path(__file__).resolve().parents[1] / 'config' / 'hardware/channel_map.yaml'

_SLOW_OK = [HealthCheck.too_slow, HealthCheck.filter_too_much]


@pytest.fixture(autouse=True)
def floating_point_errors_raise():
    """Every property runs with numpy raising on overflow, invalid and divide (underflow may
    pass): the core handles its hard cases rather than letting a warning through."""
    with np.errstate(over='raise', invalid='raise', divide='raise', under='ignore'):
        yield


FAST = settings(max_examples=100, deadline=None, suppress_health_check=_SLOW_OK)
FITS = settings(max_examples=50, deadline=None, suppress_health_check=_SLOW_OK)
SLOW = settings(max_examples=25, deadline=None, suppress_health_check=_SLOW_OK)

# ---------------------------------------------------------------------------------------------
# Strategies and helpers
# ---------------------------------------------------------------------------------------------

finite = st.floats(allow_nan=False, allow_infinity=False)
non_finite = st.sampled_from([math.nan, math.inf, -math.inf])
positive_finite = st.floats(min_value=0.0, exclude_min=True, allow_infinity=False)


def law_or_none(abc):
    """The PowerLaw for (a, b, c), or None when the constructor refuses it with a clear ValueError."""
    try:
        return PowerLaw(*abc)
    except ValueError as exc:
        assert str(exc)
        return None


#: Laws a calibration can sensibly produce: a over twelve decades, any accepted b, |c| <= P_MAX.
sane_laws = st.tuples(
    st.floats(-6.0, 6.0).map(lambda e: 10.0 ** e),
    st.floats(B_MIN, B_MAX),
    st.floats(-P_MAX, P_MAX),
).map(law_or_none).filter(lambda law: law is not None)
#: Raw coefficients spanning every finite float (a > 0, b within [B_MIN, B_MAX]).
raw_coefficients = st.tuples(positive_finite, st.floats(B_MIN, B_MAX), finite)
#: Every law the PowerLaw constructor accepts (e.g. read back from a calibration file).
accepted_laws = raw_coefficients.map(law_or_none).filter(lambda law: law is not None)

angles_0_180 = st.floats(0.0, THETA_MAX)


def robust_norm(v) -> float:
    """Euclidean norm that neither overflows nor underflows (the reference, not the code under test)."""
    v = np.asarray(v, dtype=float)
    m = float(np.max(np.abs(v)))
    return 0.0 if m == 0.0 else m * float(np.linalg.norm(v / m))


vectors = st.tuples(finite, finite, finite)
#: Finite vectors of any magnitude, clearly away from the zero-length threshold.
non_degenerate = vectors.filter(lambda v: robust_norm(v) > 10 * MIN_NORM)
#: Moderate vectors, clearly non-degenerate.
moderate_vectors = st.tuples(*[st.floats(-1e6, 1e6)] * 3).filter(lambda v: robust_norm(v) > 1e-3)
unit_vectors = moderate_vectors.map(lambda v: tuple(np.asarray(v) / np.linalg.norm(v)))
#: Zero-length for the package: |v| <= sqrt(3) * 5e-10 < MIN_NORM.
zero_length = st.tuples(*[st.floats(-5e-10, 5e-10)] * 3)


@st.composite
def non_finite_vectors(draw, n=3):
    v = list(draw(st.tuples(*[finite] * n)))
    v[draw(st.integers(0, n - 1))] = draw(non_finite)
    return tuple(v)


@st.composite
def vertical_vectors(draw):
    """Straight up or down, with a horizontal part the code treats as vanished (< 1e-6 of |v|)."""
    z = draw(st.floats(1e-3, 1e3)) * draw(st.sampled_from([1.0, -1.0]))
    x = draw(st.floats(-1.0, 1.0)) * abs(z) * 5e-7
    y = draw(st.floats(-1.0, 1.0)) * abs(z) * 5e-7
    return (x, y, z)


@st.composite
def calibration_pressures(draw, p_max=P_MAX, min_size=3, max_size=12):
    """Strictly increasing pressures within [0, p_max], as Algorithm 1 applies them."""
    ps = draw(st.lists(st.floats(0.0, p_max), min_size=min_size, max_size=max_size, unique=True))
    return sorted(ps)


@st.composite
def power_law_points(draw, b_range=(0.2, 3.0)):
    """Angles a wearer with an exact power law reaches at an Algorithm 1 schedule: n evenly
    spaced steps up to P_MAX; c below the first step; the last step reaches theta_max, i.e.
    theta = theta_max * ((p - c) / (P_MAX - c))**(1/b)."""
    n = draw(st.integers(3, 12))
    p = np.linspace(draw(st.floats(0.0, 0.9 * P_MAX)), P_MAX, n)
    b = draw(st.floats(*b_range))
    c = draw(st.floats(-P_MAX, float(p[0])))
    theta_max = draw(st.floats(1.0, THETA_MAX))
    theta = theta_max * (np.maximum(p - c, 0.0) / (P_MAX - c)) ** (1.0 / b)
    return p, theta


def clamp(p: float, p_max: float) -> float:
    return min(max(p, 0.0), p_max)


def circular_distance(x: float, y: float) -> float:
    d = abs(x - y) % 360.0
    return min(d, 360.0 - d)


def assert_finite(x, what='value'):
    arr = np.asarray(x, dtype=float)
    assert np.all(np.isfinite(arr)), f'{what} is not finite: {x!r}'


def assert_pressures_bounded(p, p_max, what='pressure'):
    arr = np.asarray(p, dtype=float)
    assert_finite(arr, what)
    assert np.all(arr >= 0.0) and np.all(arr <= p_max), f'{what} outside [0, {p_max}]: {p!r}'


def check_law_functions(law: PowerLaw, theta: float, pressure: float, p_max: float = P_MAX) -> None:
    """pressure, slope, theta and inverse_slope of a law are finite and within their ranges."""
    p = law.pressure(theta)
    assert_finite(p, f'{law}.pressure({theta})')
    slope = law.slope(theta)
    assert_finite(slope, f'{law}.slope({theta})')
    assert slope >= 0.0
    inv = law.theta(pressure, p_max)
    assert_finite(inv, f'{law}.theta({pressure})')
    assert 0.0 <= inv <= THETA_MAX
    inv_slope = law.inverse_slope(pressure, p_max)
    assert_finite(inv_slope, f'{law}.inverse_slope({pressure})')
    assert inv_slope > 0.0


def check_fit_report(report: FitReport, theta, pressure) -> None:
    """A FitReport that is finite and agrees with an independent evaluation of the model."""
    assert isinstance(report, FitReport)
    law = report.law
    for value in (law.a, law.b, law.c):
        assert math.isfinite(value)
    assert law.a > 0 and B_MIN <= law.b <= B_MAX
    assert math.isfinite(report.rmse) and report.rmse >= 0.0
    assert math.isfinite(report.r2) and report.r2 <= 1.0 + 1e-12
    res = np.asarray(report.residuals, dtype=float)
    assert res.shape == (len(pressure),) and report.n_points == len(pressure)
    assert_finite(res, 'residuals')
    for t_i, p_i, r_i in zip(theta, pressure, res):
        model = law.a * max(float(t_i), 0.0) ** law.b + law.c  # plain Python floats
        expected = float(p_i) - model
        scale = max(1.0, abs(float(p_i)), abs(law.c), abs(model))
        assert abs(r_i - expected) <= 1e-9 * scale, (t_i, p_i, r_i, expected)
    assert math.isclose(report.rmse, math.sqrt(float(np.mean(res ** 2))), rel_tol=1e-9, abs_tol=1e-300)
    # The fitted law is usable over the whole angle range.
    assert_finite(law.pressure(np.linspace(0.0, THETA_MAX, 181)), 'fitted law')


def fit_or_clear_error(theta, pressure, p_max=P_MAX):
    """fit_power_law's contract: a checked FitReport or CalibrationFitError, nothing else."""
    try:
        report = fit_power_law(theta, pressure, p_max)
    except CalibrationFitError as exc:
        assert str(exc), 'CalibrationFitError without a message'
        event('fit: CalibrationFitError')
        return None
    check_fit_report(report, theta, pressure)
    event('fit: FitReport')
    return report
