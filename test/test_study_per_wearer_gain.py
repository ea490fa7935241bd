"""The per-wearer gain study in simulation (experiments/discussion/per_wearer_gain.py): the choice of G, the
tuning and its seeds, the evaluation trials as the protocol's, the gain reaching the controller."""
import math

import numpy as np
import pytest

from fabric_guidance.sim import protocols
from fabric_guidance.sim.engine import trial_run
from fabric_guidance.sim.node_loop import NodeLoop
from fabric_guidance.experiments.discussion.per_wearer_gain import GAIN_GRID, choose_gain, speed_trial, tune_gain
from fabric_guidance.experiments.discussion.trials import TrialKey, evaluation_keys, tuning_keys

from study_scenes import short, wearer_and_cal


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
