"""pressure_controller in this process, its clocks in the test's hands: the enable latch
(enable false and vent stop every pressure, a calibration's included, until enable true; no
lifecycle transition or parameter lifts it), the safety bounds on the steady clock with a
stopped ROS clock (use_sim_time with no /clock), and parameters set at run time (each takes
effect at once or is refused with the reason). Every assertion is on a command the node
published or a service's or parameter's answer."""
import contextlib
import math

import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import PointStamped, PoseStamped
from rclpy.context import Context
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.time import Time
from std_msgs.msg import String
from std_srvs.srv import SetBool, Trigger

from fabric_guidance.core import Calibration, ChannelMap, PowerLaw, ray_orientation
from fabric_guidance.core.geometry import DIRECTIONS
from fabric_guidance.nodes.pressure_controller import PressureController
from fabric_guidance.graph.process_graph import CONFIG, fresh_domain_id

SIM_CAL_FILE = CONFIG / 'calibrations' / 'sim-wearer.yaml'
F40 = Calibration.load(SIM_CAL_FILE).laws[0].pressure(40.0)
CMAP = ChannelMap.load(CONFIG / 'hardware' / 'channel_map.yaml')
EYE = np.array([0.0, 0.0, 1.2])
OK = TransitionCallbackReturn.SUCCESS
#: A short calibration: 4 x (0.5 s rest + 3 x 0.5 s steps) = 8 s of the fake clock.
FAST_CAL = dict(calibration_steps=3, calibration_dwell_s=0.5, calibration_rest_s=0.5, calibration_window_s=0.1)


def direction(yaw_deg, pitch_deg=0.0):
    y, p = math.radians(yaw_deg), math.radians(pitch_deg)
    return np.array([math.cos(p) * math.cos(y), math.cos(p) * math.sin(y), math.sin(p)])


class Rig:
    """The node, a fake steady clock (`clock`), and every command it published (`sent`).
    ros_time: the node's ROS time follows that clock (as a running /clock would); else it
    stays at 0 (use_sim_time with no /clock)."""

    def __init__(self, node, ros_time=False):
        self.node, self.clock, self.sent, self.ros_time = node, 1000.0, [], ros_time
        node.now_s = lambda: self.clock
        publish = node.publish

        def capture(channels):
            publish(channels)
            self.sent.append(np.array(node.command_msg.data))
        node.publish = capture

    def gaze(self, yaw_deg=0.0, pitch_deg=0.0, dt=1 / 30):
        """One gaze sample dt after the last (it steps the node, step_on_gaze)."""
        self.clock += dt
        if self.ros_time:
            self.node.get_clock().set_ros_time_override(Time(nanoseconds=int(self.clock * 1e9)))
        msg = PoseStamped()
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = EYE
        o = msg.pose.orientation
        o.x, o.y, o.z, o.w = ray_orientation(direction(yaw_deg, pitch_deg))
        self.node.on_gaze(msg)

    def gazes(self, seconds, yaw_deg=0.0):
        for _ in range(int(round(seconds * 30))):
            self.gaze(yaw_deg)

    def target(self, name='t1', yaw_deg=40.0):
        self.node.on_active_target(String(data=name))
        msg = PointStamped()
        msg.point.x, msg.point.y, msg.point.z = EYE + 2.0 * direction(yaw_deg)
        self.node.on_target(msg)

    def last(self) -> dict:
        return dict(zip(CMAP.channels, self.sent[-1]))

    def vented(self) -> bool:
        return bool(self.sent) and not np.any(self.sent[-1])

    def enable(self, on: bool):
        return self.node.on_enable(SetBool.Request(data=on), SetBool.Response())

    def vent(self):
        return self.node.on_vent(Trigger.Request(), Trigger.Response())

    def start_calibration(self):
        return self.node.on_start_calibration(Trigger.Request(), Trigger.Response())

    def set(self, **values):
        return self.node.set_parameters([Parameter(k, value=v) for k, v in values.items()])


@contextlib.contextmanager
def controller(tmp_path, activate=True, ros_time=False, **params):
    """An active controller on the simulated wearer's calibration, use_sim_time with no /clock:
    ROS time reads 0 throughout, or follows the fake clock (ros_time)."""
    context = Context()
    rclpy.init(context=context, domain_id=fresh_domain_id())
    values = {'calibration_file': str(SIM_CAL_FILE), 'calibration_dir': str(tmp_path / 'calibrations'),
              'autostart': False, 'use_sim_time': True, **params}
    node = None
    try:
        node = PressureController(context=context,
                                  parameter_overrides=[Parameter(k, value=v) for k, v in values.items()])
        rig = Rig(node, ros_time)
        assert node.trigger_configure() == OK, node.configure_error
        if activate:
            assert node.trigger_activate() == OK
        yield rig
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.shutdown(context=context)


