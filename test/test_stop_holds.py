"""A stop is a stop for the whole system (docs/safety.md, "Latches and limits"), on the graph, with
the mock PLC's holding registers read over Modbus by a client of the test's own (never the
nodes' view):

- an outside `vent` (a safety officer's `ros2 service call`) in a trial of the simulated study:
  the registers go to 0 and stay there through the session's next rest and trial time; the
  session ends the trial 'vented', says so and waits; the operator's key e arms and resumes it;
- the controller killed between trials and respawned disarmed (start_enabled false, as the lab
  launch runs it): the session's next trial does not put pressure on the registers; it waits;
- p_max_kpa lowered at run time, the controller killed and respawned: the operator's next
  enable guides under the lowered limit, and the diagnostics say it is held.
"""
import contextlib
import dataclasses
from pathlib import Path
import signal
import socket
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
import yaml
from std_srvs.srv import SetBool, Trigger

from fabric_guidance import interface
from fabric_guidance.core import ChannelMap
from fabric_guidance.plc import PlcClient, RegisterMap
from rosgraph import CONFIG, Graph, Probe, free_port, wait_until
from test_graph import F_LEFT_40, RESOLUTION_KPA, HoloLensStub

pytestmark = pytest.mark.graph

CMAP = ChannelMap.load(CONFIG / 'hardware/channel_map.yaml')
REGMAP = RegisterMap.load(CONFIG / 'hardware/plc_register_map.yaml', expected_channels=CMAP.channels)
#: A register above this counts as pressurised [kPa] (the register resolution is far below it).
ON_KPA = 1.0
#: An outside vent -> every register at 0: the controller's zeros, plc_output's next write
#: cycle (1/50 s), DDS and the read's poll on a loaded machine.
VENT_DEADLINE_S = 1.0
#: The registers are read every POLL_S while they must stay at 0.
POLL_S = 0.01
#: The study's trials here [s]; its rests are StudyDesign's 3 s.
TRIAL_S = 5.0
REST_S = 3.0
#: The rest after which the restarted controller's trial comes: long enough for the respawned
#: process to be up and discovered (a request sent while only the dead server is known is lost).
RESTART_REST_S = 8.0
#: Graph start-up and the first trial under pressure (discovery, seven processes, a loaded machine).
STARTUP_S = 90.0


class Registers:
    """The mock PLC's command registers, read over Modbus by the test's own client."""

    def __init__(self, port: int):
        self.client = PlcClient(REGMAP, '127.0.0.1', port, timeout_s=0.5)

    def read(self) -> np.ndarray | None:
        try:
            return self.client.read_commands_kpa()
        except Exception:  # noqa: BLE001 - the PLC side restarting: no value this time
            self.client.close()
            return None

    def pressurised(self) -> bool:
        r = self.read()
        return r is not None and float(r.max()) > ON_KPA

    def zero(self) -> bool:
        r = self.read()
        return r is not None and not np.any(r)

    def hold_zero(self, seconds: float, what: str) -> int:
        """Every read for `seconds` is all zeros; returns the number of reads."""
        end, reads = time.monotonic() + seconds, 0
        while time.monotonic() < end:
            r = self.read()
            if r is not None:
                assert not np.any(r > ON_KPA), f'{what}: registers read {dict(zip(REGMAP.names, r))}'
                reads += 1
            time.sleep(POLL_S)
        return reads

    def zero_for(self, seconds: float):
        """A predicate: every read all zeros for the last `seconds`."""
        since = [None]

        def check():
            now = time.monotonic()
            if not self.zero():
                since[0] = None
                return False
            since[0] = since[0] or now
            return now - since[0] >= seconds
        return check

    def hold_zero_until(self, predicate, deadline_s: float, what: str) -> int:
        """Every read is all zeros until predicate() (AssertionError after deadline_s); the reads."""
        end, reads = time.monotonic() + deadline_s, 0
        while not predicate():
            assert time.monotonic() < end, f'{what}: not within {deadline_s:g} s'
            reads += self.hold_zero(POLL_S, what)
        return reads

    def close(self):
        self.client.close()


def speed_scene(tmp_path: Path, trials: int):
    from fabric_guidance.sim.scene import load_scene, scene_path
    data = yaml.safe_load(scene_path('paper-speed').read_text())
    data.update(conditions=[1], repetitions=trials)
    data['protocol']['trial_s'] = TRIAL_S
    path = tmp_path / 'scene.yaml'
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return load_scene(path)


