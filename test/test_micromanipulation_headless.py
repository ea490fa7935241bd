"""The micromanipulation sequence headless, straight from object to object.

The three objects of config/params/micromanipulation.yaml (micromanipulator_sim's default positions,
mapped by live_scale and live_offset) are presented one after another with no return to the
front, to simulated wearers calibrated by Algorithm 1, with every effect of the paper-speed
scene (gaze noise, loss, latency, reaction, hysteresis). Every seed tried finds all three.
"""
from dataclasses import replace
import math

import numpy as np
import pytest

from fabric_guidance.paths import node_parameters
from fabric_guidance.sim.engine import ClosedLoop, run_calibration
from fabric_guidance.sim.population import sample_wearer
from fabric_guidance.sim.protocols import sequence_loop
from fabric_guidance.sim.scene import load_scene

EYE = np.array([0.0, 0.0, 1.2])
SEEDS = range(6)
TIMEOUT_S = 15.0


def objects() -> list[tuple[float, float]]:
    sel = node_parameters('params/micromanipulation.yaml', 'target_selector')
    stack = node_parameters('params/micromanipulation.yaml', 'micromanipulator_sim')
    pos = np.reshape(stack['object_positions'], (-1, 3))
    out = []
    for p in pos:
        rel = p * sel['live_scale'] + np.asarray(sel['live_offset']) - EYE
        out.append((math.degrees(math.atan2(rel[1], rel[0])),
                    math.degrees(math.atan2(rel[2], math.hypot(rel[0], rel[1])))))
    return out


def test_the_config_runs_straight_from_object_to_object():
    assert node_parameters('params/micromanipulation.yaml', 'target_selector').get('return_to_front', False) is False


def run(seed: int, frame: str) -> list:
    sc = load_scene('paper-speed')
    sc = replace(sc, seed=seed, controller=replace(sc.controller, guidance_frame=frame))
    wearer = sample_wearer(sc, seed % sc.population.subjects)
    cal = run_calibration(sc, wearer)
    loop = ClosedLoop(sc, wearer, (20, 1, seed), 1, cal)
    loop.warm_up()
    return sequence_loop(loop, objects(), sc.protocol.acceptance_deg, sc.protocol.dwell_s,
                         TIMEOUT_S)


@pytest.mark.parametrize('seed', SEEDS)
def test_all_three_objects_are_found_in_the_calibrations_frame(seed):
    times = run(seed, 'rest')
    print(f'seed {seed}: found after {times} s')
    assert len(times) == 3 and all(t is not None for t in times), times
