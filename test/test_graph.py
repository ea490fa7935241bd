"""The lab graph end to end, as separate processes with the package's parameter files (what
launch/guidance.launch.py starts, against mock_plc): UDP gaze datagrams in, the mock PLC's
holding registers read back over Modbus out. Also `fabric-guidance demo` as the user runs it.
"""
import os
import signal
import socket
import subprocess
import sys
import time

import pytest
from std_msgs.msg import Float64MultiArray

from fabric_guidance.core import Calibration, ChannelMap
from fabric_guidance.core.gaze_wire import encode_datagram
from fabric_guidance.graph.process_graph import processes_with
from fabric_guidance.nodes import qos
from fabric_guidance.plc import PlcClient, RegisterMap
from rosgraph import CONFIG, ROOT, Graph, Probe, free_port, wait_until
from senders import PeriodicSender

pytestmark = pytest.mark.graph  # starts a process graph with DDS

CMAP = ChannelMap.load(CONFIG / 'hardware/channel_map.yaml')
REGMAP = RegisterMap.load(CONFIG / 'hardware/plc_register_map.yaml', expected_channels=CMAP.channels)
SIM_CAL = 'config/calibrations/sim-wearer.yaml'
F_LEFT_40 = Calibration.load(CONFIG / 'calibrations' / 'sim-wearer.yaml').laws[0].pressure(40.0)
P_MAX = 375.0
RESOLUTION_KPA = 1.0 / REGMAP.counts_per_kpa
# Deadlines, measured at the mock PLC's registers:
#   gaze stops -> controller vents after gaze_timeout_s (0.3) + a control step (1/30 s), then
#   plc_output writes within a cycle (1/50 s); DDS delivery and polling margin on top.
GAZE_STALE_VENT_S = 0.3 + 1 / 30 + 1 / 50 + 0.6
#   plc_output killed -> the mock PLC's watchdog (watchdog_s 0.5) vents at its next scan (1/100 s).
WATCHDOG_VENT_S = 0.5 + 1 / 100 + 0.5
#: The environment variable that marks the processes of one `fabric-guidance demo` run.
DEMO_MARK = 'FABRIC_GUIDANCE_TEST_DEMO'


class HoloLensStub(PeriodicSender):
    """Sends gaze datagrams (wire format v1, Unity frame) at 60 Hz: the wearer looks ahead."""

    period_s = 1 / 60

    def __init__(self, port):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.port, self.seq = port, 0
        self.start()

    def datagram(self) -> bytes:
        return encode_datagram(self.seq, time.monotonic(), (0.0, 1.2, 0.0), (0.0, 0.0, 1.0),
                               (0.0, 1.2, 0.0), (0.0, 0.0, 0.0, 1.0), True)

    def tick(self):
        if self.sending.is_set():
            self.sock.sendto(self.datagram(), ('127.0.0.1', self.port))
            self.seq += 1

    def close(self):
        super().close()
        self.sock.close()


class RegisterWatch:
    """Reads the mock PLC's holding registers over Modbus, remembering the largest value seen."""

    def __init__(self, port):
        self.client = PlcClient(REGMAP, '127.0.0.1', port, timeout_s=0.5)
        self.highest = 0.0

    def read(self) -> dict:
        values = self.client.read_commands_kpa()
        self.highest = max(self.highest, float(values.max()))
        return dict(zip(REGMAP.names, values))

    def matches(self, expected: dict) -> bool:
        try:
            now = self.read()
        except Exception:  # the PLC side restarting: not yet
            return False
        return all(abs(now[c] - expected.get(c, 0.0)) <= RESOLUTION_KPA for c in REGMAP.names)


