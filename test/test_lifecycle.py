"""plc_output and pressure_controller as lifecycle nodes, driven through the standard services
as an operator (`ros2 lifecycle set`) or a launch file does, on processes started with
autostart false. Every assertion is on what leaves the nodes: the PLC's registers read back
over Modbus, the topics, /diagnostics, the services' answers. The transitions' times are
measured and printed (run with -s)."""
import signal
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
import numpy as np
import pytest
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import SetBool

from deadlines import DeadlineLog
from fabric_guidance.interface import CONTROLLER_PARAMETERS, DIAGNOSTICS, ENABLE, PRESSURE_COMMAND, VENT
from fabric_guidance.nodes.qos import COMMAND_QOS, LATCHED_QOS
from rosgraph import Graph, Probe, wait_until
from test_node_plc import (COMMAND_DEADLINE_S, EXIT_DEADLINE_S, OUTPUT_STATUS, PARAMS_FILES, STARTUP_DEADLINE_S,
                           VENT_MARGIN_S, WRITE_PERIOD_S, Rig, distinct_command)

pytestmark = pytest.mark.graph  # starts a process graph with DDS

#: A transition's answer (the node runs it in a service callback; configure connects to the PLC).
TRANSITION_DEADLINE_S = 10.0
#: deactivate / shutdown answered -> registers vented: the node writes zeros inside the
#: transition, so only the read-back poll and slack remain.
TRANSITION_VENT_DEADLINE_S = WRITE_PERIOD_S + VENT_MARGIN_S
#: How long "nothing written" is watched for.
QUIET_S = 0.5

TIMES = DeadlineLog('transition')
times_report = TIMES.report_at_module_end('lifecycle transitions (answer, and vent read back)')


def transition(probe, node, transition_id):
    """Ask for a transition; (success, seconds to the answer)."""
    t0 = time.monotonic()
    response = probe.call(ChangeState, f'/{node}/change_state',
                          ChangeState.Request(transition=Transition(id=transition_id)), TRANSITION_DEADLINE_S)
    return response.success, time.monotonic() - t0


def state(probe, node):
    return probe.call(GetState, f'/{node}/get_state', GetState.Request(), TRANSITION_DEADLINE_S).current_state.label


def lifecycle_value(rig, start=0):
    status = rig.latest_status(OUTPUT_STATUS, start)
    return None if status is None else {kv.key: kv.value for kv in status.values}.get('lifecycle state')


@pytest.fixture
def managed_rig(tmp_path):
    rig = Rig(tmp_path / 'graph', output={'autostart': False}, wait=False)
    yield rig
    rig.close()