class StudyRun:
    """The simulated study's participant graph (its operator arms once at start), the session's
    driver on a thread, the registers read over Modbus."""

    def __init__(self, tmp_path: Path, trials: int, supervise: bool = False, rest_s: float = REST_S):
        from fabric_guidance.live_study.driver import SessionDriver
        from fabric_guidance.live_study.simulated import SimulatedParticipant, design_of
        from fabric_guidance.study.plan import participant_blocks
        from fabric_guidance.study.session import Session
        from fabric_guidance.study.store import Study
        scene = speed_scene(tmp_path, trials)
        design = dataclasses.replace(design_of(scene), rest_s=rest_s)
        blocks = participant_blocks(design, '01', 0)
        study = Study.open(tmp_path / 'study')
        study.add_participant('01')
        self.store = study.session('01', 1, design)
        self.lines: list[str] = []
        self.part = SimulatedParticipant(scene, 0, blocks[0].condition, tmp_path / 'graph', self.lines.append, design)
        # As the lab launch runs it: every start of the controller, respawns included, disarmed.
        self.part.lab.overrides['pressure_controller']['start_enabled'] = False
        self.registers = None
        self.errors: list[BaseException] = []
        self.part.start()
        if supervise:
            self.part.graph.supervise('pressure_controller')
        self.registers = Registers(self.part.lab.plc_port)
        op = self.part.op
        self.session = Session(design, blocks, {'gaze_source': 'wearer_sim'})
        self.driver = SessionDriver(op, self.session, self.store, self.lines.append,
                                    before_trial=lambda c, r: op.set_parameters('wearer_sim', condition=c,
                                                                                repetition=r))
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        try:
            self.driver.run()
        except BaseException as exc:  # noqa: BLE001 - the test says what it was
            self.errors.append(exc)

    def rows(self) -> list[dict]:
        return self.driver.rows

    def text(self) -> str:
        return '\n'.join(self.lines)

    def operator_arms(self):
        """The operator's key e at the session's terminal."""
        from fabric_guidance.live_study.live_session import operator_keys
        operator_keys(self.part.op, self.driver, self.lines.append)('arm')

    def close(self):
        if self.thread.is_alive():
            self.driver.command('stop')
            self.thread.join(20)
        if self.registers is not None:
            self.registers.close()
        self.part.close()


@pytest.fixture
def study_run(tmp_path):
    made = []

    def make(**kw):
        made.append(StudyRun(tmp_path, **kw))
        return made[-1]
    yield make
    for run in made:
        run.close()


def test_an_outside_vent_mid_trial_holds_through_the_sessions_next_trial_until_the_operator_arms(study_run):
    run = study_run(trials=2)
    reg = run.registers
    wait_until(lambda: run.errors or (run.session.phase in ('target', 'front') and reg.pressurised()), STARTUP_S,
               POLL_S, what='trial 1 under pressure at the registers')
    assert not run.errors, run.errors
    # A safety officer's `ros2 service call .../vent`, from a node of their own.
    with Probe(run.part.graph.domain_id, 'safety_officer') as officer:
        officer._client(Trigger, interface.VENT, 10.0)      # discovered: the time below is the vent's
        t0 = time.monotonic()
        assert officer.call(Trigger, interface.VENT, Trigger.Request()).success
    wait_until(reg.zero, VENT_DEADLINE_S, POLL_S, what='every register at 0 after the outside vent')
    vented_s = time.monotonic() - t0
    # Through the rest of trial 1, the rest and what would have been trial 2: nothing on the registers.
    reads = reg.hold_zero(TRIAL_S + REST_S + 3.0, 'after the outside vent, before the operator armed')
    assert reads > 100
    assert run.session.phase == 'held' and not run.errors, (run.session.phase, run.errors)
    assert [r['status'] for r in run.rows()] == ['vented'], run.rows()
    assert "STOPPED: the operator's arm dropped" in run.text() and 'press e to arm' in run.text(), run.text()
    # The operator's key e: enable, then the session goes on; trial 1 runs again, then trial 2.
    run.operator_arms()
    wait_until(reg.pressurised, 30.0, POLL_S, what='guidance back after the operator armed')
    run.thread.join(2 * (TRIAL_S + REST_S) + 30.0)
    assert not run.thread.is_alive() and not run.errors, run.errors
    assert [r['status'] for r in run.rows()] == ['vented', 'ok', 'ok'], run.rows()
    print(f'\noutside vent -> registers at 0 in {vented_s:.3f} s; held {reads} reads at 0 until the operator armed')