@pytest.fixture
def lab_graph(tmp_path):
    plc_port, gaze_port = free_port(), free_port(socket.SOCK_DGRAM)
    graph = Graph(tmp_path / 'logs')
    files = ('params/guidance.yaml', 'params/sim.yaml')
    graph.start('mock_plc', files, port=plc_port)
    graph.start('plc_output', files, plc_port=plc_port)
    graph.start('gaze_bridge', files, port=gaze_port)
    graph.start('target_selector', files, target_names=['left40'], target_positions=[1.5321, 1.2856, 1.2],
                auto_advance=False)
    # stall_timeout_s 0: the stub's gaze never moves (no-progress vent: test_node_pressure_controller).
    graph.start('pressure_controller', files, calibration_file=SIM_CAL, calibration_dir=str(tmp_path / 'cal'),
                stall_timeout_s=0.0)
    hololens = HoloLensStub(gaze_port)
    watch = RegisterWatch(plc_port)
    probe = Probe(graph.domain_id)
    try:
        yield graph, hololens, watch, probe
    finally:
        probe.close()
        hololens.close()
        watch.client.close()  # before the mock PLC's shutdown, which waits for its clients to leave
        graph.stop_all()


def end_to_end(graph, hololens, watch) -> tuple[float, float]:
    """Guidance reaches the PLC; the gaze stopping vents; SIGKILL of plc_output lets the PLC's
    watchdog vent. Returns the two vent times. Also run with the graph split over two network
    namespaces (test_netns.py)."""
    guided = {'L1': F_LEFT_40, 'L2': F_LEFT_40}
    wait_until(lambda: watch.matches(guided), 30.0,
               what=f'L1, L2 at the calibrated f_left(40) = {F_LEFT_40:.1f} kPa and every other register at 0')

    hololens.sending.clear()
    t0 = time.monotonic()
    wait_until(lambda: watch.matches({}), GAZE_STALE_VENT_S, what='every register at 0 after the gaze stopped')
    stale_vent = time.monotonic() - t0

    hololens.sending.set()
    wait_until(lambda: watch.matches(guided), 10.0, what='guidance back with the gaze')

    graph.processes['plc_output'].send_signal(signal.SIGKILL)
    t0 = time.monotonic()
    wait_until(lambda: watch.matches({}), WATCHDOG_VENT_S, what="the mock PLC's watchdog venting every register")
    watchdog_vent = time.monotonic() - t0

    print(f'\ngaze stopped -> vented in {stale_vent:.3f} s (deadline {GAZE_STALE_VENT_S:.2f} s); '
          f'plc_output killed -> watchdog vented in {watchdog_vent:.3f} s (deadline {WATCHDOG_VENT_S:.2f} s)')
    assert watch.highest <= P_MAX
    return stale_vent, watchdog_vent


def test_target_40_left_reaches_the_plc_and_every_fault_vents(lab_graph):
    graph, hololens, watch, probe = lab_graph
    max_written = probe.subscribe(Float64MultiArray, 'mock_plc/max_written_kpa', qos.COMMAND_QOS)
    end_to_end(graph, hololens, watch)
    wait_until(lambda: max_written, 5.0, what='the mock PLC reporting its largest writes')
    assert max(max_written[-1].data) <= P_MAX
    assert max(max_written[-1].data) == pytest.approx(F_LEFT_40, abs=RESOLUTION_KPA)


def test_demo_runs_the_whole_simulated_graph(tmp_path):
    """`fabric-guidance demo` (= make demo): every target found, nothing over P_MAX, vented at
    the end, no process left behind."""
    t0 = time.monotonic()
    # Every process the demo starts inherits this mark: the check below finds its processes and
    # no other graph's (tests of other pytest-xdist workers run theirs from the same files).
    mark = f'{os.getpid()}-{time.monotonic_ns()}'
    out = subprocess.run([sys.executable, '-m', 'fabric_guidance.commands.cli', 'demo', '--out', str(tmp_path)],
                         capture_output=True, text=True, timeout=120, cwd=ROOT, env={**os.environ, DEMO_MARK: mark})
    elapsed = time.monotonic() - t0
    assert out.returncode == 0, out.stdout + out.stderr
    assert '4 of 4 targets found' in out.stdout
    assert 'after shutdown the PLC registers read 0.0 kPa at most' in out.stdout
    print(f'demo took {elapsed:.1f} s')   # its own --timeout bounds it; speed belongs to make bench
    leftovers = processes_with(DEMO_MARK, mark)
    assert not leftovers, f'processes left behind: {leftovers}'