def test_plc_output_goes_through_every_transition_and_vents_out_of_active(managed_rig):
    rig, probe = managed_rig, managed_rig.probe
    command = distinct_command()
    wait_until(lambda: rig.max_written, STARTUP_DEADLINE_S, what='the mock PLC up')
    assert state(probe, 'plc_output') == 'unconfigured'
    wait_until(lambda: lifecycle_value(rig) == 'unconfigured', STARTUP_DEADLINE_S,
               what='/diagnostics to report the lifecycle state unconfigured')
    rig.command(command)
    rig.first_published()
    rig.assert_stays_vented(QUIET_S, 'unconfigured: no link, nothing written')
    assert not rig.measured, 'an unconfigured plc_output has no link and publishes no measured_pressure'

    ok, dt = transition(probe, 'plc_output', Transition.TRANSITION_CONFIGURE)
    assert ok, 'configure refused'
    TIMES.record('plc_output configure (reads the maps, connects)', dt, TRANSITION_DEADLINE_S)
    wait_until(lambda: rig.measured, STARTUP_DEADLINE_S, what='measured_pressure once configured (link up)')
    rig.assert_stays_vented(QUIET_S, 'inactive: commands heard but not written')

    t0 = time.monotonic()
    ok, dt = transition(probe, 'plc_output', Transition.TRANSITION_ACTIVATE)
    assert ok
    rig.wait_registers(command, COMMAND_DEADLINE_S, 'the command in the registers once active')
    TIMES.record('plc_output activate (answer)', dt, TRANSITION_DEADLINE_S)
    TIMES.record('plc_output activate -> command in the registers', time.monotonic() - t0,
                 TRANSITION_DEADLINE_S + COMMAND_DEADLINE_S)

    t0 = time.monotonic()
    ok, dt = transition(probe, 'plc_output', Transition.TRANSITION_DEACTIVATE)
    assert ok
    TIMES.record('plc_output deactivate (answer)', dt, TRANSITION_DEADLINE_S)
    deadline = TRANSITION_VENT_DEADLINE_S + dt
    TIMES.record('plc_output deactivate -> registers vented', rig.time_to_vent(t0, deadline, 'deactivate'), deadline)
    # The link is held: read-backs keep coming while the commands (still published) are not written.
    n = len(rig.measured)
    rig.assert_stays_vented(QUIET_S, 'inactive after deactivate')
    wait_until(lambda: len(rig.measured) > n + 3, COMMAND_DEADLINE_S, what='measured_pressure while inactive')
    start = len(rig.diagnostics)
    wait_until(lambda: lifecycle_value(rig, start) == 'inactive', STARTUP_DEADLINE_S, what='diagnostics: inactive')
    values = {kv.key: kv.value for kv in rig.latest_status(OUTPUT_STATUS, start).values}
    assert values['connected'] == 'True' and int(values['commands ignored while not active']) > 0, values

    ok, _ = transition(probe, 'plc_output', Transition.TRANSITION_ACTIVATE)
    assert ok
    rig.wait_registers(command, COMMAND_DEADLINE_S, 'the command again after a second activate')
    ok, _ = transition(probe, 'plc_output', Transition.TRANSITION_DEACTIVATE)
    assert ok
    t0 = time.monotonic()
    ok, dt = transition(probe, 'plc_output', Transition.TRANSITION_CLEANUP)
    assert ok
    TIMES.record('plc_output cleanup (vents, closes the link)', dt, TRANSITION_DEADLINE_S)
    n = len(rig.measured)
    time.sleep(3 * WRITE_PERIOD_S)   # a read-back already on its way may still arrive
    settled = len(rig.measured)
    rig.assert_stays_vented(QUIET_S, 'unconfigured after cleanup')
    assert len(rig.measured) == settled, f'measured_pressure after cleanup ({n} -> {len(rig.measured)})'
    assert state(probe, 'plc_output') == 'unconfigured'

    ok, _ = transition(probe, 'plc_output', Transition.TRANSITION_CONFIGURE)
    assert ok, 'a second configure after cleanup'
    ok, _ = transition(probe, 'plc_output', Transition.TRANSITION_ACTIVATE)
    assert ok
    rig.wait_registers(command, COMMAND_DEADLINE_S, 'the command after cleanup, configure, activate')
    t0 = time.monotonic()
    ok, dt = transition(probe, 'plc_output', Transition.TRANSITION_ACTIVE_SHUTDOWN)
    assert ok
    TIMES.record('plc_output shutdown from active (answer)', dt, TRANSITION_DEADLINE_S)
    deadline = TRANSITION_VENT_DEADLINE_S + dt
    TIMES.record('plc_output shutdown -> registers vented', rig.time_to_vent(t0, deadline, 'shutdown'), deadline)
    assert state(probe, 'plc_output') == 'finalized'
    rig.assert_stays_vented(QUIET_S, 'finalized')
    # The process still ends cleanly on SIGINT, as a finalized node should.
    assert rig.graph.stop('plc_output', signal.SIGINT, EXIT_DEADLINE_S) == 0


def test_plc_output_faults_hold_while_inactive(managed_rig):
    """Inactive is not a blind spot: a lost PLC is reported and reconnected, SIGINT vents and
    exits 0, and the commands written once active are the fresh ones only."""
    rig, probe = managed_rig, managed_rig.probe
    wait_until(lambda: rig.max_written, STARTUP_DEADLINE_S, what='the mock PLC up')
    assert transition(probe, 'plc_output', Transition.TRANSITION_CONFIGURE)[0]
    wait_until(lambda: rig.measured, STARTUP_DEADLINE_S, what='link up')
    rig.graph.stop('mock_plc', signal.SIGKILL)
    start = len(rig.diagnostics)
    wait_until(lambda: (s := rig.latest_status(OUTPUT_STATUS, start)) is not None and s.level == DiagnosticStatus.ERROR,
               STARTUP_DEADLINE_S, what='diagnostics ERROR for the lost link while inactive')
    rig.start_mock()
    n = len(rig.measured)
    wait_until(lambda: len(rig.measured) > n, STARTUP_DEADLINE_S, what='the link back while inactive')
    # A command heard while inactive is never written: activation waits for a new one.
    rig.command(distinct_command())
    rig.first_published()
    rig.stop_commands()
    time.sleep(2 / 20.0)            # the last command delivered
    assert transition(probe, 'plc_output', Transition.TRANSITION_ACTIVATE)[0]
    rig.assert_stays_vented(QUIET_S, 'active, no command since activation')
    assert transition(probe, 'plc_output', Transition.TRANSITION_DEACTIVATE)[0]
    assert rig.graph.stop('plc_output', signal.SIGINT, EXIT_DEADLINE_S) == 0
    assert not np.any(rig.registers())


