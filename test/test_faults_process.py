"""Process faults in the lab graph, each with its deadline measured at the mock PLC's registers.

One graph for the whole module (mock_plc, plc_output, gaze_bridge, target_selector,
pressure_controller as processes with guidance.yaml and sim.yaml, a HoloLens stub sending
gaze datagrams): every test starts from the wearer being guided to a target 40 deg left
(L1, L2 at the calibrated pressure), injects one fault, measures the time until every
register reads 0, and brings the killed or stopped node back for the next test.

The mock PLC's watchdog is set far longer than any deadline here, so every vent measured in
this module comes from the package's nodes, never from the PLC side. The watchdog itself is
tested in test_graph.py and test_node_plc.py (SIGKILL of plc_output); a gaze stream that
stops in test_graph.py. Worst times are printed at the end (run with -s or -rP).
"""
import json
import signal
import time

import pytest

from deadlines import DeadlineLog
from fabric_guidance.lab.lab_network import profile_variable
from fabric_guidance.plc.records import load_records
from rosgraph import CONFIG, Graph, free_port, wait_until
from guided_lab import GUIDED, GuidedLab, guided_overrides, guided_until_closed
from test_graph import F_LEFT_40, GAZE_STALE_VENT_S, HoloLensStub, encode_datagram
import socket

pytestmark = pytest.mark.graph  # starts a process graph with DDS

#: Far longer than any test here: the PLC side never vents in this module.
MOCK_WATCHDOG_S = 60.0
COMMAND_TIMEOUT_S = 0.5     # plc_output, guidance.yaml
POLL_S = 0.01

# ---- deadlines, from the fault to every register at 0
#: The controller publishes zeros as it exits; plc_output writes them within a cycle.
CONTROLLER_SIGNAL_VENT_S = 1.0
#: plc_output writes zeros itself as it exits (one spin, one Modbus round trip, slack).
PLC_OUTPUT_SIGNAL_VENT_S = 2.0
#: The selector announces no target as it exits; the controller vents at its next step.
SELECTOR_SIGNAL_VENT_S = 1.0
#: The bridge exits (receive timeout 0.1 s), then the gaze goes stale at the controller.
BRIDGE_SIGNAL_VENT_S = 0.2 + GAZE_STALE_VENT_S
#: SIGKILL of the controller: plc_output's command_timeout_s, a write cycle, delivery slack.
CONTROLLER_KILL_VENT_S = COMMAND_TIMEOUT_S + 1 / 50 + 0.5
#: Only invalid or malformed gaze datagrams: as if the gaze had stopped.
INVALID_GAZE_VENT_S = GAZE_STALE_VENT_S
#: A signal -> the process has exited (with code 0).
EXIT_DEADLINE_S = 10.0
#: A node restarted -> guidance back at the registers (cold start of a process, 2 loaded cores).
RESTART_DEADLINE_S = 30.0
#: The mock PLC restarted (listening) -> the latest command back: plc_output's longest backoff.
MOCK_RECONNECT_DEADLINE_S = 5.0 + 2.0

LOG = DeadlineLog('process')
record = LOG.record


class Stub(HoloLensStub):
    """The HoloLens stub with a switch: 'valid' samples, 'invalid' (eye tracking not valid),
    or 'junk' (malformed datagrams)."""

    kind = 'valid'

    def datagram(self) -> bytes:
        if self.kind == 'junk':
            return b'{"version":1,"seq":' + str(self.seq).encode() + b',"stamp":NaN}'
        return encode_datagram(self.seq, time.monotonic(), (0.0, 1.2, 0.0), (0.0, 0.0, 1.0),
                               (0.0, 1.2, 0.0), (0.0, 0.0, 0.0, 1.0), self.kind == 'valid')


class Lab(GuidedLab):
    def __init__(self, log_dir):
        self.plc_port, self.gaze_port = free_port(), free_port(socket.SOCK_DGRAM)
        self.graph = Graph(log_dir)
        self.overrides = {'mock_plc': dict(port=self.plc_port, watchdog_s=MOCK_WATCHDOG_S),
                          **guided_overrides(log_dir, self.plc_port, self.gaze_port)}
        self.start_all(Stub)

    def guided(self, deadline_s=RESTART_DEADLINE_S, what='guidance at the registers'):
        self.hololens.kind = 'valid'
        wait_until(lambda: self.watch.matches(GUIDED), deadline_s, what=f'{what}: L1, L2 at {F_LEFT_40:.1f} kPa')

    def time_to_vent(self, t0, deadline_s, what):
        last = None
        while True:
            try:
                now_regs = self.watch.read()
                last = now_regs
                if not any(now_regs.values()):
                    return time.monotonic() - t0
            except Exception:  # noqa: BLE001 - the PLC side restarting
                pass
            if time.monotonic() - t0 > deadline_s:
                raise AssertionError(f'{what}: registers not vented {time.monotonic() - t0:.3f} s after the fault '
                                     f'(deadline {deadline_s:.3f} s); last read {last}')
            time.sleep(POLL_S)

    def watchdog_trips(self):
        return load_records(self.graph.records_files[-1])['watchdog_trips']

    def close(self):
        self.hololens.close()
        self.watch.client.close()  # first: the mock PLC's shutdown waits for its clients to leave
        self.graph.stop_all()


