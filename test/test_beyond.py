"""Beyond the paper in simulation: a per-wearer gain (sim/per_wearer_gain.py) and moving targets
(sim/moving_targets.py) on the loop built as the node builds it (sim/node_loop.py), both run
together (sim/discussion_studies.py), and the `beyond` command (experiments/beyond.py)."""
from dataclasses import replace
import math

import numpy as np
import pandas as pd
import pytest

from fabric_guidance.core.feedback import GuidanceController
from fabric_guidance.experiments import beyond as beyond_cmd
from fabric_guidance.sim import protocols
from fabric_guidance.sim.discussion_studies import StudySettings, run_studies
from fabric_guidance.sim.moving_targets import LAWS, TargetMotion, moving_trial
from fabric_guidance.sim.node_loop import NodeLoop
from fabric_guidance.sim.per_wearer_gain import GAIN_GRID, choose_gain, speed_trial, tune_gain
from fabric_guidance.sim.study_trials import TrialKey, evaluation_keys, tuning_keys
from fabric_guidance.sim.engine import ClosedLoop, gaze_from_angles, trial_run
from fabric_guidance.sim.population import calibrate_wearer, sample_wearer
from fabric_guidance.sim.scene import load_scene


def short(name='paper-speed', trial_s=10.0, exact=True):
    """A scene with shorter trials and (by default) the wearer's true laws as calibration."""
    sc = load_scene(name)
    return sc.replace(protocol=replace(sc.protocol, trial_s=trial_s),
                      calibration=replace(sc.calibration, exact=exact))


def wearer_and_cal(sc, index=0):
    w = sample_wearer(sc, index)
    return w, calibrate_wearer(sc, w).calibration


# ---- 1. the per-wearer gain -------------------------------------------------------------------

def test_choose_gain_takes_most_identified_then_faster_then_nearest_the_papers():
    assert choose_gain({0.0: (20.0, 1.0), 0.2: (21.0, 3.0), 0.5: (20.5, 0.5)}) == 0.2
    assert choose_gain({0.0: (20.0, 2.0), 0.2: (20.0, 1.5), 0.5: (20.0, 1.6)}) == 0.2
    assert choose_gain({0.0: (20.0, 1.0), 0.05: (20.0, 1.0), 0.1: (20.0, 1.0)}) == 0.05
    assert choose_gain({0.0: (20.0, 1.0), 0.1: (20.0, 1.0)}) == 0.0      # equally near 0.05: the smaller
    assert choose_gain({0.3: (0.0, math.inf), 0.4: (0.0, math.inf)}) == 0.3
    with pytest.raises(ValueError):
        choose_gain({})


def test_tuning_picks_a_gain_from_the_grid_and_is_deterministic():
    sc = short()
    w, cal = wearer_and_cal(sc, 1)
    grid = (0.0, 0.05, 0.3, 0.5)
    g1, rows1 = tune_gain(sc, w, cal, grid, reps=2)
    g2, rows2 = tune_gain(sc, w, cal, grid, reps=2)
    assert g1 in grid and g1 == g2 and rows1 == rows2
    assert sorted({r['gain'] for r in rows1}) == list(grid) and len(rows1) == 2 * len(grid)
    assert all(r['phase'] == 'tuning' for r in rows1)
    # The choice is the rule applied to those trials.
    means = {}
    for g in grid:
        rs = [r for r in rows1 if r['gain'] == g]
        finds = [r['mean_find_s'] for r in rs if r['mean_find_s'] is not None]
        means[g] = (np.mean([r['identified'] for r in rs]), np.mean(finds) if finds else math.inf)
    assert g1 == choose_gain(means)
    assert GAIN_GRID[0] == 0.0 and GAIN_GRID[-1] == 0.5 and 0.05 in GAIN_GRID and len(GAIN_GRID) == 11


def test_tuning_and_evaluation_trials_use_disjoint_seeds():
    sc = short()
    tune, ev = tuning_keys(6), evaluation_keys(6)
    assert not {k.run for k in tune} & {k.run for k in ev}
    assert not {k.target_stream for k in tune} & {k.target_stream for k in ev}
    moving = [TrialKey('moving', r) for r in range(6)]
    assert not {k.run for k in moving} & ({k.run for k in tune} | {k.run for k in ev})
    # Different targets, not just different keys.
    for r in range(6):
        a = protocols.draw_target(tune[r].targets(sc, 0), sc.protocol)
        b = protocols.draw_target(ev[r].targets(sc, 0), sc.protocol)
        assert a != b
    # The evaluation trials are the protocol's own condition-1 trials.
    assert [k.run for k in ev] == [trial_run(1, r) for r in range(6)]


