"""Scenes and wearers the Discussion studies' tests share (test_study_per_wearer_gain.py,
test_study_moving_targets.py, test_beyond.py)."""
from dataclasses import replace

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