@pytest.fixture(scope='module')
def lab(tmp_path_factory):
    with guided_until_closed(Lab(tmp_path_factory.mktemp('process_faults')), LOG,
                             'worst times, process faults') as lab:
        yield lab


@pytest.mark.parametrize('kind', ['invalid', 'junk'])
def test_only_invalid_gaze_samples_vent(lab, kind):
    lab.guided()
    t0 = time.monotonic()
    lab.hololens.kind = kind
    seconds = lab.time_to_vent(t0, INVALID_GAZE_VENT_S, f'only {kind} gaze datagrams')
    record(f'only {kind} gaze datagrams', seconds, INVALID_GAZE_VENT_S)
    lab.guided(10.0, 'guidance back with valid samples')


def test_sigkill_of_the_controller_lets_plc_output_vent_the_stale_command(lab):
    lab.guided()
    trips = lab.watchdog_trips()
    proc = lab.graph.processes['pressure_controller']
    t0 = time.monotonic()
    proc.kill()
    seconds = lab.time_to_vent(t0, CONTROLLER_KILL_VENT_S, 'SIGKILL of pressure_controller')
    record('SIGKILL of pressure_controller (plc_output: stale command)', seconds, CONTROLLER_KILL_VENT_S)
    assert proc.wait(EXIT_DEADLINE_S) == -signal.SIGKILL
    assert lab.watchdog_trips() == trips, 'the PLC watchdog vented, not plc_output'
    lab.start('pressure_controller')
    lab.guided(what='guidance back with a new pressure_controller')


VENT_DEADLINES = {'pressure_controller': CONTROLLER_SIGNAL_VENT_S, 'plc_output': PLC_OUTPUT_SIGNAL_VENT_S,
                  'target_selector': SELECTOR_SIGNAL_VENT_S, 'gaze_bridge': BRIDGE_SIGNAL_VENT_S}


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
@pytest.mark.parametrize('node', list(VENT_DEADLINES))
def test_a_signal_to_any_node_vents_and_it_exits_0(lab, node, sig):
    lab.guided()
    trips = lab.watchdog_trips()
    proc = lab.graph.processes[node]
    t0 = time.monotonic()
    proc.send_signal(sig)
    deadline = VENT_DEADLINES[node]
    seconds = lab.time_to_vent(t0, deadline, f'{sig.name} of {node}')
    record(f'{sig.name} of {node}', seconds, deadline)
    assert proc.wait(EXIT_DEADLINE_S) == 0, lab.graph.log(node)
    record(f'{sig.name} of {node}: exit 0', time.monotonic() - t0, EXIT_DEADLINE_S)
    assert lab.watchdog_trips() == trips, 'the PLC watchdog vented, not the graph'
    lab.start(node)
    lab.guided(what=f'guidance back with a new {node}')


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
def test_the_mock_plc_restarts_mid_session_and_plc_output_reconnects(lab, sig):
    lab.guided()
    proc = lab.graph.processes['mock_plc']
    t0 = time.monotonic()
    proc.send_signal(sig)
    assert proc.wait(EXIT_DEADLINE_S) == 0, lab.graph.log('mock_plc')
    record(f'{sig.name} of mock_plc: exit 0', time.monotonic() - t0, EXIT_DEADLINE_S)
    records = load_records(lab.graph.records_files[-1])
    lab.start('mock_plc')
    wait_until(lambda: _listening(lab.plc_port), 20.0, what='the restarted mock PLC listening')
    t_up = time.monotonic()
    lab.guided(MOCK_RECONNECT_DEADLINE_S, 'the latest command back in the restarted PLC')
    record('mock_plc restarted -> plc_output reconnected, command back', time.monotonic() - t_up,
           MOCK_RECONNECT_DEADLINE_S)
    assert records['writes'] > 0, json.dumps(records)


def _listening(port):
    with socket.socket() as s:
        s.settimeout(0.2)
        return s.connect_ex(('127.0.0.1', port)) == 0


def test_every_node_of_the_graph_keeps_dds_discovery_on_localhost(lab):
    for node, proc in lab.graph.processes.items():
        environ = dict(item.split('=', 1) for item in
                       open(f'/proc/{proc.pid}/environ').read().split('\0') if '=' in item)
        assert environ.get(profile_variable()) == str(CONFIG / 'fastdds_loopback.xml'), node
        assert environ.get('ROS_DOMAIN_ID') == str(lab.graph.domain_id), node