def test_pressure_controller_guides_only_while_active_and_refuses_a_bad_file(tmp_path):
    graph = Graph(tmp_path / 'logs')
    probe = None
    try:
        bad = tmp_path / 'bad.yaml'
        bad.write_text('wearer: [\n')
        graph.start('pressure_controller', PARAMS_FILES, autostart=False,
                    calibration_file=str(bad))
        probe = Probe(graph.domain_id)
        commands = probe.subscribe(Float64MultiArray, PRESSURE_COMMAND, COMMAND_QOS)
        diagnostics = probe.subscribe(DiagnosticArray, DIAGNOSTICS, COMMAND_QOS)
        ok, dt = transition(probe, 'pressure_controller', Transition.TRANSITION_CONFIGURE)
        assert not ok, 'configure must fail on an unreadable calibration file'
        assert state(probe, 'pressure_controller') == 'unconfigured'

        def configure_error():
            for msg in diagnostics:
                for s in msg.status:
                    values = {kv.key: kv.value for kv in s.values}
                    if s.name.startswith('pressure_controller') and 'bad.yaml' in values.get('configure error', ''):
                        return s
        status = wait_until(configure_error, STARTUP_DEADLINE_S, what='the configure error on /diagnostics')
        assert status.level == DiagnosticStatus.ERROR and 'unconfigured' in status.message, status
        assert not commands, 'an unconfigured controller commands nothing'
        assert graph.processes['pressure_controller'].poll() is None, 'a failed configure keeps the node up'
        assert graph.stop('pressure_controller', signal.SIGINT, EXIT_DEADLINE_S) == 0
        probe.close()
        probe = None

        graph.start('pressure_controller', PARAMS_FILES, as_name='pressure_controller_good', autostart=False)
        probe = Probe(graph.domain_id)
        commands = probe.subscribe(Float64MultiArray, PRESSURE_COMMAND, COMMAND_QOS)
        parameters = probe.subscribe(String, CONTROLLER_PARAMETERS, LATCHED_QOS)
        assert transition(probe, 'pressure_controller', Transition.TRANSITION_CONFIGURE)[0]
        wait_until(lambda: parameters, STARTUP_DEADLINE_S, what='controller_parameters once configured')
        refused = probe.call(SetBool, ENABLE, SetBool.Request(data=True))
        assert not refused.success and 'inactive' in refused.message, refused
        time.sleep(QUIET_S)
        assert not commands, 'an inactive controller does not step'
        assert transition(probe, 'pressure_controller', Transition.TRANSITION_ACTIVATE)[0]
        wait_until(lambda: len(commands) > 5, STARTUP_DEADLINE_S, what='commands once active (the control timer)')
        ok, dt = transition(probe, 'pressure_controller', Transition.TRANSITION_DEACTIVATE)
        assert ok
        TIMES.record('pressure_controller deactivate (answer)', dt, TRANSITION_DEADLINE_S)
        time.sleep(3 / 50.0)
        n = len(commands)
        assert not np.any(commands[-1].data), 'the last command out of active is a vent'
        time.sleep(QUIET_S)
        assert len(commands) == n, 'an inactive controller stays silent (plc_output times out to a vent)'
    finally:
        if probe is not None:
            probe.close()
        graph.stop_all(check=False)