def guiding(rig):
    rig.target()
    rig.gazes(0.2)
    assert rig.last()['L1'] == pytest.approx(F40), 'guiding to 40 deg left'


def calibrating_under_pressure(rig):
    """start_calibration accepted and its first pressure step applied."""
    rig.gazes(0.2)
    reply = rig.start_calibration()
    assert reply.success, reply.message
    rig.gazes(0.8)   # past the 0.5 s rest: the first step's pressure
    assert np.any(rig.sent[-1]), 'the calibration pressurises'


# ------------------------------------------------------------------------- the enable latch
def test_enable_false_during_a_calibration_ends_it_and_vents_at_once(tmp_path):
    with controller(tmp_path, ros_time=True, **FAST_CAL) as rig:
        calibrating_under_pressure(rig)
        status = []
        rig.node.status_pub.publish = lambda msg: status.append(msg.data)
        n = len(rig.sent)
        reply = rig.enable(False)
        assert reply.success and 'disabled' in reply.message
        assert len(rig.sent) > n and rig.vented(), 'zeros published by the call itself'
        assert rig.node.procedure is None and status and status[-1].startswith('failed: disabled')
        rig.gazes(2.0)
        assert all(not np.any(c) for c in rig.sent[n:]), 'nothing pressurised after enable false'


@pytest.mark.parametrize('stop', ['enable false', 'vent'])
def test_a_disabled_or_vented_controller_refuses_to_calibrate(tmp_path, stop):
    with controller(tmp_path, **FAST_CAL) as rig:
        rig.gazes(0.2)
        rig.enable(False) if stop == 'enable false' else rig.vent()
        reply = rig.start_calibration()
        assert not reply.success and 'call enable first' in reply.message, reply.message
        rig.gazes(2.0)
        assert rig.vented() and all(not np.any(c) for c in rig.sent)
        assert rig.enable(True).success and rig.start_calibration().success


def test_a_controller_started_disabled_refuses_to_calibrate(tmp_path):
    """A respawned controller (start_enabled false) calibrates nobody before the operator's enable."""
    with controller(tmp_path, start_enabled=False, **FAST_CAL) as rig:
        rig.gazes(0.2)
        assert not rig.start_calibration().success
        rig.gazes(1.0)
        assert all(not np.any(c) for c in rig.sent)


@pytest.mark.parametrize('stop', ['enable false', 'vent'])
def test_no_lifecycle_transition_or_parameter_lifts_the_latch(tmp_path, stop):
    with controller(tmp_path) as rig:
        guiding(rig)
        rig.enable(False) if stop == 'enable false' else rig.vent()
        n = len(rig.sent)
        node = rig.node
        assert node.trigger_deactivate() == OK and node.trigger_activate() == OK
        rig.gazes(0.5)
        assert node.trigger_deactivate() == OK and node.trigger_cleanup() == OK
        assert node.trigger_configure() == OK and node.trigger_activate() == OK
        rig.target('t2', 30.0)
        rig.gazes(0.5)
        assert all(r.successful for r in rig.set(gain=0.1, condition=2))
        rig.gazes(0.5)
        assert all(not np.any(c) for c in rig.sent[n:]), 'pressure without the operator\'s enable'
        assert rig.enable(True).success
        rig.gazes(0.3)
        assert rig.last()['L1'] == pytest.approx(Calibration.load(SIM_CAL_FILE).laws[0].pressure(30.0))


def test_deactivate_and_activate_keep_a_latched_stall(tmp_path):
    with controller(tmp_path, ros_time=True, stall_timeout_s=1.0) as rig:
        guiding(rig)
        rig.gazes(1.5)     # the wearer stays at the front: no progress
        assert rig.vented() and rig.node.controller.stalled
        node = rig.node
        assert node.trigger_deactivate() == OK and node.trigger_activate() == OK
        n = len(rig.sent)
        rig.gazes(1.0)
        assert all(not np.any(c) for c in rig.sent[n:]), 'a deactivate/activate cleared the stall'
        rig.target('t2', 30.0)     # the next target guides again
        rig.gazes(0.2)
        assert np.any(rig.sent[-1])