def test_a_controller_restarted_between_trials_waits_for_the_operator_not_the_session(study_run):
    run = study_run(trials=2, supervise=True, rest_s=RESTART_REST_S)
    reg = run.registers
    graph = run.part.graph
    wait_until(lambda: run.errors or run.rows(), STARTUP_S, POLL_S, what='trial 1 finished')
    assert not run.errors, run.errors
    with Probe(graph.domain_id, 'lab_watch') as watch:
        diagnostics = watch.subscribe(DiagnosticArray, interface.DIAGNOSTICS, 10)
        wait_until(lambda: _guidance_values(diagnostics), 10.0, what="the controller's diagnostics")
        graph.processes['pressure_controller'].send_signal(signal.SIGKILL)
        killed = time.monotonic()
        wait_until(lambda: graph.restart_count('pressure_controller') == 1, 10.0, what='the controller respawned')
        since = len(diagnostics)
        # Until the respawned controller is up (its own diagnostics), then the session's trial 2
        # time (due REST_S after trial 1; its gate opens on a disarmed controller) and more.
        reads = reg.hold_zero_until(
            lambda: _guidance_values(diagnostics[since:]).get('lifecycle state') == 'active', 60.0,
            'the respawned controller active, registers at 0 meanwhile')
    reads += reg.hold_zero(RESTART_REST_S + TRIAL_S, 'after the restart, before the operator armed')
    assert reads > 100
    assert run.session.phase == 'held' and not run.errors, (run.session.phase, run.errors, run.text())
    assert 'STOPPED: ' in run.text() and 'press e to arm' in run.text(), run.text()
    assert [r['status'] for r in run.rows()].count('ok') == 1, run.rows()
    held_s = time.monotonic() - killed
    run.operator_arms()
    wait_until(reg.pressurised, 30.0, POLL_S, what='guidance back after the operator armed')
    run.thread.join(2 * (TRIAL_S + RESTART_REST_S) + 30.0)
    assert not run.thread.is_alive() and not run.errors, run.errors
    assert [r['status'] for r in run.rows()].count('ok') == 2, run.rows()
    print(f'\ncontroller killed; registers at 0 for the {held_s:.1f} s until the operator armed')


# ------------------------------------------------------------------------- a limit held across a restart
def _guidance_values(diagnostics) -> dict:
    for msg in reversed(diagnostics):
        for st in msg.status:
            if st.name.startswith('pressure_controller'):
                return {'message': st.message, **{kv.key: kv.value for kv in st.values}}
    return {}


@contextlib.contextmanager
def lab_graph(tmp_path, selector=None):
    """The lab graph against the mock PLC, the controller disarmed at every start (the lab
    launch's way) and respawned when it dies; the stub headset looks ahead, the target is 40 deg
    left; a probe for the operator and the diagnostics; the registers read over Modbus."""
    plc_port, gaze_port = free_port(), free_port(socket.SOCK_DGRAM)
    graph = Graph(tmp_path / 'logs')
    files = ('params/guidance.yaml', 'params/sim.yaml')
    hololens = reg = probe = None
    try:
        graph.start('mock_plc', files, port=plc_port)
        graph.start('plc_output', files, plc_port=plc_port)
        graph.start('gaze_bridge', files, port=gaze_port)
        graph.start('target_selector', files, target_names=['left40'], target_positions=[1.5321, 1.2856, 1.2],
                    auto_advance=False, **(selector or {}))
        # stall_timeout_s 0: the stub's gaze never moves
        graph.start('pressure_controller', files, calibration_file='config/calibrations/sim-wearer.yaml',
                    calibration_dir=str(tmp_path / 'cal'), stall_timeout_s=0.0, start_enabled=False)
        graph.supervise('pressure_controller')
        hololens = HoloLensStub(gaze_port)
        reg = Registers(plc_port)
        probe = Probe(graph.domain_id, 'lab_operator')
        diagnostics = probe.subscribe(DiagnosticArray, interface.DIAGNOSTICS, 10)
        yield graph, reg, probe, diagnostics
    finally:
        if probe is not None:
            probe.close()
        if hololens is not None:
            hololens.close()
        if reg is not None:
            reg.close()
        graph.stop_all()


def left(reg, kpa) -> bool:
    """L1, L2 at kpa and every other register at 0."""
    r = reg.read()
    return r is not None and all(abs(v - (kpa if n in ('L1', 'L2') else 0.0)) <= RESOLUTION_KPA
                                 for n, v in zip(REGMAP.names, r))


def enable(probe):
    assert probe.call(SetBool, interface.ENABLE, SetBool.Request(data=True), attempts=3).success