def test_an_operators_vent_holds_through_deactivate_and_activate(tmp_path):
    """A controller that guides once active (start_enabled true, the simulated graph's) is vented
    by the operator, then deactivated and activated: it stays vented with gaze and target
    present until the operator's enable."""
    from std_srvs.srv import Trigger
    from test_node_pressure_controller import SIM_CAL, FakeUpstream, channels_equal
    graph = Graph(tmp_path / 'logs')
    probe = upstream = None
    try:
        graph.start('pressure_controller', PARAMS_FILES, calibration_file='config/calibrations/sim-wearer.yaml',
                    calibration_dir=str(tmp_path / 'cal'), stall_timeout_s=0.0,
                    target_publisher='test_probe')   # the probe plays target_selector (FakeUpstream)
        probe = Probe(graph.domain_id)
        commands = probe.subscribe(Float64MultiArray, PRESSURE_COMMAND, COMMAND_QOS)
        upstream = FakeUpstream(probe)
        f40 = SIM_CAL.laws[0].pressure(40.0)
        upstream.activate('t1', 40.0)
        wait_until(lambda: channels_equal(probe, {'L1': f40, 'L2': f40}), 30.0, what='guiding')
        t0 = time.monotonic()
        assert probe.call(Trigger, VENT, Trigger.Request()).success
        wait_until(lambda: channels_equal(probe, {}), 1.0, what='vented by the service')
        TIMES.record('pressure_controller vent -> zeros published', time.monotonic() - t0, 1.0)
        assert transition(probe, 'pressure_controller', Transition.TRANSITION_DEACTIVATE)[0]
        assert transition(probe, 'pressure_controller', Transition.TRANSITION_ACTIVATE)[0]
        n = len(commands)
        wait_until(lambda: len(commands) > n + 30, 10.0, what='a second of commands once active again')
        assert all(not np.any(m.data) for m in commands[n:]), 'guiding again without the operator\'s enable'
        assert probe.call(SetBool, ENABLE, SetBool.Request(data=True)).success
        wait_until(lambda: channels_equal(probe, {'L1': f40, 'L2': f40}), 10.0, what='guiding once enabled')
    finally:
        if upstream is not None:
            upstream.close()
        if probe is not None:
            probe.close()
        graph.stop_all(check=False)


def test_a_transition_that_raises_goes_through_error_processing_and_releases():
    """rclpy turns an exception in a transition into error processing: ManagedNode releases
    (vents) there and ends unconfigured, from where configure works again."""
    import rclpy
    from rclpy.context import Context
    from rclpy.lifecycle import TransitionCallbackReturn
    from fabric_guidance.nodes.managed import ManagedNode
    from fabric_guidance.graph.process_graph import fresh_domain_id

    class Flaky(ManagedNode):
        def __init__(self, **kwargs):
            super().__init__('flaky', **kwargs)
            self.calls, self.fail_activate = [], True

        def configure(self):
            self.calls.append('configure')

        def activate(self):
            self.calls.append('activate')
            if self.fail_activate:
                raise RuntimeError('valve driver fault')

        def deactivate(self):
            self.calls.append('deactivate')

        def release(self):
            self.calls.append('release')

    context = Context()
    rclpy.init(context=context, domain_id=fresh_domain_id())
    try:
        node = Flaky(context=context)
        assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS and node.state_label == 'inactive'
        assert node.trigger_activate() == TransitionCallbackReturn.ERROR
        assert node.calls == ['configure', 'activate', 'release'] and not node.active
        assert node.state_label == 'unconfigured' and node._state_machine.current_state[1] == 'unconfigured'
        node.fail_activate = False
        assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS
        assert node.trigger_activate() == TransitionCallbackReturn.SUCCESS and node.active
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def test_the_managed_nodes_are_the_interfaces():
    """One list: the nodes that are ManagedNodes are interface.MANAGED_NODES (launch files and the
    security policy read it)."""
    import importlib
    from fabric_guidance.interface import MANAGED_NODES
    from fabric_guidance.nodes.managed import ManagedNode
    from test_node_imports import lab_nodes
    managed = set()
    for name in lab_nodes():
        module = importlib.import_module(f'fabric_guidance.nodes.{name}')
        if any(isinstance(v, type) and issubclass(v, ManagedNode) and v is not ManagedNode
               for v in vars(module).values()):
            managed.add(name)
    assert managed == set(MANAGED_NODES)