# ------------------------------------------------------------- the steady clock, not ROS time
def test_the_stall_vent_fires_with_ros_time_stopped(tmp_path):
    with controller(tmp_path, stall_timeout_s=1.0) as rig:
        assert rig.node.get_clock().now().nanoseconds == 0, 'ROS time stopped (use_sim_time, no /clock)'
        guiding(rig)
        rig.gazes(1.5)
        assert rig.vented(), 'no-progress vent on the steady clock'


def test_a_wearer_who_blinks_every_second_is_still_stopped(tmp_path):
    """A gaze gap longer than gaze_timeout_s every second vents for the gap but does not
    restart the stall watch: the stall vent comes after stall_timeout_s of no progress."""
    with controller(tmp_path, stall_timeout_s=2.0, gaze_timeout_s=0.3) as rig:
        guiding(rig)
        t0 = rig.clock
        stalled_at = None
        for _ in range(5):
            rig.gazes(0.6)
            rig.clock += 0.4                  # a blink: no gaze for longer than gaze_timeout_s
            rig.node.on_timer()
            assert rig.vented()
            if rig.node.controller.stalled and stalled_at is None:
                stalled_at = rig.clock - t0
        rig.gazes(0.5)
        assert rig.node.controller.stalled, 'every blink restarted the stall watch'
        assert rig.vented() and stalled_at is not None and stalled_at <= 2.0 + 1.0 + 0.1, stalled_at


def test_a_gaze_sample_that_waited_in_a_frozen_controller_is_stale(tmp_path):
    """Samples are aged from their capture stamp: after a freeze (SIGSTOP) of the controller, the
    samples queued meanwhile are as old as their stamps, and guidance vents instead of acting on
    them; a sample stamped now guides again, and one without a stamp counts from its arrival."""
    with controller(tmp_path, gaze_timeout_s=0.3, ros_time=True) as rig:
        guiding(rig)

        def sample(age_s):
            msg = PoseStamped()
            msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = EYE
            o = msg.pose.orientation
            o.x, o.y, o.z, o.w = ray_orientation(direction(0.0))
            rig.clock += 1 / 30
            rig.node.get_clock().set_ros_time_override(Time(nanoseconds=int(rig.clock * 1e9)))
            if age_s is not None:
                msg.header.stamp = Time(nanoseconds=int((rig.clock - age_s) * 1e9)).to_msg()
            rig.node.on_gaze(msg)
        sample(2.0)     # captured 2 s ago: waited in the frozen process
        assert rig.vented(), 'a 2 s old sample guided'
        sample(0.01)
        assert not rig.vented(), 'a sample captured now guides'
        sample(None)
        assert not rig.vented()


def test_a_calibration_ends_with_ros_time_stopped(tmp_path):
    """The calibration's schedule runs on the steady clock: with no /clock it still moves on and
    ends (here refused: the wearer does not move), leaving the suit vented."""
    with controller(tmp_path, **FAST_CAL) as rig:
        status = []
        publish = rig.node.status_pub.publish
        rig.node.status_pub.publish = lambda msg: (status.append(msg.data), publish(msg))
        calibrating_under_pressure(rig)
        rig.gazes(9.0)
        assert rig.node.procedure is None, f'a calibration frozen in a step: {status[-3:]}'
        assert status[-1].startswith('failed') and rig.vented()


# --------------------------------------------------------------------- parameters at run time
def test_a_lower_p_max_clamps_the_very_next_command_and_a_higher_one_is_refused(tmp_path):
    with controller(tmp_path) as rig:
        guiding(rig)
        (result,) = rig.set(p_max_kpa=100.0)
        assert result.successful, result.reason
        assert rig.vented(), 'the change vents at once'
        rig.gazes(0.3, yaw_deg=-10.0)            # the error grows: Eq. 5 would raise the pressure
        assert max(max(c) for c in rig.sent[-9:]) <= 100.0 and rig.last()['L1'] == pytest.approx(100.0)
        for higher in (400.0, 375.0):   # above the start value, and back up to it: limits only tighten
            (refused,) = rig.set(p_max_kpa=higher)
            assert not refused.successful and 'would loosen a safety limit (in force: 100' in refused.reason
        assert rig.node.get_parameter('p_max_kpa').value == 100.0