def test_at_the_papers_gain_the_evaluation_trial_is_the_protocols_condition_1_trial():
    sc = short(exact=False)                        # Algorithm 1 and every effect
    w, cal = wearer_and_cal(sc, 2)
    expected = protocols.speed_trial(sc, w, cal, 1, 1)
    assert speed_trial(sc, w, cal, TrialKey('evaluation', 1)) == expected
    assert speed_trial(sc, w, cal, TrialKey('evaluation', 1), gain=sc.controller.gain) == expected
    assert speed_trial(sc, w, cal, TrialKey('tuning', 1)) != expected


def test_the_wearers_own_gain_reaches_the_controller_only_with_use_wearer_gain():
    sc = short()
    w, cal = wearer_and_cal(sc)
    own = cal.with_gain(0.3)
    assert {d.gain for d in NodeLoop(sc, w, (9,), 1, own, use_wearer_gain=True).controller.directions} == {0.3}
    assert {d.gain for d in NodeLoop(sc, w, (9,), 1, own).controller.directions} == {0.05}
    assert {d.gain for d in NodeLoop(sc, w, (9,), 1, cal, use_wearer_gain=True).controller.directions} == {0.05}


# ---- 2. moving targets ------------------------------------------------------------------------

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


# ---- the whole study and the command ----------------------------------------------------------

TINY = StudySettings(grid=(0.05, 0.3), tuning_reps=1, evaluation_reps=1, speeds_dps=(20.0,), moving_reps=1,
                      moving_s=4.0)


def test_the_study_is_deterministic_for_any_number_of_workers():
    sc = short(trial_s=8.0)
    a = run_studies(sc, 2, TINY, workers=1)
    b = run_studies(sc, 2, TINY, workers=2)
    pd.testing.assert_frame_equal(a.gain_grid_frame(), b.gain_grid_frame())
    pd.testing.assert_frame_equal(a.moving_frame(), b.moving_frame())
    assert [w.tuned_gain for w in a.wearers] == [w.tuned_gain for w in b.wearers]
    ev = a.gain_trials_frame()
    assert set(ev['condition']) == {'paper', 'own', 'oracle'} and set(ev['phase']) == {'evaluation'}


def test_beyond_quick_writes_the_report_csvs_and_pngs(tmp_path, capsys):
    out = tmp_path / 'beyond'
    assert beyond_cmd.main(['--out', str(out), '--quick']) == 0
    printed = capsys.readouterr().out
    assert 'Per-wearer gain' in printed and 'Moving target' in printed and 'report:' in printed
    report = (out / 'beyond.md').read_text()
    for heading in ('## Summary', '## 1. Per-wearer adjustment gain', '## 2. Moving targets', 'Friedman test',
                    'Dunn-Bonferroni'):
        assert heading in report
    pngs = sorted(p.name for p in out.glob('*.png'))
    assert 'gain_identified.png' in pngs and len(pngs) == 1 + 2 * 2 * 2     # 2 scenarios x 2 speeds x 2 measures
    for name in pngs:
        assert f']({name})' in report and (out / name).read_bytes()[:4] == b'\x89PNG'
    grid = pd.read_csv(out / 'gain_grid.csv')
    assert set(grid['phase']) == {'tuning', 'evaluation'} and grid['subject'].nunique() == 3
    moving = pd.read_csv(out / 'moving_trials.csv')
    assert set(moving['law']) == set(LAWS) and set(moving['scenario']) == {'seen', 'unseen'}
    assert {'find_s', 'tracking_error_deg', 'late_error_deg', 'found'} <= set(moving.columns)
    choice = pd.read_csv(out / 'gain_choice.csv')
    assert len(choice) == 3 and set(choice['tuned_gain']) <= {0.0, 0.05, 0.2, 0.5}
    assert not pd.read_csv(out / 'gain_trials.csv').empty


def test_beyond_refuses_a_non_speed_scene_and_too_few_wearers(tmp_path, capsys):
    assert beyond_cmd.main(['--out', str(tmp_path), '--scene', 'paper-accuracy', '--quick']) == 2
    assert beyond_cmd.main(['--out', str(tmp_path), '--subjects', '1', '--quick']) == 2
    err = capsys.readouterr().err
    assert 'speed scene' in err and '--subjects' in err
