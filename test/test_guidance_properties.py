"""Property-based tests of the guidance core beyond the power law: geometry (gaze straight up or
down, degenerate vectors, the wrap at +-180), the feedback law (repeated and jumping timestamps,
arbitrary inputs), the channel map, speech and Algorithm 1's procedure. The rule and the pinned
@examples are test_core_properties.py's; the strategies are shared (core_property_support.py).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, event, example, given, strategies as st

from fabric_guidance.core import speech
from fabric_guidance.core.calibration import DONE, FAILED, CalibrationProcedure
from fabric_guidance.core.channels import ChannelMap
from fabric_guidance.core.feedback import ADJUSTED, FIXED, MODES, FeedbackLaw, GuidanceController
from fabric_guidance.core.geometry import (
    DIRECTIONS, MIN_NORM, GeometryError, angles_between, target_direction, unity_to_ros_point,
    unity_to_ros_quaternion, wrap_deg,
)
from fabric_guidance.core.power_law import B_MAX, THETA_MAX, PowerLaw

from core_property_support import (  # noqa: E402,F401 (test/ is on sys.path; the fixture is autouse)
    assert_finite, assert_pressures_bounded, CHANNEL_MAP, circular_distance, clamp, FAST, finite,
    floating_point_errors_raise, law_or_none, moderate_vectors, non_degenerate, non_finite, non_finite_vectors,
    P_MAX, positive_finite, robust_norm, sane_laws, SLOW, unit_vectors, vectors, vertical_vectors, zero_length,
)


# ---------------------------------------------------------------------------------------------
# 7. gaze straight up or down
# ---------------------------------------------------------------------------------------------

@FAST
@given(vertical=vertical_vectors(), other=non_degenerate, vertical_first=st.booleans())
def test_angles_with_gaze_straight_up_or_down(vertical, other, vertical_first):
    """Case 7a: a gaze (or target) straight up or down has no horizontal projection: the angles
    are finite, horizontal_defined is False and horizontal is 0 (no twist is commanded)."""
    g, t = (vertical, other) if vertical_first else (other, vertical)
    ang = angles_between(g, t)
    assert ang.horizontal_defined is False
    assert ang.horizontal == 0.0
    assert math.isfinite(ang.vertical) and -180.0 <= ang.vertical <= 180.0
    assert_finite(ang.by_direction())


@FAST
@given(laws=st.lists(sane_laws, min_size=4, max_size=4), mode=st.sampled_from(MODES),
       g0=st.one_of(unit_vectors, vertical_vectors()), target=st.one_of(unit_vectors, vertical_vectors()),
       gazes=st.lists(st.one_of(vertical_vectors(), unit_vectors), min_size=1, max_size=10),
       dt=st.floats(0.0, 1.0))
def test_controller_with_gaze_straight_up_or_down(laws, mode, g0, target, gazes, dt):
    """Case 7b: GuidanceController.update with gazes straight up/down gives finite pressures
    within [0, p_max]."""
    ctl = GuidanceController(laws, P_MAX, mode=mode, estimator='sign', frame='target')
    ctl.begin(g0)
    for i, g in enumerate(gazes):
        out = ctl.update(g, target, i * dt)
        assert out.shape == (len(DIRECTIONS),)
        assert_pressures_bounded(out, P_MAX)
        assert_pressures_bounded(ctl.pressures, P_MAX)


# ---------------------------------------------------------------------------------------------
# 8. zero-length, NaN and inf vectors
# ---------------------------------------------------------------------------------------------

bad_vectors = st.one_of(zero_length, non_finite_vectors())


@FAST
@given(bad=bad_vectors, good=unit_vectors, bad_first=st.booleans())
def test_degenerate_vectors_in_angles_between(bad, good, bad_first):
    """Case 8a: zero-length or NaN/inf gaze or target -> GeometryError from angles_between."""
    args = (bad, good) if bad_first else (good, bad)
    with pytest.raises(GeometryError, match=r'.+'):
        angles_between(*args)


@FAST
@given(eye=moderate_vectors, offset=zero_length, bad=non_finite_vectors(), which=st.integers(0, 2))
def test_degenerate_vectors_in_target_direction(eye, offset, bad, which):
    """Case 8b: target at the eye (zero-length direction) or a NaN/inf eye or target -> GeometryError."""
    if which == 0:
        eye_arr = np.asarray(eye)
        args = (eye_arr, eye_arr + np.asarray(offset))
        assume(robust_norm(args[1] - args[0]) <= MIN_NORM)
    elif which == 1:
        args = (bad, eye)
    else:
        args = (eye, bad)
    with pytest.raises(GeometryError, match=r'.+'):
        target_direction(*args)


@FAST
@given(bad=non_finite_vectors(), ok=vectors, wrong_len=st.integers(0, 6).filter(lambda n: n != 3))
def test_non_finite_points_in_unity_to_ros_point(bad, ok, wrong_len):
    """Case 8c: a NaN/inf point (or one without 3 components) -> GeometryError; any finite point
    (the zero point is the origin, a valid point) converts to a finite point."""
    with pytest.raises(GeometryError, match=r'.+'):
        unity_to_ros_point(bad)
    with pytest.raises(GeometryError, match=r'.+'):
        unity_to_ros_point([0.0] * wrong_len)
    out = unity_to_ros_point(ok)
    assert_finite(out)
    assert sorted(np.abs(out)) == sorted(np.abs(ok))


@FAST
@given(zero=st.tuples(*[st.floats(-4e-10, 4e-10)] * 4), bad=non_finite_vectors(4),
       good=st.tuples(*[finite] * 4).filter(lambda q: robust_norm(q) > 10 * MIN_NORM))
@example(zero=(0.0,) * 4, bad=(math.nan, 0.0, 0.0, 1.0), good=(1e200, 1e200, 0.0, 0.0))
def test_degenerate_quaternions(zero, bad, good):
    """Case 8d: zero-length or NaN/inf quaternion -> GeometryError; any other finite one gives a
    finite unit quaternion with w >= 0 (a huge one is not silently the identity)."""
    for q in (zero, bad):
        with pytest.raises(GeometryError, match=r'.+'):
            unity_to_ros_quaternion(q)
    out = unity_to_ros_quaternion(good)
    assert_finite(out)
    assert math.isclose(float(np.linalg.norm(out)), 1.0, rel_tol=1e-9)
    assert out[3] >= 0.0
    # Same orientation as the quaternion scaled to a moderate length.
    ref = unity_to_ros_quaternion(tuple(np.asarray(good) / float(np.max(np.abs(good)))))
    assert min(np.max(np.abs(out - ref)), np.max(np.abs(out + ref))) <= 1e-9, (out, ref)


@FAST
@given(laws=st.lists(sane_laws, min_size=4, max_size=4), mode=st.sampled_from(MODES),
       g0=unit_vectors, target=unit_vectors, gazes=st.lists(unit_vectors, min_size=0, max_size=5),
       bad=bad_vectors, bad_t=non_finite, which=st.sampled_from(['gaze', 'target', 'time']),
       started=st.booleans())
def test_controller_rejects_degenerate_input_and_keeps_state(laws, mode, g0, target, gazes, bad, bad_t,
                                                             which, started):
    """Case 8e: GuidanceController.update with a zero-length/NaN/inf gaze or target, or a
    non-finite time, raises ValueError and leaves its pressures unchanged."""
    ctl = GuidanceController(laws, P_MAX, mode=mode, estimator='sign', frame='target')
    if started:
        ctl.begin(g0)
    for i, g in enumerate(gazes):
        ctl.update(g, target, float(i))
    before = ctl.pressures.copy()
    gaze, tgt, t = g0, target, float(len(gazes))
    if which == 'gaze':
        gaze = bad
    elif which == 'target':
        tgt = bad
    else:
        t = bad_t
    with pytest.raises(ValueError, match=r'.+'):
        ctl.update(gaze, tgt, t)
    np.testing.assert_array_equal(ctl.pressures, before)
    assert_pressures_bounded(ctl.pressures, P_MAX)


# ---------------------------------------------------------------------------------------------
# 9. dt = 0, repeated timestamps
# ---------------------------------------------------------------------------------------------

@st.composite
def samples_with_repeated_times(draw):
    n = draw(st.integers(1, 30))
    steps = draw(st.lists(st.one_of(st.just(0.0), st.floats(0.0, 1.0)), min_size=n, max_size=n))
    times = draw(st.floats(-1e6, 1e6)) + np.cumsum(steps)
    tt = draw(st.lists(st.one_of(st.floats(-180.0, 180.0), finite), min_size=n, max_size=n))
    th = draw(st.lists(st.one_of(st.floats(-180.0, 180.0), finite), min_size=n, max_size=n))
    return list(zip(tt, th, times.tolist()))


@FAST
@given(law=sane_laws, mode=st.sampled_from(MODES), gain=st.floats(0.0, 10.0),
       p_max=st.floats(1e-3, 1e4), samples=samples_with_repeated_times())
def test_feedback_repeated_timestamp_holds(law, mode, gain, p_max, samples):
    """Case 9: dt = 0 (a repeated timestamp) never divides by zero; while the law is active the
    sample leaves the output unchanged; the output always lies within [0, p_max]."""
    fb = FeedbackLaw(law, p_max, gain, mode, estimator='sign')
    prev = None
    for tt, th, t in samples:
        out = fb.step(tt, th, t)
        assert_pressures_bounded(out, p_max)
        if prev is not None and tt > 0 and prev[0] > 0 and t == prev[2]:
            assert out == prev[3], 'a repeated timestamp changed the output'
        prev = (tt, th, t, out)


# ---------------------------------------------------------------------------------------------
# 10. clocks that jump back
# ---------------------------------------------------------------------------------------------

@FAST
@given(law=sane_laws, mode=st.sampled_from(MODES), gain=st.floats(0.0, 10.0),
       samples=st.lists(st.tuples(st.floats(-10.0, 180.0), st.floats(-180.0, 180.0), finite), max_size=30),
       loops=st.integers(1, 3))
def test_feedback_clock_jumping_back(law, mode, gain, samples, loops):
    """Case 10: a replay loop (arbitrary times, going back too) keeps the output within
    [0, p_max], and a jump back produces no change of output at that sample."""
    fb = FeedbackLaw(law, P_MAX, gain, mode, estimator='sign')
    prev = None
    for tt, th, t in samples * loops:  # replaying the sequence jumps the clock back at each loop
        out = fb.step(tt, th, t)
        assert_pressures_bounded(out, P_MAX)
        if prev is not None and tt > 0 and prev[0] > 0 and t < prev[2]:
            assert out == prev[3], 'a clock jump back changed the output'
        prev = (tt, th, t, out)


# ---------------------------------------------------------------------------------------------
# 11. angle wrap at +-180
# ---------------------------------------------------------------------------------------------

@FAST
@given(x=finite, small=st.floats(-1e6, 1e6), k=st.integers(-1000, 1000), bad=non_finite)
@example(x=-180.0, small=180.0, k=1, bad=math.nan)
@example(x=540.0, small=-540.0, k=-1, bad=math.inf)
@example(x=-1e-300, small=-180.0, k=-1000, bad=-math.inf)
def test_wrap_deg(x, small, k, bad):
    """Case 11a: wrap_deg maps every finite angle into (-180, 180]; it is periodic in 360
    (wrap(x + 360k) == wrap(x) up to rounding); a non-finite angle is a GeometryError."""
    w = wrap_deg(x)
    assert math.isfinite(w) and -180.0 < w <= 180.0
    assert circular_distance(w, x) <= 1e-9 * max(1.0, abs(x)) or abs(x) > 1e15
    assert circular_distance(wrap_deg(small + 360.0 * k), wrap_deg(small)) <= 1e-6
    assert wrap_deg(w) == w
    with pytest.raises(GeometryError):
        wrap_deg(bad)


@FAST
@given(g=non_degenerate, t=non_degenerate)
@example(g=(-1.0, 1e-300, 0.0), t=(-1.0, -1e-300, 0.0))
@example(g=(-1.0, 0.0, 0.0), t=(-1.0, -0.0, 0.0))
@example(g=(1e308, -1e308, 1e308), t=(-1e-8, 0.0, 0.0))
def test_angles_between_ranges(g, t):
    """Case 11b: for arbitrary finite non-degenerate vectors the horizontal angle lies in
    (-180, 180] and the vertical angle in [-180, 180]."""
    ang = angles_between(g, t)
    assert math.isfinite(ang.horizontal) and -180.0 < ang.horizontal <= 180.0
    assert math.isfinite(ang.vertical) and -180.0 <= ang.vertical <= 180.0
    theta = ang.by_direction()
    assert_finite(theta)
    assert np.all(np.abs(theta) <= 180.0)


@FAST
@given(g=unit_vectors, t=unit_vectors, scale_g=st.floats(1e-6, 1e300), scale_t=st.floats(1e-6, 1e300))
# An earlier core silently turned a vector this long into a zero direction:
@example(g=(1.0, 0.0, 0.0), t=(0.0, 1.0, 0.0), scale_g=1e200, scale_t=1.0)
def test_angles_between_do_not_depend_on_length(g, t, scale_g, scale_t):
    """Case 11c: the angles do not depend on the length of finite vectors (no silent overflow
    of |v|^2 for huge vectors)."""
    ref = angles_between(g, t)
    big = angles_between(tuple(scale_g * np.asarray(g)), tuple(scale_t * np.asarray(t)))
    assert big.horizontal_defined == ref.horizontal_defined
    assert circular_distance(big.horizontal, ref.horizontal) <= 1e-6
    assert abs(big.vertical - ref.vertical) <= 1e-6


# ---------------------------------------------------------------------------------------------
# 12. the feedback law for arbitrary finite inputs
# ---------------------------------------------------------------------------------------------

@FAST
@given(law=sane_laws, mode=st.sampled_from(MODES), gain=st.floats(0.0, allow_infinity=False),
       p_max=positive_finite, deadband=st.floats(0.0, allow_infinity=False),
       samples=st.lists(st.tuples(finite, finite, finite), max_size=30))
@example(law=law_or_none((1e6, B_MAX, P_MAX)), mode=ADJUSTED, gain=1e308, p_max=P_MAX, deadband=0.0,
         samples=[(180.0, -1e308, 0.0), (180.0, -1e308, 5e-324), (1e308, 1e308, 1.0), (180.0, 0.0, 2.0)])
def test_feedback_arbitrary_finite_inputs_stay_bounded(law, mode, gain, p_max, deadband, samples):
    """Case 12a: for arbitrary finite (theta_target, theta, t) sequences, any gain >= 0, any
    p_max > 0 and either mode, the output always lies within [0, p_max]."""
    assume(law is not None)  # a pinned law the constructor now refuses
    fb = FeedbackLaw(law, p_max, gain, mode, deadband, estimator='sign')
    for sample in samples:
        out = fb.step(*sample)
        assert_pressures_bounded(out, p_max)
        assert fb.pressure == out


def _check_adjustment_direction(law, gain, p_max, samples):
    fb = FeedbackLaw(law, p_max, gain, ADJUSTED, estimator='sign')
    prev = None
    for tt, th, t in samples:
        out = fb.step(tt, th, t)
        assert_pressures_bounded(out, p_max)
        if prev is not None and tt > 0 and prev[0] > 0 and out != prev[1]:
            push = law.pressure(tt) - law.pressure(th)
            assert (out > prev[1]) == (push > 0), (
                f'pressure went {prev[1]} -> {out} although f(theta_t) - f(theta) = {push}')
        prev = (tt, out)


@FAST
@given(law=sane_laws, gain=st.floats(0.0, 1e3), p_max=st.floats(1e-3, 1e4),
       samples=st.lists(st.tuples(st.floats(-10.0, 180.0), st.floats(-180.0, 180.0), st.floats(-10.0, 1e3)),
                        max_size=30))
def test_feedback_adjustment_moves_toward_the_push(law, gain, p_max, samples):
    """Case 12d: in 'adjusted' mode a change of output always has the sign of
    f(theta_target) - f(theta) (Eq. 5's increment); bounds only stop it."""
    _check_adjustment_direction(law, gain, p_max, samples)


# Was a bug: an increment overflowing to +inf (gain 1e308) vented instead of saturating at p_max.
@SLOW
@given(law=sane_laws, gain=st.floats(0.0, allow_infinity=False), p_max=positive_finite,
       samples=st.lists(st.tuples(finite, finite, finite), max_size=30))
@example(law=law_or_none((1.0, 1.0, 0.0)), gain=1e308, p_max=P_MAX,
         samples=[(100.0, 0.0, 0.0), (100.0, -1.0, 1.0)])
def test_feedback_adjustment_moves_toward_the_push_any_gain(law, gain, p_max, samples):
    """Case 12e: as 12d for any finite gain >= 0 and any p_max > 0 (the constructor accepts them):
    an overflowing increment saturates, it does not reverse the adjustment."""
    assume(law is not None)
    _check_adjustment_direction(law, gain, p_max, samples)


@FAST
@given(law=sane_laws, gain=st.floats(0.0, allow_infinity=False), p_max=positive_finite,
       samples=st.lists(st.tuples(finite, finite, finite), max_size=30))
def test_feedback_fixed_mode_is_zero_or_f_of_target(law, gain, p_max, samples):
    """Case 12b: in 'fixed' mode the output is always 0 (target <= 0) or clamp(f(theta_target)),
    theta_target being the target at the (re)activation of the law: nothing ever adds to it."""
    fb = FeedbackLaw(law, p_max, gain, FIXED, estimator='sign')
    anchor = None
    for tt, th, t in samples:
        out = fb.step(tt, th, t)
        if tt <= 0:
            anchor = None
            assert out == 0.0
        else:
            if anchor is None:
                anchor = tt
            assert out == clamp(law.pressure(anchor), p_max)


@FAST
@given(law=sane_laws, gain=st.floats(0.0, 10.0), target=st.floats(0.0, 180.0, exclude_min=True),
       samples=st.lists(st.tuples(st.booleans(), finite, finite), max_size=30))
def test_feedback_fixed_mode_constant_target(law, gain, target, samples):
    """Case 12c: 'fixed' mode with one target (switched on and off): output in {0, clamp(f(target))}."""
    fb = FeedbackLaw(law, P_MAX, gain, FIXED, estimator='sign')
    allowed = {0.0, clamp(law.pressure(target), P_MAX)}
    for on, th, t in samples:
        assert fb.step(target if on else 0.0, th, t) in allowed


# ---------------------------------------------------------------------------------------------
# 13. channel map
# ---------------------------------------------------------------------------------------------

CMAP = ChannelMap.load(CHANNEL_MAP)


@FAST
@given(layout=st.sampled_from(CMAP.layouts), p_max=st.floats(1e-3, 1e4),
       fractions=st.tuples(*[st.floats(0.0, 1.0)] * 4))
def test_channel_map_in_range(layout, p_max, fractions):
    """Case 13: any in-range direction pressures map to channel pressures within [0, p_max];
    only the layout's channels are non-zero, each carrying its direction's pressure."""
    p = np.asarray(fractions) * p_max
    out = CMAP.to_channels(p, layout)
    assert out.shape == (len(CMAP.channels),)
    assert_pressures_bounded(out, p_max, 'channel pressure')
    owner = {ch: k for k, d in enumerate(DIRECTIONS) for ch in CMAP.channels_of(layout, d)}
    for name, value in zip(CMAP.channels, out):
        if name in owner:
            assert value == p[owner[name]]
        else:
            assert value == 0.0
    np.testing.assert_allclose(CMAP.to_directions(out, layout), p, rtol=1e-12)


# ---------------------------------------------------------------------------------------------
# 14. speech
# ---------------------------------------------------------------------------------------------

@FAST
@given(h=finite, v=finite, bad=non_finite, bad_first=st.booleans())
def test_speech_phrase(h, v, bad, bad_first):
    """Case 14: any finite angles give a non-empty phrase; a non-finite angle is a ValueError."""
    text = speech.phrase(h, v)
    assert isinstance(text, str) and text.strip()
    with pytest.raises(ValueError, match=r'.+'):
        speech.phrase(*((bad, v) if bad_first else (h, bad)))


# ---------------------------------------------------------------------------------------------
# 15. the calibration procedure (Algorithm 1) with random gaze sequences
# ---------------------------------------------------------------------------------------------

GAZE_PALETTE = [
    None, (math.nan, 0.0, 0.0), (0.0, math.inf, 0.0), (0.0, 0.0, 0.0), (1e-12, 0.0, 0.0),
    (0.0, 0.0, 1.0), (0.0, 0.0, -1.0), (1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 1.0, 0.0),
    (1e200, 0.0, 0.0), (1e308, 1e308, 0.0),
]
gaze_samples = st.one_of(st.sampled_from(GAZE_PALETTE), unit_vectors, vertical_vectors())
CAL_KW = dict(steps=3, dwell_s=1.0, rest_s=1.0, record_window_s=0.5)


def run_procedure(proc: CalibrationProcedure, ticks):
    """Drive the procedure; once the ticks run out keep ticking without gaze until it ends."""
    commands = []
    t = 0.0
    for t, gaze in ticks:
        commands.append(proc.tick(t, gaze))
        if proc.phase in (DONE, FAILED):
            break
    if not math.isfinite(t):
        t = 0.0
    for _ in range(1000):
        if proc.phase in (DONE, FAILED):
            break
        t += 0.25
        commands.append(proc.tick(t, None))
    return commands


def check_procedure_outcome(proc: CalibrationProcedure, commands) -> None:
    for cmd in commands:
        assert_pressures_bounded(cmd.pressure, proc.p_max, 'commanded pressure')
        assert math.isfinite(cmd.progress) and 0.0 <= cmd.progress <= 1.0
    assert proc.phase in (DONE, FAILED)
    event(f'procedure: {proc.phase}')
    if proc.phase == DONE:
        for law in proc.result().laws:
            for value in (law.a, law.b, law.c):
                assert math.isfinite(value)
            assert_finite(law.pressure(np.linspace(0.0, THETA_MAX, 19)))
    else:
        assert isinstance(proc.error, str) and proc.error


@st.composite
def gaze_ticks(draw):
    n = draw(st.integers(1, 90))
    dts = draw(st.lists(st.floats(0.0, 0.6), min_size=n, max_size=n))
    gazes = draw(st.lists(gaze_samples, min_size=n, max_size=n))
    times = np.cumsum(dts)
    jump = draw(st.one_of(st.none(), st.integers(0, n - 1)))
    if jump is not None:
        times[jump:] -= draw(st.floats(0.01, 100.0))
    if draw(st.booleans()):
        times[draw(st.integers(0, n - 1))] = draw(non_finite)
    return list(zip(times.tolist(), gazes))


_FWD, _BACK = (1.0, 0.0, 0.0), (-1.0, 0.0, 0.0)


@SLOW
@given(ticks=gaze_ticks())
# An earlier core raised GeometryError out of tick() here (rest-window mean g0 = 0):
@example(ticks=[(0.0, _FWD), (0.6, _FWD), (1.0, _BACK), (1.5, _FWD), (2.0, _FWD)])
def test_calibration_procedure_random_gaze(ticks):
    """Case 15a: Algorithm 1 driven with random gaze sequences (None, NaN, inf, zero-length,
    huge, straight up/down, opposite directions) and times (repeats, jumps back, non-finite)
    ends DONE with finite laws or FAILED with a non-empty reason; it never raises, and the
    commanded pressure always lies within [0, p_max]."""
    proc = CalibrationProcedure('prop', **CAL_KW)
    check_procedure_outcome(proc, run_procedure(proc, ticks))


def _rotate(direction: str, angle_deg: float) -> tuple[float, float, float]:
    a = math.radians(angle_deg)
    return {
        'left': (math.cos(a), math.sin(a), 0.0),
        'right': (math.cos(a), -math.sin(a), 0.0),
        'down': (math.cos(a), 0.0, -math.sin(a)),
        'up': (math.cos(a), 0.0, math.sin(a)),
    }[direction]


@SLOW
@given(a=st.floats(0.5, 50.0), b=st.floats(0.3, 3.0), c=st.floats(-50.0, 30.0),
       noise=st.lists(st.floats(-2.0, 2.0), min_size=1, max_size=50), limit=st.floats(30.0, 89.0))
@example(a=10.0, b=1.0, c=-200.0, noise=[0.0], limit=89.0)
def test_calibration_procedure_simulated_wearer(a, b, c, noise, limit):
    """Case 15b: Algorithm 1 with a simulated wearer (a power law, gaze noise, a range-of-motion
    limit) ends DONE with finite laws or FAILED with a reason; pressures stay within [0, p_max]."""
    wearer = PowerLaw(a, b, c)
    proc = CalibrationProcedure('sim', **CAL_KW)
    cmd = proc.tick(0.0, _FWD)
    commands = [cmd]
    t, i = 0.0, 0
    while proc.phase not in (DONE, FAILED) and i < 1000:
        t += 0.25
        if cmd.direction is None:
            gaze = _FWD
        else:
            angle = min(wearer.theta(cmd.pressure, proc.p_max), limit) + noise[i % len(noise)]
            gaze = _rotate(cmd.direction, angle)
        cmd = proc.tick(t, gaze)
        commands.append(cmd)
        i += 1
    check_procedure_outcome(proc, commands)
