"""pressure_controller in this process (the rig of test_controller_latch.py): the operator's arm
and the study session's trial gate (pressure only while both are open; the gate never arms),
safety limits that only tighten at run time, use_sim_time fixed while the node runs, and a
tightened limit held across a restart of the node. Every assertion is on a command the node
published, a service's or parameter's answer, or its diagnostics."""
import numpy as np
import pytest
from rclpy.parameter import Parameter
from std_srvs.srv import SetBool

from test_controller_latch import F40, controller, guiding


def gate(rig, on: bool):
    return rig.node.on_trial_gate(SetBool.Request(data=on), SetBool.Response())


def limits_file(state_dir, namespace):
    from fabric_guidance.nodes.held_limits import limits_file
    return limits_file(state_dir, namespace)


def diagnostics(rig) -> tuple[str, dict]:
    got = []
    rig.node.diag_pub.publish = got.append
    rig.node.publish_diagnostics()
    (st,) = got[-1].status
    return st.message, {kv.key: kv.value for kv in st.values}


# ------------------------------------------------------------------- the arm and the trial gate
def test_opening_the_trial_gate_never_arms_a_controller_that_started_disarmed(tmp_path):
    with controller(tmp_path, start_enabled=False) as rig:
        rig.target()
        reply = gate(rig, True)
        assert not reply.success and "operator's arm is off" in reply.message, reply.message
        rig.gazes(0.5)
        assert rig.vented() and not any(np.any(c) for c in rig.sent), 'nothing flows through the gate alone'
        message, values = diagnostics(rig)
        assert values['armed'] == 'False' and values['trial_gate'] == 'open' and "arm is off" in message


def test_pressure_flows_only_while_the_arm_and_the_gate_are_both_open(tmp_path):
    with controller(tmp_path, start_enabled=False) as rig:
        rig.target()
        assert gate(rig, False).success
        assert rig.enable(True).success          # the operator arms: the gate is still closed
        rig.gazes(0.5)
        assert not any(np.any(c) for c in rig.sent), 'armed, the gate closed: vented'
        assert gate(rig, True).success           # the session's trial
        rig.gazes(0.2)
        assert rig.last()['L1'] == pytest.approx(F40)
        n = len(rig.sent)
        assert gate(rig, False).success          # the session's rest: vents at once
        assert len(rig.sent) > n and rig.vented()
        rig.gazes(0.3)
        assert all(not np.any(c) for c in rig.sent[n:])
        assert rig.node.enabled, 'closing the gate leaves the arm as it is'


@pytest.mark.parametrize('stop', ['vent', 'enable false'])
def test_an_outside_vent_holds_whatever_the_session_does_with_its_gate(tmp_path, stop):
    with controller(tmp_path) as rig:
        guiding(rig)
        n = len(rig.sent)
        rig.vent() if stop == 'vent' else rig.enable(False)
        for on in (False, True, False, True):    # the session's next rest and trial, and again
            reply = gate(rig, on)
            assert reply.success == (not on), reply.message
            rig.gazes(0.3)
        assert all(not np.any(c) for c in rig.sent[n:]), 'the stop held through the trial gate'
        message, values = diagnostics(rig)
        assert values['armed'] == 'False' and values['trial_gate'] == 'open'
        assert rig.enable(True).success          # only the operator's enable lifts it
        rig.gazes(0.2)
        assert rig.last()['L1'] == pytest.approx(F40)


def test_a_calibration_needs_the_arm_and_the_open_gate(tmp_path):
    with controller(tmp_path, start_enabled=False) as rig:
        rig.gazes(0.2)
        assert gate(rig, True).success is False
        reply = rig.start_calibration()
        assert not reply.success and "operator's arm is off" in reply.message
        assert rig.enable(True).success and gate(rig, False).success
        reply = rig.start_calibration()
        assert not reply.success and 'trial gate is closed' in reply.message


# ---------------------------------------------------------------- limits only tighten at run time
@pytest.mark.parametrize('name, tighter, looser', [
    ('p_max_kpa', 200.0, 250.0),
    ('gaze_timeout_s', 0.2, 5.0),
    ('stall_timeout_s', 5.0, 20.0),
    ('stall_timeout_s', 5.0, 0.0),      # 0: never
])
def test_a_safety_limit_is_tightened_at_once_and_never_loosened_at_run_time(tmp_path, name, tighter, looser):
    with controller(tmp_path) as rig:
        guiding(rig)
        assert rig.set(**{name: tighter})[0].successful
        (refused,) = rig.set(**{name: looser})
        assert not refused.successful and f'{name} {looser:g} would loosen a safety limit' in refused.reason
        assert rig.node.get_parameter(name).value == tighter and rig.node.v[name] == tighter
        # held for the next start of the node (its namespace's file)
        assert f'{name}: {tighter}' in limits_file('', rig.node.get_namespace()).read_text()


def test_a_limit_loosened_in_one_call_with_other_changes_refuses_them_all(tmp_path):
    with controller(tmp_path) as rig:
        guiding(rig)
        result = rig.node.set_parameters_atomically([Parameter('gain', value=0.2),
                                                     Parameter('gaze_timeout_s', value=2.0)])
        assert not result.successful and 'gaze_timeout_s 2 would loosen' in result.reason
        assert rig.node.v['gain'] == 0.05