def test_gain_condition_and_calibration_file_take_effect_or_are_refused(tmp_path):
    with controller(tmp_path) as rig:
        guiding(rig)
        assert rig.set(gain=0.2)[0].successful
        assert [d.gain for d in rig.node.controller.directions] == [0.2] * 4
        assert rig.set(condition=3)[0].successful
        rig.gazes(0.2)
        last = rig.last()
        assert last['L1'] == 0.0 and max(last.values()) > 0.0, 'condition 3 drives the arm muscles'
        bad = tmp_path / 'bad.yaml'
        bad.write_text('wearer: [\n')
        (refused,) = rig.set(calibration_file=str(bad))
        assert not refused.successful and 'bad.yaml' in refused.reason
        (missing,) = rig.set(calibration_file=str(tmp_path / 'nobody.yaml'))
        assert not missing.successful and 'does not exist' in missing.reason
        (refused,) = rig.set(wearer='../etc')
        assert not refused.successful and 'wearer' in refused.reason
        assert not rig.set(channel_map_file='x.yaml')[0].successful   # read-only


def test_a_calibration_refuses_changes_but_a_lower_p_max_ends_it(tmp_path):
    with controller(tmp_path, ros_time=True, **FAST_CAL) as rig:
        calibrating_under_pressure(rig)
        for change in (dict(condition=3), dict(wearer='bob'), dict(calibration_steps=5), dict(gain=0.1)):
            (r,) = rig.set(**change)
            assert not r.successful and 'calibration is running' in r.reason, change
        assert rig.set(p_max_kpa=50.0)[0].successful
        assert rig.node.procedure is None and rig.vented()


# ----------------------------------------------------------------- a first-time participant
def test_a_missing_calibration_file_configures_without_one_and_a_new_wearer_calibrates(tmp_path):
    with controller(tmp_path, calibration_file=str(tmp_path / 'alice.yaml'), **FAST_CAL) as rig:
        assert rig.node.calibration is None and rig.node.state_label == 'active'
        assert rig.set(wearer='alice')[0].successful
        status = []
        rig.node.status_pub.publish = lambda msg: status.append(msg.data)
        calibrating_under_pressure(rig)
        rig.gazes(9.0)     # the wearer does not move: refused
        assert 'no previous calibration of alice' in status[-1], status[-1]
        assert 'is kept' not in status[-1]
        assert not (tmp_path / 'calibrations' / 'alice.yaml').exists()


ALICE = [PowerLaw(18.0, 0.7, 22.0), PowerLaw(25.0, 0.6, 18.0), PowerLaw(45.0, 0.5, 28.0), PowerLaw(35.0, 0.6, 30.0)]
SIGN = {'left': (1, 0), 'right': (-1, 0), 'down': (0, -1), 'up': (0, 1)}


def answer(rig, laws, seconds):
    """The wearer of `laws` looking where each command turns them, for `seconds` of gaze."""
    for _ in range(int(round(seconds * 30))):
        per_dir = CMAP.to_directions(rig.sent[-1], 'suit') if rig.sent else np.zeros(4)
        yaw = pitch = 0.0
        for d, p, law in zip(DIRECTIONS, per_dir, laws):
            if p > 0:
                angle = law.theta(p, 375.0)
                yaw, pitch = yaw + SIGN[d][0] * angle, pitch + SIGN[d][1] * angle
        rig.gaze(yaw, pitch)


def test_a_session_sets_wearer_and_condition_then_calibrates_and_guides_at_once(tmp_path):
    """What a study session does over set_parameters: a new participant (no file) and a
    condition in one call, start_calibration, and guidance on the new file from the next step."""
    with controller(tmp_path, **FAST_CAL) as rig:
        results = rig.node.set_parameters_atomically([Parameter('wearer', value='p01'),
                                                      Parameter('condition', value=2)])
        assert results.successful, results.reason
        assert rig.node.calibration is None, "another person's calibration is dropped"
        rig.gazes(0.2)
        assert rig.start_calibration().success
        answer(rig, ALICE, 9.0)
        path = tmp_path / 'calibrations' / 'p01.yaml'
        assert rig.node.procedure is None and path.is_file()
        assert rig.node.calibration.wearer == 'p01'
        rig.target('t1', 40.0)
        rig.gazes(0.2)
        fitted = Calibration.load(path).laws[0].pressure(40.0)
        assert rig.last()['L1'] == pytest.approx(fitted) and abs(fitted - ALICE[0].pressure(40.0)) < 5.0


def test_a_bag_recorded_before_the_clock_field_still_replays():
    """controller_input of 18 values (before `clock`): decoded with the stall watch on t."""
    from fabric_guidance.bag.controller_io import FIELDS, decode_input
    data = [0.0] * (len(FIELDS) - 1)
    assert decode_input(data).clock is None
    assert decode_input(data + [5.0]).clock == 5.0
