"""The paper's micromanipulation demonstration: its configuration (config/params/micromanipulation.yaml).

The demonstration itself runs under the real launch system in test_launch.py
(launch/micromanipulation.launch.py with the simulated stack, PLC and wearer: the objects found in
order, the stack's frame and drift, the targets mapped x1000 + offset); it replaced the process
graph that was started here with the same files.
"""
import math

import numpy as np

from fabric_guidance.paths import node_parameters


ORDER = ['holding_pipette', 'microbead', 'injection_pipette']
SELECTOR = node_parameters('params/micromanipulation.yaml', 'target_selector')
STACK = node_parameters('params/micromanipulation.yaml', 'micromanipulator_sim')
SCALE, OFFSET = SELECTOR['live_scale'], np.array(SELECTOR['live_offset'])
MICRO = {n: np.array(STACK['object_positions'][3 * i:3 * i + 3]) for i, n in enumerate(STACK['object_names'])}
EYE = np.array([0.0, 0.0, 1.2])


def test_the_configuration_is_the_papers_demonstration():
    assert SELECTOR['sequence'] == ORDER == STACK['object_names']
    assert sorted(SELECTOR['live_targets']) == sorted(ORDER)
    assert SCALE == 1000.0                     # the paper's 1000x
    assert STACK['frame_id'] == 'microscope'
    # Every object at micro scale (within a few mm of the field's centre) and, once mapped, off
    # the wearer's front by more than the acceptance angle, within the simulated wearer's reach.
    for name, p in MICRO.items():
        assert np.all(np.abs(p) < 5e-3), name
        rel = p * SCALE + OFFSET - EYE
        yaw = math.degrees(math.atan2(rel[1], rel[0]))
        pitch = math.degrees(math.atan2(rel[2], math.hypot(rel[0], rel[1])))
        assert SELECTOR['acceptance_deg'] < math.hypot(yaw, pitch) < 60.0, (name, yaw, pitch)
