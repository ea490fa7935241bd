"""core/controller_parameters.py is the one source of pressure_controller's parameters: the
docs table is generated from it, and the setup, the scene section and the recorded YAML agree
with it. Also the one split of Eq. 5 into directions (core.feedback.step_directions)."""
from dataclasses import fields
import math
from pathlib import Path
import subprocess
import sys
import warnings

import pytest

from fabric_guidance.bag.controller_io import setup_from_dict, setup_to_dict
from fabric_guidance.core import Calibration, ChannelMap, PowerLaw
from fabric_guidance.core import controller_parameters as cp
from fabric_guidance.core.control_step import ControllerSetup
from fabric_guidance.core.feedback import FeedbackLaw, GuidanceController, step_directions
from fabric_guidance.paths import config_path
from fabric_guidance.sim.scene import ControllerSpec, SceneError, load_scene, scene_from_dict

DOCS = Path(__file__).resolve().parent.parent / 'docs' / 'interfaces.md'
LAW = PowerLaw(20.0, 0.65, 25.0)


def setup():
    return ControllerSetup(calibration=Calibration.from_laws('w', [LAW] * 4),
                           channel_map=ChannelMap.load(config_path('hardware/channel_map.yaml')))


def test_docs_rows_are_the_generated_ones():
    assert cp.markdown() in DOCS.read_text(), (
        "docs/interfaces.md: pressure_controller's parameter rows differ from "
        '`python -m fabric_guidance.core.controller_parameters --markdown`; paste its output')
    out = subprocess.run([sys.executable, '-m', 'fabric_guidance.core.controller_parameters', '--markdown'],
                         capture_output=True, text=True, timeout=60, check=True).stdout
    assert out == cp.markdown()


def test_names_unique_defaults_in_range_and_units_in_names():
    assert len(cp.BY_NAME) == len(cp.PARAMETERS)
    for p in cp.PARAMETERS:
        if p.name != 'channels':
            assert cp.check(p.name, p.default, p.name) == p.default
        # ROS convention: the unit ends the name of every quantity with one
        suffix = {'kPa': '_kpa', 's': '_s', 'Hz': '_hz', 'deg/s': '_dps', 'deg': '_deg'}.get(p.unit)
        if suffix:
            assert p.name.endswith(suffix), f'{p.name} has unit {p.unit}'


def test_setup_scene_and_recorded_yaml_follow_the_table():
    assert [f.name for f in fields(ControllerSetup)][2:] == [p.name for p in cp.SETUP]
    assert [f.name for f in fields(ControllerSpec)] == [p.name for p in cp.SCENE]
    assert all(getattr(ControllerSpec(), p.name) == p.default for p in cp.SCENE)
    d = setup_to_dict(setup())
    assert [k for k in d if k in cp.BY_NAME] == [p.name for p in cp.SETUP]
    assert setup_to_dict(setup_from_dict(d)) == d


def test_recorded_values_out_of_range_are_refused_naming_the_field():
    d = setup_to_dict(setup())
    d['p_max_kpa'] = 0.0
    with pytest.raises(ValueError, match=r'controller_parameters: field "p_max_kpa": must be > 0 kPa'):
        setup_from_dict(d)


def test_scene_ranges_come_from_the_table():
    scene = load_scene('paper-speed')
    data = {'name': 'x', 'seed': 1, 'protocol': {'kind': 'speed'},
            'population': {'laws': {d: {'a': 20.0, 'b': 0.6, 'c': 20.0} for d in ('left', 'right', 'down', 'up')}},
            'controller': {'gain': 11.0}}
    with pytest.raises(SceneError, match=r'field "controller.gain" must be <= 10'):
        scene_from_dict(data, 'x.yaml')
    assert scene.controller.p_max_kpa == cp.default('p_max_kpa')


def test_an_old_name_is_read_as_the_new_one_with_one_warning(monkeypatch):
    """A renamed parameter (none is renamed today: this one is for the test) stays readable in a
    recorded YAML and a scene file, with a warning naming where it came from."""
    p = cp.BY_NAME['gain']
    monkeypatch.setattr(cp, '_OLD', {'adjustment_gain': 'gain'})
    d = setup_to_dict(setup())
    d['adjustment_gain'] = d.pop('gain') * 2
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        assert setup_from_dict(d, 'bag x').gain == 2 * p.default
    assert [str(w.message) for w in caught] == [
        'bag x: parameter "adjustment_gain" is deprecated, read as "gain"; rename it']
    d['gain'] = 0.1
    with pytest.raises(ValueError, match='both "adjustment_gain" and its new name "gain"'):
        setup_from_dict(d, 'bag x')