def test_use_sim_time_cannot_change_at_run_time(tmp_path):
    with controller(tmp_path) as rig:      # started with use_sim_time true
        (refused,) = rig.set(use_sim_time=False)
        assert not refused.successful and 'use_sim_time is fixed while the node runs' in refused.reason
        assert rig.node.get_parameter('use_sim_time').value is True
        assert rig.set(use_sim_time=True)[0].successful     # no change: nothing refused


# --------------------------------------------------------------------- held across a restart
def test_a_restarted_controller_comes_up_with_the_tightened_limit_and_says_so(tmp_path):
    with controller(tmp_path) as rig:
        assert rig.set(p_max_kpa=100.0, gaze_timeout_s=0.2)[0].successful
    # the process dies; the next one starts from the same parameters (375 kPa, 0.3 s)
    with controller(tmp_path) as rig:
        assert rig.node.p_max == 100.0 and rig.node.get_parameter('p_max_kpa').value == 100.0
        assert rig.node.gaze_timeout == 0.2
        rig.target()
        rig.gazes(0.3, yaw_deg=-10.0)
        assert max(max(c) for c in rig.sent) <= 100.0
        message, values = diagnostics(rig)
        assert 'held limits: p_max_kpa 100 (parameter 375)' in message, message
        assert values['p_max_kpa'] == '100'
        assert not rig.set(p_max_kpa=375.0)[0].successful


def test_a_start_tighter_than_the_held_limit_keeps_the_tighter(tmp_path):
    with controller(tmp_path) as rig:
        assert rig.set(p_max_kpa=100.0)[0].successful
    with controller(tmp_path, p_max_kpa=80.0) as rig:
        assert rig.node.p_max == 80.0


def test_a_held_limits_file_that_cannot_be_read_stops_the_start_in_one_line(tmp_path):
    path = limits_file('', '/')
    path.parent.mkdir(parents=True)
    path.write_text('held: {p_max_kpa: lots}\n')
    with pytest.raises(ValueError, match=r'held limits .*pressure_controller_limits.yaml: field "held.p_max_kpa"'):
        with controller(tmp_path):
            pass


# ------------------------------------------------------------------ one person's calibration
def test_a_parameter_set_naming_another_person_than_its_calibration_is_refused_at_start(tmp_path):
    import rclpy
    from rclpy.context import Context
    from fabric_guidance.graph.process_graph import fresh_domain_id
    from fabric_guidance.nodes.pressure_controller import PressureController
    from test_controller_latch import OK, SIM_CAL_FILE
    context = Context()
    rclpy.init(context=context, domain_id=fresh_domain_id())
    node = None
    try:
        node = PressureController(context=context, parameter_overrides=[
            Parameter('wearer', value='bob'), Parameter('calibration_file', value=str(SIM_CAL_FILE)),
            Parameter('autostart', value=False)])
        assert node.trigger_configure() != OK
        assert 'field "wearer" is "sim-wearer", the parameter "wearer" is "bob"' in node.configure_error
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.shutdown(context=context)


def test_a_calibration_file_of_another_person_is_refused_at_run_time(tmp_path):
    from test_controller_latch import SIM_CAL_FILE
    with controller(tmp_path, calibration_file='') as rig:
        assert rig.set(wearer='bob')[0].successful
        (refused,) = rig.set(calibration_file=str(SIM_CAL_FILE))
        assert not refused.successful and "one person's calibration never guides another" in refused.reason
        result = rig.node.set_parameters_atomically([Parameter('wearer', value='carol'),
                                                     Parameter('calibration_file', value=str(SIM_CAL_FILE))])
        assert not result.successful and rig.node.calibration is None and rig.node.wearer == 'bob'
        # the default, unnamed wearer takes the file's
        assert rig.node.set_parameters_atomically([Parameter('wearer', value='wearer'),
                                                   Parameter('calibration_file', value=str(SIM_CAL_FILE))]).successful


# ------------------------------------------------------------------------ control inputs
def test_a_target_position_stamped_too_long_ago_is_refused(tmp_path):
    from geometry_msgs.msg import PointStamped
    from rclpy.time import Time
    from std_msgs.msg import String
    from fabric_guidance.interface import ACTIVE_TARGET, TARGET
    from fabric_guidance.nodes.command_source import Publisher
    from fabric_guidance.nodes.control_inputs import TARGET_MAX_AGE_S
    from test_controller_latch import EYE, direction
    with controller(tmp_path, ros_time=True) as rig:
        node = rig.node
        for source in node.input_sources.values():   # the graph: target_selector alone publishes both
            source._publishers = lambda: [Publisher('target_selector', '/', b'selector')]
        rig.gazes(0.2)

        def position(age_s):
            msg = PointStamped()
            msg.header.stamp = Time(nanoseconds=int((rig.clock - age_s) * 1e9)).to_msg()
            msg.point.x, msg.point.y, msg.point.z = EYE + 2.0 * direction(40.0)
            return msg
        node.on_control_input(ACTIVE_TARGET, String(data='t1'))
        node.on_control_input(TARGET, position(TARGET_MAX_AGE_S + 0.5))
        rig.gazes(0.3)
        assert node.target is None and rig.vented() and 'older than' in node.last_input_refusal
        node.on_control_input(TARGET, position(0.05))
        rig.gazes(0.2)
        assert rig.last()['L1'] == pytest.approx(F40)
