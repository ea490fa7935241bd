"""Eq. 5, worked by hand with f(theta) = 2*theta**0.5 + 10: f(0) = 10, f(4) = 14, f(9) = 16,
f(16) = 18; G = 0.5 so that each increment is easy to follow."""
import math

import numpy as np
import pytest

from fabric_guidance.core.feedback import FeedbackLaw, GuidanceController
from fabric_guidance.core.power_law import PowerLaw

LAW = PowerLaw(2.0, 0.5, 10.0)


def law(mode='adjusted', p_max=100.0, gain=0.5):
    return FeedbackLaw(LAW, p_max=p_max, gain=gain, mode=mode, estimator='sign')


def test_starts_at_f_of_target():
    fb = law()
    assert fb.step(16.0, 0.0, 0.0) == 18.0                 # P = f(theta_t)


def test_adds_only_while_the_error_grows_and_holds_while_it_shrinks():
    fb = law()
    assert fb.step(16.0, 0.0, 0.0) == 18.0                 # e = 16
    assert fb.step(16.0, -2.0, 1.0) == 22.0                # e = 18 grows: + 0.5*(f(16) - f(-2)) = +4
    assert fb.step(16.0, 4.0, 2.0) == 22.0                 # e = 12 shrinks: hold
    assert fb.step(16.0, 0.0, 3.0) == 26.0                 # e = 16 grows: + 0.5*(18 - 10) = +4
    assert fb.step(16.0, 9.0, 4.0) == 26.0                 # e = 7 shrinks: hold
    assert fb.step(16.0, 4.0, 5.0) == 28.0                 # e = 12 grows: + 0.5*(18 - 14) = +2
    assert fb.step(16.0, 4.0, 6.0) == 28.0                 # e unchanged: de/dt = 0 is not "grows"


def test_increment_uses_f_of_the_current_angle():
    # Literal Eq. 5 past the target: theta 22 -> 20 makes e = -6 -> -4 grow, and the increment
    # G*(f(16) - f(20)) is negative, so the pressure eases off.
    fb = law()
    fb.step(16.0, 22.0, 0.0)
    p = fb.step(16.0, 20.0, 1.0)
    assert p == pytest.approx(18.0 + 0.5 * (18.0 - (2.0 * math.sqrt(20.0) + 10.0)))


def test_zero_when_target_angle_not_positive_then_restarts():
    fb = law()
    fb.step(16.0, 0.0, 0.0)
    fb.step(16.0, -2.0, 1.0)
    assert fb.pressure == 22.0
    assert fb.step(0.0, 5.0, 2.0) == 0.0                   # theta_t <= 0: this direction is not needed
    assert fb.step(-3.0, 5.0, 3.0) == 0.0
    assert fb.step(16.0, 0.0, 4.0) == 18.0                 # starts again from f(theta_t)


def test_fixed_mode_holds_f_of_target():
    fb = law(mode='fixed')
    for theta, t in [(0.0, 0.0), (-2.0, 1.0), (-5.0, 2.0), (-9.0, 3.0)]:
        assert fb.step(16.0, theta, t) == 18.0


def test_clamped_to_p_max_without_wind_up():
    fb = law(p_max=20.0)
    assert fb.step(16.0, 0.0, 0.0) == 18.0
    assert fb.step(16.0, -2.0, 1.0) == 20.0                # 22 clamps to P_MAX
    assert fb.step(16.0, -4.0, 2.0) == 20.0
    assert fb.pressure == 20.0                             # the state is clamped too: no hidden 26
    assert fb.step(16.0, 16.0, 3.0) == 20.0
    assert law(p_max=15.0).step(16.0, 0.0, 0.0) == 15.0    # f(theta_t) itself above P_MAX


def test_repeated_timestamp_holds():
    fb = law()
    fb.step(16.0, 0.0, 1.0)
    assert fb.step(16.0, -50.0, 1.0) == 18.0               # dt = 0: no derivative, no jump
    assert fb.step(16.0, -2.0, 2.0) == 22.0                # still measured against the sample at t = 1


def test_clock_jump_back_restarts_the_derivative():
    fb = law()
    fb.step(16.0, 0.0, 10.0)
    fb.step(16.0, -2.0, 11.0)
    assert fb.pressure == 22.0
    assert fb.step(16.0, -30.0, 0.5) == 22.0               # replay loop: no step at the jump
    assert fb.step(16.0, -31.0, 0.6) == 26.0               # then e grows 46 -> 47 against the new reference


def test_non_finite_input_raises_and_keeps_state():
    fb = law()
    fb.step(16.0, 0.0, 0.0)
    for args in [(float('nan'), 0.0, 1.0), (16.0, float('inf'), 1.0), (16.0, 0.0, float('nan'))]:
        with pytest.raises(ValueError, match='not finite'):
            fb.step(*args)
    assert fb.pressure == 18.0