def _skipping(directions, ht, vt, h, v, t):
    """The simulator's former split: a direction whose theta_t <= 0 was not stepped at all."""
    thetas = (ht, -ht, -vt, vt)
    gazes = (h, -h, -v, v)
    return tuple(d.step(tt, g, t) if tt > 0.0 else 0.0 for d, tt, g in zip(directions, thetas, gazes))


def test_a_direction_whose_target_angle_turns_non_positive_restarts_from_f():
    """Eq. 5 per direction: P = 0 while theta_t <= 0, and guidance in that direction starts
    again from f(theta_t). Skipping the direction (the engine's old shortcut) kept its old state
    instead: when a (moving) target came back to that side, the pressure resumed where it was.
    With a static target both agree (test_sim_engine: bit-identical protocols); step_directions
    is the paper's law and what GuidanceController.update does."""
    def laws():
        return [FeedbackLaw(LAW, gain=0.5, estimator='sign') for _ in range(4)]
    stepped, skipped = laws(), laws()
    # target 30 deg left; the gaze drifts right (the error grows: Eq. 5 adds pressure)
    track = [(30.0, 0.0), (30.0, -2.0), (30.0, -4.0),
             (0.0, -4.0),              # the target moves to straight ahead: left's theta_t = 0
             (30.0, -4.0)]             # and back to the left
    for k, (ht, h) in enumerate(track):
        a = step_directions(stepped, ht, 0.0, h, 0.0, 0.1 * k)
        b = _skipping(skipped, ht, 0.0, h, 0.0, 0.1 * k)
    assert a[0] == pytest.approx(LAW.pressure(30.0))      # afresh from f(theta_t)
    assert b[0] > LAW.pressure(30.0) + 1.0                 # the stale, wound-up pressure
    # the same split as GuidanceController.update (which also vents on theta_t <= 0)
    ctl = GuidanceController([LAW] * 4, estimator='sign')
    gaze = (1.0, 0.0, 0.0)
    target = (math.cos(math.radians(30)), math.sin(math.radians(30)), 0.0)
    ref = [FeedbackLaw(LAW, estimator='sign') for _ in range(4)]
    assert tuple(ctl.update(gaze, target, 0.0)) == pytest.approx(step_directions(ref, 30.0, 0.0, 0.0, 0.0, 0.0))


NODE_DESCRIPTORS = r'''
import json, rclpy
from fabric_guidance.nodes.pressure_controller import PressureController
rclpy.init()
node = PressureController()
node.trigger_configure()   # a lifecycle node: `channels` is declared with the channel map it mirrors
out = {}
for name in node._parameters:
    if name in ('use_sim_time', 'start_type_description_service', 'autostart'):   # rclpy's; the lifecycle's
        continue
    d = node.describe_parameter(name)
    rng = d.floating_point_range or d.integer_range
    out[name] = [node.get_parameter(name).value, d.read_only,
                 [rng[0].from_value, rng[0].to_value] if rng else None, d.description]
node.destroy_node()
rclpy.shutdown()
print(json.dumps(out))
'''


def test_the_node_declares_the_table():
    """pressure_controller's parameters, values, ranges and read-only flags are the table's (a
    node in its own process, DDS on loopback in a domain of its own)."""
    import json
    import os
    from fabric_guidance.graph.process_graph import fresh_domain_id, loopback_dds_env
    env = dict(os.environ, ROS_DOMAIN_ID=str(fresh_domain_id()), **loopback_dds_env())
    out = subprocess.run([sys.executable, '-c', NODE_DESCRIPTORS], capture_output=True, text=True,
                         timeout=120, env=env, check=True).stdout
    declared = json.loads(out.strip().splitlines()[-1])
    assert list(declared) == [p.name for p in cp.PARAMETERS]
    for p in cp.PARAMETERS:
        value, read_only, rng, description = declared[p.name]
        if p.name != 'channels':
            assert value == p.default, p.name
        assert read_only == p.read_only, p.name
        assert rng == ([p.low, p.high] if p.low is not None else None), p.name
        assert description.startswith(p.description), p.name
