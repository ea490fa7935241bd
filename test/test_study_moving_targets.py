"""The moving-target study in simulation (experiments/discussion/moving_targets.py) on the loop built as the node
builds it (sim/node_loop.py): the target's motion, the static case as the engine's, and the law
stepped as GuidanceController.update does."""
import numpy as np
import pytest

from fabric_guidance.core.feedback import GuidanceController
from fabric_guidance.sim.engine import ClosedLoop, gaze_from_angles
from fabric_guidance.experiments.discussion.moving_targets import LAWS, TargetMotion, moving_trial
from fabric_guidance.sim.node_loop import NodeLoop
from fabric_guidance.experiments.discussion.trials import TrialKey

from study_scenes import short, wearer_and_cal


def test_target_motion_moves_at_its_speed_and_stays_in_the_range():
    m = TargetMotion(10.0, -5.0, 20.0, 0.0, 60.0, 30.0)
    assert m.at(0.0) == (10.0, -5.0)
    assert m.at(1.0) == pytest.approx((30.0, -5.0))
    assert m.at(3.0) == pytest.approx((50.0, -5.0))     # 70 reflected at 60
    up = TargetMotion(0.0, 0.0, 10.0, 90.0, 60.0, 30.0)
    assert up.at(1.0) == pytest.approx((0.0, 10.0))
    for s in np.linspace(0.0, 60.0, 601):
        y, p = TargetMotion(-40.0, 20.0, 20.0, 33.0, 60.0, 30.0).at(float(s))
        assert -60.0 - 1e-9 <= y <= 60.0 + 1e-9 and -30.0 - 1e-9 <= p <= 30.0 + 1e-9


@pytest.mark.parametrize('seen', [True, False])
def test_with_a_static_target_follow_target_and_the_papers_law_give_identical_runs(seen):
    sc = short(exact=False)                        # every effect: noise, loss, latency, lags
    w, cal = wearer_and_cal(sc, 3)
    for r in range(3):
        key = TrialKey('moving', r)
        runs = [moving_trial(sc, w, cal, law, 0.0, key, duration_s=6.0, seen=seen) for law in LAWS]
        assert runs[0] == runs[1] == runs[2]


def test_with_a_static_target_the_loops_pressure_trace_is_the_engines():
    sc = short(exact=False)
    w, cal = wearer_and_cal(sc, 4)
    loops = [ClosedLoop(sc, w, (12, 1, 0), 1, cal), NodeLoop(sc, w, (12, 1, 0), 1, cal),
             NodeLoop(sc, w, (12, 1, 0), 1, cal, follow_target=True)]
    traces = []
    for loop in loops:
        loop.warm_up()
        loop.present(-35.0, 12.0, visible=False)
        trace = []
        for _ in range(300):
            loop.step()
            trace.append((tuple(loop.command), loop.wearer.gaze_yaw, loop.wearer.gaze_pitch))
        traces.append(trace)
    assert traces[0] == traces[1] == traces[2]


class FrozenWearerLoop(NodeLoop):
    """The wearer holds still whatever they feel."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.wearer.feel = lambda p: None
        self.wearer.move = lambda capture=None: None


@pytest.mark.parametrize('end_yaw', [35.0, 10.0])       # the target moves away, or toward the wearer
def test_a_moving_target_changes_the_pressure_with_follow_target_while_the_wearer_holds_still(end_yaw):
    sc = short('ideal')
    w, cal = wearer_and_cal(sc)
    left = cal.laws[0]
    out = {}
    for law in LAWS:
        loop = FrozenWearerLoop(sc, w, (12, 1, 0), 1, cal, follow_target=law == 'follow',
                                live_target=law != 'paper')
        loop.warm_up()
        loop.present(20.0, 0.0, visible=False)
        for _ in range(30):                       # static: 0.5 s
            loop.step()
        assert loop.controller.pressures[0] == pytest.approx(left.pressure(20.0))
        assert loop.wearer.gaze_yaw == 0.0
        before = loop.controller.pressures.copy()
        # The target moves to end_yaw in 0.5 s: 30 deg/s, above the filtered estimator's
        # threshold (core.feedback.RATE_THRESHOLD_DPS, 14.6 deg/s).
        for i in range(1, 31):
            loop.move_target(20.0 + (end_yaw - 20.0) * i / 30, 0.0)
            loop.step()
        for _ in range(30):
            loop.step()
        assert loop.wearer.gaze_yaw == 0.0
        out[law] = (before, loop.controller.pressures.copy(), list(loop.command))
    before, after, command = out['paper']
    np.testing.assert_array_equal(after, before)              # the paper's law: theta_t taken once
    before, after, command = out['follow']
    shift = left.pressure(end_yaw) - left.pressure(20.0)
    if end_yaw > 20.0:
        # The feed-forward follows, and Eq. 5 adds on top as the error grows (up to P_MAX).
        assert after[0] - before[0] >= min(shift, cal.p_max - before[0]) - 1e-9
        # Eq. 5 alone on the live target (no shift) adds too: the error grows.
        assert out['live'][1][0] > out['live'][0][0]
    else:
        # The error shrinks, so Eq. 5 adds nothing: the pressure is f(theta_t) of the new place.
        assert after[0] == pytest.approx(left.pressure(end_yaw))
        np.testing.assert_array_equal(out['live'][1], out['live'][0])
    assert command[0] == pytest.approx(after[0])               # and the suit is commanded so


class CheckedLoop(NodeLoop):
    """Checks every control step against core GuidanceController.update on the same inputs."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        cal = args[4]
        self.reference = GuidanceController(cal.laws, p_max=min(self.p_max, cal.p_max), gain=self.gain,
                                            mode=self.cond.mode, follow_target=self.follow_target,
                                            rest_gaze=cal.origin)
        self.checked = 0

    def _control(self, t):
        fresh = t - self.received_t <= self.timeout
        super()._control(t)
        if self.target is None or not fresh:
            self.reference.vent()
            return
        ref = self.reference.update(gaze_from_angles(self.last_sample[2], self.last_sample[3]),
                                    gaze_from_angles(*self.target), t)
        np.testing.assert_allclose(self.controller.pressures, ref, rtol=1e-9, atol=1e-7)
        self.checked += 1


@pytest.mark.parametrize('follow', [False, True])
def test_the_live_target_loop_steps_the_law_as_guidance_controller_update_does(follow):
    sc = short(exact=False)
    w, cal = wearer_and_cal(sc, 5)
    loop = CheckedLoop(sc, w, (12, 1, 0), 1, cal, follow_target=follow, live_target=True)
    loop.warm_up()
    motion = TargetMotion(-30.0, 10.0, 20.0, 200.0, 60.0, 30.0)   # crosses the start: directions swap
    loop.present(*motion.at(0.0), visible=False)
    t0 = loop.t
    for _ in range(600):
        loop.step()
        loop.move_target(*motion.at(loop.t - t0))
    assert loop.checked > 250