def test_rate_deadband():
    fb = FeedbackLaw(LAW, p_max=100.0, gain=0.5, rate_deadband_dps=3.0, estimator='sign')
    fb.step(16.0, 0.0, 0.0)
    assert fb.step(16.0, -2.0, 1.0) == 18.0                # de/dt = 2 deg/s is inside the deadband
    assert fb.step(16.0, -6.0, 2.0) == 22.0                # 4 deg/s is not


def test_parameters_are_validated():
    with pytest.raises(ValueError, match='mode'):
        FeedbackLaw(LAW, mode='adaptive')
    with pytest.raises(ValueError, match='gain'):
        FeedbackLaw(LAW, gain=-0.1)
    with pytest.raises(ValueError, match='p_max'):
        FeedbackLaw(LAW, p_max=float('nan'))


def yawed(deg, pitch=0.0):
    y, p = math.radians(deg), math.radians(pitch)
    return [math.cos(p) * math.cos(y), math.cos(p) * math.sin(y), math.sin(p)]


def test_controller_four_directions_from_gaze():
    ctl = GuidanceController([LAW] * 4, p_max=100.0, gain=0.5, estimator='sign', frame='target')
    target = yawed(16.0)                                   # 16 deg to the left, level
    np.testing.assert_allclose(ctl.update(yawed(0.0), target, 0.0), [18.0, 0.0, 0.0, 0.0])
    # The wearer turns 2 deg right (away): the left direction's error grows.
    np.testing.assert_allclose(ctl.update(yawed(-2.0), target, 1.0), [22.0, 0.0, 0.0, 0.0])
    # A target up and to the right drives right twist and backward bend (up).
    ctl.begin(yawed(0.0))
    p = ctl.update(yawed(0.0), yawed(-9.0, 4.0), 2.0)
    assert p[0] == 0.0 and p[2] == 0.0
    assert p[1] == pytest.approx(LAW.pressure(9.0), rel=1e-3)  # horizontal at 4 deg pitch is still 9 deg
    assert p[3] == pytest.approx(14.0)
    np.testing.assert_array_equal(ctl.vent(), np.zeros(4))


def test_controller_angles_are_measured_from_the_initial_gaze():
    ctl = GuidanceController([LAW] * 4, p_max=100.0, gain=0.5, estimator='sign', frame='target')
    ctl.begin(yawed(0.0))
    target = yawed(16.0)
    ctl.update(yawed(0.0), target, 0.0)
    # Halfway there (theta = 9, e = 7): holds f(16) rather than restarting at f(7).
    assert ctl.update(yawed(9.0), target, 1.0)[0] == 18.0


def test_controller_rejects_invalid_gaze_and_keeps_state():
    ctl = GuidanceController([LAW] * 4, p_max=100.0, gain=0.5, estimator='sign', frame='target')
    ctl.update(yawed(0.0), yawed(16.0), 0.0)
    with pytest.raises(ValueError):
        ctl.update([0.0, 0.0, 0.0], yawed(16.0), 1.0)
    with pytest.raises(ValueError):
        ctl.update([float('nan'), 0.0, 1.0], yawed(16.0), 1.0)
    np.testing.assert_allclose(ctl.pressures, [18.0, 0.0, 0.0, 0.0])


def test_per_direction_gain():
    ctl = GuidanceController([LAW] * 4, p_max=100.0, gain=[0.5, 0.0, 0.0, 0.0], estimator='sign',
                             frame='target')
    ctl.update(yawed(0.0), yawed(16.0), 0.0)
    assert ctl.update(yawed(-2.0), yawed(16.0), 1.0)[0] == 22.0
    with pytest.raises(ValueError, match='one gain per direction'):
        GuidanceController([LAW] * 4, gain=[0.1, 0.2])


def test_paper_law_ignores_a_moving_target_after_the_start():
    fb = law()
    fb.step(16.0, 0.0, 0.0)
    assert fb.step(9.0, 0.0, 1.0) == 18.0     # e = 9 shrinks: hold; theta_t only set the start


def test_follow_target_shifts_the_feed_forward_and_keeps_the_adjustment():
    fb = FeedbackLaw(LAW, p_max=100.0, gain=0.5, follow_target=True, estimator='sign')
    assert fb.step(16.0, 0.0, 0.0) == 18.0
    assert fb.step(16.0, -2.0, 1.0) == 22.0    # Eq. 5 adds 4
    # The target moves from 16 to 9 deg while the wearer holds at -2: shift f(9) - f(16) = -2,
    # then e = 11 shrank from 18: hold.
    assert fb.step(9.0, -2.0, 2.0) == 20.0
    # It moves on to 4 deg: shift f(4) - f(9) = -2 again; e = 6 shrinks.
    assert fb.step(4.0, -2.0, 3.0) == 18.0
    # Crossing to the other side resets this direction (the other one takes over).
    assert fb.step(-1.0, -2.0, 4.0) == 0.0
