"""Property-based tests of the power law and its fit: the hard cases of the design stay stable
(shared/design/ARCHITECTURE.md, "three things", item 2; the rest of the core in
test_guidance_properties.py).

The rule checked for every hard case: the output is finite and bounded (pressures within
[0, p_max], angles within their ranges), or the package's own clear exception is raised
(CalibrationFitError, GeometryError, or a ValueError the core raises with a message). Never a
NaN or inf slipping through, never an unrelated exception (TypeError, ZeroDivisionError,
OverflowError, LinAlgError, ...).

Each property pins, with @example, the inputs that broke (or nearly broke) an earlier version
of the core, so that a regression fails deterministically rather than by chance.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, example, given, strategies as st

from fabric_guidance.core.feedback import MODES, FeedbackLaw
from fabric_guidance.core.power_law import B_MAX, B_MIN, THETA_EPS, THETA_MAX, CalibrationFitError, fit_power_law

from core_property_support import (  # noqa: E402,F401 (test/ is on sys.path; the fixture is autouse)
    accepted_laws, angles_0_180, assert_finite, assert_pressures_bounded, calibration_pressures,
    check_law_functions, FAST, finite, fit_or_clear_error, FITS, floating_point_errors_raise, law_or_none, P_MAX,
    positive_finite, power_law_points, raw_coefficients, sane_laws, SLOW,
)


# ---------------------------------------------------------------------------------------------
# 1. theta near 0 with b < 1
# ---------------------------------------------------------------------------------------------

@FAST
@given(law=sane_laws.filter(lambda law: law.b < 1.0), theta=st.floats(0.0, 1e-3))
@example(law=law_or_none((1.0, B_MIN, 0.0)), theta=5e-324)
@example(law=law_or_none((1e6, 0.5, -P_MAX)), theta=0.0)
@example(law=law_or_none((1e-6, 0.999, P_MAX)), theta=1e-300)
def test_theta_near_zero_with_b_below_one(law, theta):
    """Case 1: theta near 0 with b < 1, where f'(theta) ~ theta**(b-1) blows up.

    pressure, slope, theta and inverse_slope stay finite and bounded; the slope is floored at
    THETA_EPS, so it is bounded as theta -> 0.
    """
    assume(law is not None)  # a pinned law the constructor now refuses
    p = law.pressure(theta)
    assert_finite(p)
    assert law.c <= p <= law.pressure(THETA_EPS) + 1e-12 * max(1.0, abs(law.c))

    slope = law.slope(theta)
    assert_finite(slope)
    bound = law.a * law.b * THETA_EPS ** (law.b - 1.0)
    assert 0.0 < slope <= bound * (1 + 1e-12)
    assert slope == law.slope(THETA_EPS) == law.slope(0.0)

    check_law_functions(law, theta, p)
    arr = law.slope(np.array([0.0, theta, THETA_EPS]))  # arrays behave as scalars do
    assert_finite(arr)
    assert np.all(arr <= bound * (1 + 1e-12))


# ---------------------------------------------------------------------------------------------
# 2. theta <= 0
# ---------------------------------------------------------------------------------------------

@FAST
@given(law=sane_laws, theta=st.floats(max_value=0.0, allow_nan=False))
def test_theta_nonpositive_gives_c(law, theta):
    """Case 2a: theta <= 0 (the wearer moved the other way, even -inf) maps to exactly c."""
    assert law.pressure(theta) == law.c
    assert_finite(law.slope(theta))


@FAST
@given(law=sane_laws, mode=st.sampled_from(MODES),
       history=st.lists(st.tuples(finite, finite, finite), max_size=10),
       theta_target=st.floats(max_value=0.0, allow_nan=False, allow_infinity=False),
       theta=finite, t=finite)
def test_feedback_zero_when_target_nonpositive(law, mode, history, theta_target, theta, t):
    """Case 2b: the feedback law commands exactly 0 when theta_target <= 0, whatever came before."""
    fb = FeedbackLaw(law, P_MAX, mode=mode, estimator='sign')
    for sample in history:
        fb.step(*sample)
    assert fb.step(theta_target, theta, t) == 0.0
    assert fb.pressure == 0.0


# ---------------------------------------------------------------------------------------------
# 3. pressure below c when inverting, above P_MAX, monotonic inverse
# ---------------------------------------------------------------------------------------------

@FAST
@given(law=sane_laws, p_max=st.floats(1e-3, 1e4), below=positive_finite, above=positive_finite,
       pressures=st.lists(finite, min_size=2, max_size=20))
@example(law=law_or_none((1.0, B_MIN, 0.0)), p_max=P_MAX, below=1.0, above=1.0, pressures=[0.0, 3.0, P_MAX])
def test_inverse_below_c_above_pmax_and_monotonic(law, p_max, below, above, pressures):
    """Case 3: inverting a pressure below c gives 0; above p_max it saturates at theta(p_max);
    the inverse is finite, within [0, THETA_MAX] and non-decreasing in pressure."""
    assume(law is not None)  # a pinned law the constructor now refuses
    p_low = law.c - below
    assume(p_low < law.c and math.isfinite(p_low))
    assert law.theta(p_low, p_max) == 0.0

    p_high = p_max + above
    assume(p_high > p_max and math.isfinite(p_high))
    at_limit = law.theta(p_max, p_max)
    assert_finite(at_limit)
    assert law.theta(p_high, p_max) == at_limit
    assert 0.0 <= at_limit <= THETA_MAX

    ps = np.sort(np.asarray(pressures, dtype=float))
    th = law.theta(ps, p_max)
    assert_finite(th, 'inverse')
    assert np.all((th >= 0.0) & (th <= THETA_MAX))
    assert np.all(np.diff(th) >= 0.0), (ps, th)
    inv_slope = law.inverse_slope(ps, p_max)
    assert_finite(inv_slope, 'inverse slope')
    assert np.all(inv_slope > 0.0)


# ---------------------------------------------------------------------------------------------
# 4. flat, non-monotonic and arbitrary calibration data
# ---------------------------------------------------------------------------------------------

@FITS
@given(pressure=calibration_pressures(), angle=finite)
def test_flat_calibration_data_is_rejected(pressure, angle):
    """Case 4a: flat data (the wearer reached the same angle at every step) -> CalibrationFitError."""
    with pytest.raises(CalibrationFitError, match=r'.+'):
        fit_power_law([angle] * len(pressure), pressure, P_MAX)


@FITS
@given(pressure=calibration_pressures(),
       angles=st.lists(st.floats(-1e6, 1e6), min_size=12, max_size=12, unique=True))
def test_non_monotonic_calibration_data_is_rejected(pressure, angles):
    """Case 4b: angles that decrease as the pressure rises -> CalibrationFitError."""
    theta = sorted(angles, reverse=True)[:len(pressure)]
    with pytest.raises(CalibrationFitError, match=r'.+'):
        fit_power_law(theta, pressure, P_MAX)


@FITS
@given(theta=st.lists(finite, min_size=0, max_size=12), pressure=st.lists(finite, min_size=0, max_size=12),
       p_max=finite)
def test_fit_fully_arbitrary_finite_data(theta, pressure, p_max):
    """Case 4c: completely arbitrary finite data (mismatched lengths, pressures out of range or
    not increasing, any p_max) -> a checked FitReport or CalibrationFitError."""
    fit_or_clear_error(theta, pressure, p_max)


@FITS
@given(pressure=calibration_pressures(), angles=st.lists(st.floats(-10.0, THETA_MAX), min_size=12, max_size=12))
# An earlier core raised OverflowError (math.exp of the log-exponent in the residuals) here:
@example(pressure=[10.0, 20.0, 30.0], angles=[10.0, 11.0, 12.0] + [0.0] * 9)
@example(pressure=[10.0, 101.25, 192.5, 283.75, 375.0], angles=[20.0, 21.0, 22.0, 23.0, 24.0] + [0.0] * 7)
@example(pressure=[10.0, 20.0, 30.0], angles=[1e-100, 2e-100, 3e-100] + [0.0] * 9)
# ... and a bare ValueError from the initial guess (a0 underflowing to 0) here:
@example(pressure=[0.0, 5e-324, 1e-323], angles=[0.0, 0.001, 170.0] + [0.0] * 9)
# ... and an overflow in the solver's products (u^b of the scaled model) at angles 1e149 apart:
@example(pressure=[0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 27.0],
         angles=[0.0] * 6 + [1.0, 5.004149548174021e-150, 5.004149548174021e-150] + [0.0] * 3)
@example(pressure=[0.0, 1.0, 2.0, 3.0, 4.0, 5.0], angles=[0.0, 1e-200, 1e-150, 1e-100, 1.0, 2.0] + [0.0] * 6)
def test_fit_arbitrary_data_in_the_valid_ranges(pressure, angles):
    """Case 4d: arbitrary angles within the model's range at valid, increasing pressures
    -> a FitReport with finite coefficients, finite RMSE and residuals that match an independent
    evaluation of a*max(theta,0)**b + c, or CalibrationFitError."""
    fit_or_clear_error(angles[:len(pressure)], pressure)


# ---------------------------------------------------------------------------------------------
# 5. outliers
# ---------------------------------------------------------------------------------------------

@FITS
@given(points=power_law_points(), index=st.integers(0, 11),
       outlier=st.one_of(finite, st.floats(-10.0, THETA_MAX)))
@example(points=(np.linspace(37.5, P_MAX, 10), np.linspace(9.0, 90.0, 10)), index=0, outlier=179.0)
@example(points=(np.linspace(37.5, P_MAX, 10), np.linspace(9.0, 90.0, 10)), index=9, outlier=1e-300)
def test_fit_with_one_wild_outlier(points, index, outlier):
    """Case 5: power-law data with one wild outlier -> finite coefficients or CalibrationFitError."""
    p, theta = points
    theta = theta.copy()
    theta[index % len(theta)] = outlier
    fit_or_clear_error(theta, p)


# ---------------------------------------------------------------------------------------------
# 6. overflow of theta^b
# ---------------------------------------------------------------------------------------------

@FAST
@given(law=sane_laws.filter(lambda law: law.b >= 1.0), theta=angles_0_180, pressure=finite)
@example(law=law_or_none((1e6, B_MAX, P_MAX)), theta=THETA_MAX, pressure=1e308)
@example(law=law_or_none((1e-6, B_MAX, -P_MAX)), theta=THETA_MAX, pressure=-1e308)
def test_large_exponent_stays_finite_up_to_180(law, theta, pressure):
    """Case 6a: large b (up to B_MAX) and theta up to 180 deg: theta**b does not overflow;
    pressure, slope, inverse and inverse slope are finite (also for angles beyond 180)."""
    assume(law is not None)  # a pinned law the constructor now refuses
    for th in (theta, THETA_MAX, 1e308, math.inf):
        check_law_functions(law, th, pressure)
    assert law.pressure(1e308) == law.pressure(THETA_MAX)


@FAST
@given(abc=raw_coefficients, theta=angles_0_180)
# An earlier core accepted this law, whose f is inf at 180 deg:
@example(abc=(1e300, 5.0, 0.0), theta=THETA_MAX)
@example(abc=(1.0, B_MAX, 1.7e308), theta=THETA_MAX)
def test_any_accepted_law_pressure_finite_up_to_180(abc, theta):
    """Case 6b: every law the constructor accepts (e.g. read from a calibration file) has a
    finite f for every angle up to 180 deg; coefficients that would overflow are refused with
    a clear ValueError."""
    law = law_or_none(abc)
    if law is not None:
        assert_finite(law.pressure(theta), f'{law}.pressure({theta})')
        assert_finite(law.pressure(THETA_MAX), f'{law}.pressure(180)')


# Was a bug: PowerLaw(5e-324, 1, 0).inverse_slope(0, 375) == inf; now a >= A_MIN and the slope is capped.
@SLOW
@given(abc=raw_coefficients, theta=angles_0_180, pressure=finite)
@example(abc=(5e-324, 1.0, 0.0), theta=0.0, pressure=0.0)
# the law fit_power_law([0, 0.001, 170], [0, 5e-324, 1e-323], 375) returns:
@example(abc=(1.14e-322, 0.5851649573199212, 5e-324), theta=0.0, pressure=0.0)
def test_any_accepted_law_all_functions_finite(abc, theta, pressure):
    """Case 6c: pressure, slope, theta and inverse_slope of every accepted law are finite."""
    law = law_or_none(abc)
    if law is not None:
        check_law_functions(law, theta, pressure)


@FAST
@given(law=accepted_laws, gain=st.floats(0.0, 10.0),
       samples=st.lists(st.tuples(angles_0_180, angles_0_180, finite), min_size=1, max_size=8))
# An earlier core accepted (1e300, 5, 0) and output NaN (G * (inf - inf)); the largest f now:
@example(law=law_or_none((1e240, 5.0, 0.0)), gain=0.05, samples=[(170.0, 175.0, 0.0), (170.0, 174.0, 1.0)])
def test_feedback_with_any_accepted_law_stays_bounded(law, gain, samples):
    """Case 6d: the feedback law stays within [0, p_max] for every law the constructor accepts."""
    assume(law is not None)  # a pinned law the constructor now refuses
    fb = FeedbackLaw(law, P_MAX, gain, estimator='sign')
    for sample in samples:
        assert_pressures_bounded(fb.step(*sample), P_MAX)


@FITS
@given(points=power_law_points(b_range=(3.0, B_MAX)))
@example(points=(np.linspace(37.5, P_MAX, 10), 90.0 * (np.linspace(37.5, P_MAX, 10) / P_MAX) ** (1 / 8.0)))
@example(points=(np.linspace(37.5, P_MAX, 10), 180.0 * (np.linspace(37.5, P_MAX, 10) / P_MAX) ** (1 / B_MAX)))
def test_fit_data_with_large_exponents(points):
    """Case 6e: fit data generated with large exponents (b in [3, 20]) -> a FitReport whose law
    is finite at every angle up to 180 deg, or CalibrationFitError."""
    fit_or_clear_error(*reversed(points))


@FITS
@given(points=power_law_points(b_range=(0.2, 3.0)))
def test_fit_exact_power_law_data(points):
    """Case 6f: exact data from moderate power laws -> a checked FitReport or CalibrationFitError."""
    fit_or_clear_error(*reversed(points))