def test_a_lowered_p_max_survives_a_respawn_of_the_controller(tmp_path):
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter
    with lab_graph(tmp_path) as (graph, reg, probe, diagnostics):
        enable(probe)
        wait_until(lambda: left(reg, F_LEFT_40), 30.0, POLL_S, what=f'L1, L2 at f_left(40) = {F_LEFT_40:.0f} kPa')
        request = SetParameters.Request(parameters=[Parameter('p_max_kpa', value=100.0).to_parameter_msg()])
        (result,) = probe.call(SetParameters, '/pressure_controller/set_parameters', request).results
        assert result.successful, result.reason
        wait_until(lambda: left(reg, 100.0), 5.0, POLL_S, what='L1, L2 at the lowered 100 kPa')
        first = graph.processes['pressure_controller'].pid
        graph.processes['pressure_controller'].send_signal(signal.SIGKILL)
        wait_until(lambda: graph.restart_count('pressure_controller') == 1, 10.0, what='the controller respawned')
        assert graph.processes['pressure_controller'].pid != first
        wait_until(reg.zero, 5.0, POLL_S, what='vented after the kill')
        since = len(diagnostics)
        wait_until(lambda: _guidance_values(diagnostics[since:]).get('lifecycle state') == 'active', 30.0,
                   what='the respawned controller active')
        status = _guidance_values(diagnostics[since:])
        reg.hold_zero(1.0, 'the respawned controller before the operator armed')
        enable(probe)
        wait_until(lambda: left(reg, 100.0), 10.0, POLL_S, what='guidance under the held 100 kPa after the enable')
        end, highest = time.monotonic() + 1.0, 0.0
        while time.monotonic() < end:
            r = reg.read()
            highest = max(highest, float(r.max()) if r is not None else 0.0)
            time.sleep(POLL_S)
        assert highest <= 100.0 + RESOLUTION_KPA, highest
        # and it said so from its start
        assert status.get('armed') == 'False' and status.get('p_max_kpa') == '100', status
        assert 'held limits: p_max_kpa 100 (parameter 375)' in status['message'], status


def test_a_second_controller_in_the_namespace_is_noticed_and_the_first_vents(tmp_path):
    with lab_graph(tmp_path) as (graph, reg, probe, diagnostics):
        enable(probe)
        wait_until(lambda: left(reg, F_LEFT_40), 30.0, POLL_S, what=f'L1, L2 at f_left(40) = {F_LEFT_40:.0f} kPa')
        # A second process named pressure_controller in the same namespace (a second launch, a
        # stray terminal), started disarmed as the lab launch starts every controller.
        graph.start('pressure_controller', ('params/guidance.yaml', 'params/sim.yaml'), as_name='second_controller',
                    calibration_file='config/calibrations/sim-wearer.yaml', stall_timeout_s=0.0,
                    start_enabled=False)
        # Its start and discovery (seconds on a loaded machine) are not the first's to answer for:
        # the noticing is timed once the graph lists both.
        wait_until(lambda: sum(name == 'pressure_controller' for name, _ in
                               probe.node.get_node_names_and_namespaces()) >= 2,
                   60.0, what='the second pressure_controller on the graph')
        t0 = time.monotonic()
        since = len(diagnostics)
        # Until the first notices, the registers flicker between its pressure and the second's
        # zeros: at 0 for a whole second means the first has stopped.
        wait_until(reg.zero_for(1.0), 20.0, POLL_S, what='every register at 0 for 1 s once the first noticed')
        noticed_s = time.monotonic() - t0 - 1.0
        reg.hold_zero(2.0, 'two controllers in one namespace, the first disarmed')
        wait_until(lambda: any('joined' in st.message for m in diagnostics[since:] for st in m.status
                               if st.name.startswith('pressure_controller')), 5.0,
                   what="the first's diagnostics naming the second")
        print(f'\nsecond controller on the graph -> first disarmed, registers at 0 in {noticed_s:.2f} s')


def test_a_target_from_another_node_never_moves_the_suit(tmp_path):
    from geometry_msgs.msg import PointStamped
    from std_msgs.msg import String
    from fabric_guidance.nodes import qos
    # target_selector waits for next_target: the controller is armed with no active target.
    with lab_graph(tmp_path, selector={'autostart': False}) as (graph, reg, probe, diagnostics):
        enable(probe)
        # A bag played onto the live graph, a stray script: another node publishes both topics.
        with Probe(graph.domain_id, 'rosbag2_player') as foreign:
            name_pub = foreign.node.create_publisher(String, interface.ACTIVE_TARGET, qos.LATCHED_QOS)
            point_pub = foreign.node.create_publisher(PointStamped, interface.TARGET, qos.LATCHED_QOS)
            point = PointStamped()
            point.header.frame_id = interface.IMMERSIVE_FRAME
            point.point.x, point.point.y, point.point.z = 1.5321, 1.2856, 1.2    # 40 deg left
            wait_until(lambda: point_pub.get_subscription_count() >= 1, 20.0, what='the controller hearing the target')
            name_pub.publish(String(data='recorded_target'))
            end, reads = time.monotonic() + 3.0, 0
            while time.monotonic() < end:
                point_pub.publish(point)
                reads += reg.hold_zero(0.1, 'a target published by another node')
            assert reads > 50
        since = len(diagnostics)
        status = wait_until(lambda: _guidance_values(diagnostics[since:]) or None, 5.0, what='diagnostics')
        assert int(status['refused_inputs']) > 0 and 'rosbag2_player' in status['last_input_refusal'], status
