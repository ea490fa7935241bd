"""cue_misreading.arm_read_s: the wearer stands still while reading the arm band's cue
(condition 3), reads the suit's at once, and a scene that leaves it at 0 runs as before."""
import math

import numpy as np

from fabric_guidance.sim.engine import ClosedLoop, trial_run
from fabric_guidance.sim.population import sample_wearer
from fabric_guidance.sim.protocols import accuracy_trial
from test_sim_engine import NOISY, exact_cal, scene, trace

QUIET = [{'regulator_lag': {}}, {'body_dynamics': {}}]


def reading(arm_read_s, **cue):
    return [{'cue_misreading': {'direction_p': 0.0, 'magnitude_sd': 0.0, 'arm_read_s': arm_read_s, **cue}}]


def read_and_move(sc, cond, target=(40.0, 0.0), seconds=3.0, visible=False):
    """From the target's presentation: the first read's time, the torso's yaw and whether the
    wearer counted as acting at every step after it, and the loop."""
    w = sample_wearer(sc, 0)
    loop = ClosedLoop(sc, w, trial_run(cond, 0), cond, exact_cal(sc, w))
    loop.warm_up()
    loop.present(*target, visible=visible)
    read_t, after = None, []
    for _ in range(int(round(seconds / loop.dt))):
        loop.step()
        if read_t is None and loop.senses.cue.reads:
            read_t = loop.t
        if read_t is not None:
            after.append((loop.t - read_t, loop.wearer.torso_yaw, loop.wearer.acting))
    return read_t, np.array(after), loop


def test_the_arm_is_read_standing_still_for_arm_read_s_then_followed():
    read_t, after, loop = read_and_move(scene(QUIET + reading(0.8)), 3)
    assert read_t is not None
    reading_, followed = after[after[:, 0] < 0.8 - 1e-9], after[after[:, 0] >= 0.8 + loop.dt]
    yaw0 = reading_[0, 1]
    assert np.all(np.abs(reading_[:, 1] - yaw0) < 1e-9), 'the torso moved while the arm was read'
    assert not reading_[:, 2].any(), 'the wearer counted as acting while still reading the arm'
    assert followed[:, 2].all() and followed[0, 1] != yaw0, 'after the read the wearer acts at once'
    assert abs(loop.wearer.torso_yaw - 40.0) < 5.0, 'and follows the arm as without a read time'
    # Without a read time the same wearer is moving within two steps of the read.
    _, plain, _ = read_and_move(scene(QUIET + reading(0.0)), 3)
    assert abs(plain[2, 1] - plain[0, 1]) > 0.0 and plain[:, 2].all()


def test_the_suit_is_read_at_once_whatever_arm_read_s():
    for cond in (1, 2):
        a, _ = trace(scene(QUIET + reading(0.0)), cond, target=(40.0, 0.0))
        b, _ = trace(scene(QUIET + reading(1.5)), cond, target=(40.0, 0.0))
        assert np.array_equal(a, b)


def test_arm_read_s_of_zero_leaves_every_condition_bit_identical():
    # A scene that names arm_read_s: 0 runs as one that does not name it (the shipped default).
    named = [{'cue_misreading': {'direction_p': 0.3, 'arm_direction_p': 0.2, 'arm_read_s': 0.0}}]
    unnamed = [{'cue_misreading': {'direction_p': 0.3, 'arm_direction_p': 0.2}}]
    for cond in (1, 2, 3, 4):
        a, _ = trace(scene(NOISY + unnamed), cond, seconds=4.0)
        b, _ = trace(scene(NOISY + named), cond, seconds=4.0)
        assert np.array_equal(a, b)


def test_standing_still_to_read_is_no_reason_to_read_again():
    # A read longer than reread_s, of a visible target not yet seen (the speed task, where a
    # wearer standing still re-reads): the stand-still is the read, not a lost wearer.
    _, _, loop = read_and_move(scene(QUIET + reading(2.0, reread_s=1.0)), 3, target=(100.0, 0.0),
                               seconds=2.5, visible=True)
    assert loop.senses.rereads['still'] == 0
    assert loop.senses.cue.reads == 1


def test_the_accuracy_press_waits_for_the_arm_read():
    # settle_s below arm_read_s: a press counted while reading would come at settle_s, at the
    # front, 40 deg from the target.
    proto = {'kind': 'accuracy', 'settle_s': 0.3}
    times = {}
    for read_s in (0.0, 1.0):
        sc = scene(QUIET + reading(read_s), protocol=proto)
        w = sample_wearer(sc, 0)
        out = accuracy_trial(sc, w, exact_cal(sc, w), 3, 0)
        assert not out['timed_out']
        assert out['h_error_deg'] < 10.0 and math.isfinite(out['time_s'])
        times[read_s] = out['time_s']
    # The press comes after the read and the settling, at the target (the error above).
    assert times[1.0] >= 1.0 + 0.3 and times[1.0] > times[0.0]
