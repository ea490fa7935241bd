"""plc_output and mock_plc as processes: commands on a live topic, real Modbus TCP, venting.

Each graph is a mock_plc and a plc_output process started with the package's parameter files
(guidance.yaml, then sim.yaml) on a free port and their own ROS domain. The test plays the
pressure controller (a probe named pressure_controller publishing pressure_command at 20 Hz,
labelled with the channel order, as the controller does) and looks at the PLC with
its own Modbus client, which only ever reads: every assertion is on the holding registers read
back (or on what the nodes publish), never on a node's internal state. Every wait polls a
condition against a named deadline; vent times are measured and printed (run with -s, or -rP).
"""
import math
import signal
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import pytest
from std_msgs.msg import Float64MultiArray
import yaml

from deadlines import DeadlineLog
from fabric_guidance.core.channels import ChannelMap, label_names, layout_label
from fabric_guidance.interface import DIAGNOSTICS, MEASURED_PRESSURE, PRESSURE_COMMAND
from fabric_guidance.nodes.array_layout import named_layout
from fabric_guidance.nodes.qos import COMMAND_QOS
from fabric_guidance.plc import PlcClient, PlcLinkError, RegisterMap
from fabric_guidance.paths import node_parameters
from rosgraph import CONFIG, Graph, Probe, free_port, wait_until

pytestmark = pytest.mark.graph  # starts a process graph with DDS

PARAMS_FILES = ('params/guidance.yaml', 'params/sim.yaml')


def _parameters(node):
    """The node's parameters as the graph gets them: the files in order, later ones winning."""
    merged = {}
    for name in PARAMS_FILES:
        merged.update(node_parameters(name, node))
    return merged


OUTPUT = _parameters('plc_output')
MOCK = _parameters('mock_plc')
REGISTER_MAP = RegisterMap.load(CONFIG / 'hardware/plc_register_map.yaml')
N = len(REGISTER_MAP)
CHANNELS = ChannelMap.load(CONFIG / 'hardware/channel_map.yaml').channels
#: Every command names its channels, in the configured order (plc_output refuses other orders).
LAYOUT = named_layout(CHANNELS)
P_MAX_KPA = min(OUTPUT['p_max_kpa'], REGISTER_MAP.p_max_kpa)
#: plc_output's command timeout in these rigs [s]: twice the configured one. The rig's controller
#: is a timer thread of the loaded test process; a stall of it over the configured 0.5 s vented a
#: rising command mid-test ("stale command" in plc_output's log), which is the node right.
COMMAND_TIMEOUT_S = 2 * OUTPUT['command_timeout_s']
WATCHDOG_S = MOCK['watchdog_s']
RECONNECT_MAX_S = OUTPUT['reconnect_max_s']
DIAGNOSTICS_PERIOD_S = OUTPUT['diagnostics_period_s']
WRITE_PERIOD_S = 1.0 / OUTPUT['write_rate_hz']

#: One register count is 0.1 kPa; a command must read back within that.
TOLERANCE_KPA = 0.1
#: The test's controller publishes at this rate (faster than 1 / command_timeout_s).
COMMAND_RATE_HZ = 20.0
#: How often the test reads the registers back (the resolution of the measured times).
POLL_S = 0.01

# ---- deadlines
#: Both processes up, PLC link up, the probe matched with plc_output (cold start on 2 cores).
STARTUP_DEADLINE_S = 20.0
#: A published command reaches the registers (DDS delivery + one write cycle + slack).
COMMAND_DEADLINE_S = 2.0
#: Slack on top of a configured time before a vent must be seen: DDS delivery, one write
#: cycle, the read-back poll, a loaded 2-core machine.
VENT_MARGIN_S = 0.5
#: Last command published -> registers vented, when no further command comes.
STALE_VENT_DEADLINE_S = COMMAND_TIMEOUT_S + VENT_MARGIN_S
#: Last valid command published -> registers vented after invalid ones. Shorter than the stale
#: timeout, so a vent in time cannot have come from staleness.
INVALID_VENT_DEADLINE_S = COMMAND_TIMEOUT_S
#: SIGINT of plc_output (closing a rig) -> process gone.
EXIT_DEADLINE_S = 10.0
#: SIGKILL of plc_output -> the mock's heartbeat watchdog vented the registers.
WATCHDOG_VENT_DEADLINE_S = WATCHDOG_S + VENT_MARGIN_S
#: Mock gone -> plc_output reports ERROR on /diagnostics (a request fails, then one period).
LINK_DOWN_DIAGNOSTICS_DEADLINE_S = DIAGNOSTICS_PERIOD_S + 2.0
#: Mock restarted (listening again) -> the latest command back in its registers: the longest
#: backoff, plus a write cycle and slack.
RECONNECT_DEADLINE_S = RECONNECT_MAX_S + 2.0
#: Link back -> /diagnostics OK again.
LINK_UP_DIAGNOSTICS_DEADLINE_S = DIAGNOSTICS_PERIOD_S + 2.0
#: The restarted mock process listens (and publishes its status).
MOCK_START_DEADLINE_S = 10.0
#: A step command -> measured_pressure within MEASURED_TOLERANCE_KPA (regulator tau 0.15 s: ~7 tau).
MEASURED_DEADLINE_S = 3.0
MEASURED_TOLERANCE_KPA = 1.0
#: The restarted link must hold the command this long (the mock's watchdog re-arming
#: zeroes commands written before it has seen a heartbeat change).
HOLD_S = 0.2

OUTPUT_STATUS = 'plc_output: PLC output'
MOCK_STATUS = 'mock_plc: mock PLC'

#: every vent time measured [s]; the worst of each kind is printed at the end of the module.
VENTS = DeadlineLog('vent')
record_vent = VENTS.record


vent_report = VENTS.report_at_module_end(
    'worst vent times (registers read back every %.0f ms)' % (POLL_S * 1e3))


# ---------------------------------------------------------------------- rig
class Rig:
    """A mock_plc and a plc_output process, a probe playing the controller, a read-only client."""

    def __init__(self, log_dir, mock=None, output=None, port=None, wait=True):
        self.port = port or free_port()   # the mock's; plc_output's may be overridden (a proxy)
        self.graph = Graph(log_dir)
        self.mock_overrides = {'port': self.port, **(mock or {})}
        self.output_overrides = {'plc_port': self.port, 'command_timeout_s': COMMAND_TIMEOUT_S, **(output or {})}
        self.start_mock()
        self.graph.start('plc_output', PARAMS_FILES, **self.output_overrides)
        print(f'graph logs: {self.graph.log_dir}')
        # The controller of this graph, as plc_output knows it: a node named pressure_controller.
        self.probe = Probe(self.graph.domain_id, 'pressure_controller')
        node = self.probe.node
        self.measured = self.probe.subscribe(Float64MultiArray, MEASURED_PRESSURE, COMMAND_QOS)
        self.max_written = self.probe.subscribe(Float64MultiArray, 'mock_plc/max_written_kpa', COMMAND_QOS)
        self.diagnostics = self.probe.subscribe(DiagnosticArray, DIAGNOSTICS, COMMAND_QOS)
        self.command_pub = node.create_publisher(Float64MultiArray, PRESSURE_COMMAND, COMMAND_QOS)
        self.client = PlcClient(REGISTER_MAP, '127.0.0.1', self.port, timeout_s=0.5)
        self._lock = threading.Lock()
        self._data = None
        self._layout = LAYOUT
        self.first_publish_s = self.last_publish_s = None
        node.create_timer(1.0 / COMMAND_RATE_HZ, self._publish)
        if wait:   # (an unconfigured lifecycle node has no link yet: its test waits on its own)
            self.wait_ready()

    # ---- the controller's side
    def _publish(self):
        with self._lock:
            if self._data is None:
                return
            self.last_publish_s = time.monotonic()  # taken before publishing: a lower bound
            if self.first_publish_s is None:
                self.first_publish_s = self.last_publish_s
            data, layout = self._data, self._layout
        self.command_pub.publish(Float64MultiArray(layout=layout, data=data))

    def command(self, values, layout=LAYOUT):
        """Publish `values` (with `layout`) from now on, at COMMAND_RATE_HZ; returns when the last
        other command was published (None if none)."""
        with self._lock:
            previous = self.last_publish_s
            self._data = [float(v) for v in values]
            self._layout = layout
            self.first_publish_s = None
            return previous

    def stop_commands(self):
        """Publish nothing more; returns when the last command was published."""
        with self._lock:
            self._data = None
            return self.last_publish_s

    def first_published(self):
        return wait_until(lambda: self.first_publish_s, COMMAND_DEADLINE_S, what='the command to be published')

    # ---- the PLC's side, read back
    def registers(self):
        """Command registers read back (kPa, channel order), None while the mock is unreachable.
        Tried twice: the PLC closes a reader's connection after IDLE_S of silence (as the program
        reaps its sockets), and the first read after such a pause finds it closed."""
        for _ in range(2):
            try:
                return self.client.read_commands_kpa()
            except PlcLinkError:
                self.client.close()
        return None

    def wait_registers(self, expected, deadline_s, what, hold_s=0.0):
        """Wait until the registers read `expected` (within TOLERANCE_KPA), continuously for hold_s."""
        expected = np.asarray(expected, dtype=float)
        since = [None]

        def matches():
            r = self.registers()
            now = time.monotonic()
            if r is None or np.max(np.abs(r - expected)) > TOLERANCE_KPA + 1e-9:
                since[0] = None
                return False
            since[0] = since[0] or now
            return now - since[0] >= hold_s
        try:
            wait_until(matches, deadline_s, POLL_S, what)
        except AssertionError as exc:
            raise AssertionError(f'{exc}; registers read {self.registers()}, expected {expected}') from None
        return time.monotonic()

    def time_to_vent(self, t0, deadline_s, what):
        """Seconds from t0 until the registers read all zero; fails after deadline_s from t0."""
        last = None
        while True:
            r = self.registers()
            now = time.monotonic()
            if r is not None:
                last = r
                if not np.any(r):
                    return now - t0
            if now - t0 > deadline_s:
                raise AssertionError(f'{what}: registers not vented {now - t0:.3f} s after the trigger '
                                     f'(deadline {deadline_s:.3f} s); last read {last}')
            time.sleep(POLL_S)

    def assert_stays_vented(self, duration_s, what):
        """Read the registers for duration_s; every read must be all zero."""
        end = time.monotonic() + duration_s
        while time.monotonic() < end:
            r = self.registers()
            assert r is None or not np.any(r), f'{what}: registers no longer vented: {r}'
            time.sleep(POLL_S)

    # ---- what the nodes publish
    def statuses(self, name, start=0):
        """DiagnosticStatus named `name` in the /diagnostics messages received from index `start`."""
        return [s for msg in self.diagnostics[start:] for s in msg.status if s.name == name]

    def latest_status(self, name, start=0):
        found = self.statuses(name, start)
        return found[-1] if found else None

    # ---- life cycle
    def start_mock(self):
        self.graph.start('mock_plc', PARAMS_FILES, **self.mock_overrides)

    def wait_ready(self):
        deadline = time.monotonic() + STARTUP_DEADLINE_S
        # mock_plc publishes its status only once its Modbus server listens.
        wait_until(lambda: self.max_written, STARTUP_DEADLINE_S, what='mock_plc/max_written_kpa (mock PLC up)')
        wait_until(lambda: self.command_pub.get_subscription_count() > 0, deadline - time.monotonic(),
                   what='plc_output to subscribe to pressure_command')
        wait_until(lambda: self.measured, deadline - time.monotonic(),
                   what='measured_pressure from plc_output (PLC link up)')

    def close(self):
        self.stop_commands()
        if self.graph.processes['plc_output'].poll() is None:
            self.graph.stop('plc_output', signal.SIGINT, EXIT_DEADLINE_S)  # vents while the mock is still up
        self.probe.close()
        self.client.close()
        self.graph.stop_all()


@pytest.fixture
def make_rig(tmp_path):
    rigs = []

    def make(**overrides):
        rigs.append(Rig(tmp_path / f'graph{len(rigs)}', **overrides))
        return rigs[-1]
    yield make
    for rig in rigs:
        rig.close()


def distinct_command():
    """A different, non-round pressure per channel, all below p_max."""
    return 12.34 + 17.3 * np.arange(N)


# ------------------------------------------------ one graph, commands in normal operation
@pytest.fixture(scope='class')
def rig(tmp_path_factory):
    """One graph shared by the tests of a class; each test sets up the command it needs."""
    rig = Rig(tmp_path_factory.mktemp('commands'))
    yield rig
    rig.close()


class TestCommands:

    def test_a_command_reaches_the_registers(self, rig):
        command = distinct_command()
        rig.command(command)
        rig.wait_registers(command, COMMAND_DEADLINE_S, f'the command within {TOLERANCE_KPA} kPa in the registers')

    def test_over_limit_commands_arrive_as_exactly_p_max(self, rig):
        rig.command(np.full(N, 500.0))
        rig.wait_registers(np.full(N, P_MAX_KPA), COMMAND_DEADLINE_S, f'500 kPa clamped to {P_MAX_KPA} kPa')
        registers = rig.registers()
        assert np.all(registers == P_MAX_KPA), f'500 kPa must arrive as exactly {P_MAX_KPA} kPa, got {registers}'

        mixed = np.linspace(0.0, 300.0, N)
        mixed[0], mixed[1], mixed[2] = 1e6, -20.0, P_MAX_KPA + 0.04
        rig.command(mixed)
        rig.wait_registers(np.clip(mixed, 0.0, P_MAX_KPA), COMMAND_DEADLINE_S, 'each channel clamped to [0, p_max]')

        # The mock's own record of every write: every channel saw p_max, none ever more.
        n = len(rig.max_written)
        wait_until(lambda: len(rig.max_written) > n and np.all(np.asarray(rig.max_written[-1].data) == P_MAX_KPA),
                   COMMAND_DEADLINE_S, what=f'mock_plc/max_written_kpa to report {P_MAX_KPA} kPa on every channel')
        highest = max(max(msg.data) for msg in rig.max_written)
        assert highest <= P_MAX_KPA, f'mock_plc/max_written_kpa reported {highest} kPa > {P_MAX_KPA} kPa'
        mock = rig.latest_status(MOCK_STATUS)
        values = {kv.key: kv.value for kv in mock.values}
        assert mock.level == DiagnosticStatus.OK and values['over-limit writes'] == '0', mock

    def test_the_arrays_name_their_channels(self, rig):
        """measured_pressure's layout label lists the channel map's channels, max_written_kpa's the
        register map's, in data order; each value is the named channel's."""
        command = distinct_command()
        rig.command(command)
        wait_until(lambda: np.all(np.abs(np.asarray(rig.measured[-1].data) - command) <= MEASURED_TOLERANCE_KPA),
                   MEASURED_DEADLINE_S, what='measured_pressure within 1 kPa of a different command per channel')
        channels = ChannelMap.load(CONFIG / 'hardware/channel_map.yaml').channels
        for msg, names in ((rig.measured[-1], channels), (rig.max_written[-1], REGISTER_MAP.names)):
            assert len(msg.layout.dim) == 1 and msg.layout.data_offset == 0, msg.layout
            dim = msg.layout.dim[0]
            assert label_names(dim.label) == tuple(names)
            assert dim.size == dim.stride == len(msg.data) == N
        measured = dict(zip(label_names(rig.measured[-1].layout.dim[0].label), rig.measured[-1].data))
        # distinct_command() differs by 17.3 kPa between neighbours: a shifted name would show.
        assert all(abs(measured[name] - command[i]) <= MEASURED_TOLERANCE_KPA
                   for i, name in enumerate(REGISTER_MAP.names)), measured

    def test_measured_pressure_approaches_the_command(self, rig):
        rig.command(np.zeros(N))
        wait_until(lambda: rig.measured and max(rig.measured[-1].data) < TOLERANCE_KPA, MEASURED_DEADLINE_S,
                   what='measured_pressure back at 0 kPa')
        start = len(rig.measured)
        target = 200.0
        rig.command(np.full(N, target))
        wait_until(lambda: np.all(np.abs(np.asarray(rig.measured[-1].data) - target) <= MEASURED_TOLERANCE_KPA),
                   MEASURED_DEADLINE_S, what=f'measured_pressure within {MEASURED_TOLERANCE_KPA} kPa of {target} kPa')
        samples = np.array([msg.data for msg in rig.measured[start:]])
        assert samples.shape[1] == N
        # A first-order lag: intermediate values on the way, rising, no overshoot.
        between = np.all((samples > 0.1 * target) & (samples < 0.9 * target), axis=1)
        assert between.any(), f'no measured sample between 10 % and 90 % of the command: {samples[:, 0]}'
        assert np.all(np.diff(samples, axis=0) >= -TOLERANCE_KPA), f'measured pressure fell on the way: {samples[:, 0]}'
        assert samples.max() <= target + TOLERANCE_KPA, f'measured pressure overshot: {samples.max()} kPa'

    def test_stale_commands_vent(self, rig):
        for i in range(3):
            command = np.full(N, 100.0 + 10 * i)
            rig.command(command)
            rig.wait_registers(command, COMMAND_DEADLINE_S, 'the command in the registers')
            last = rig.stop_commands()
            seconds = rig.time_to_vent(last, STALE_VENT_DEADLINE_S, 'commands stopped')
            record_vent('stale command (from the last publication)', seconds, STALE_VENT_DEADLINE_S)
            # Held while fresh: the node counts from the arrival, which is after the publication.
            assert seconds >= COMMAND_TIMEOUT_S, f'vented {seconds:.3f} s after the last command, before ' \
                                                 f'command_timeout_s = {COMMAND_TIMEOUT_S} s'
        n = len(rig.diagnostics)
        wait_until(lambda: (s := rig.latest_status(OUTPUT_STATUS, n)) and s.level == DiagnosticStatus.WARN,
                   LINK_UP_DIAGNOSTICS_DEADLINE_S, what='plc_output WARN on /diagnostics while venting a stale command')

    @pytest.mark.parametrize('kind', ['wrong length', 'too long', 'NaN', 'inf', 'channels swapped',
                                      'channels unnamed'])
    def test_an_invalid_command_vents(self, rig, kind):
        """A command that is not the configured channel order (two names swapped, as a node with
        another channel map sends; or no names at all) is invalid like a NaN: it would drive the
        wrong muscles."""
        valid = np.full(N, 120.0)
        invalid = {'wrong length': [120.0] * (N - 1), 'too long': [120.0] * (N + 1),
                   'NaN': np.where(np.arange(N) == 5, math.nan, 120.0),
                   'inf': np.where(np.arange(N) == N - 1, math.inf, 120.0)}.get(kind, valid)
        swapped = list(CHANNELS)
        swapped[8], swapped[10] = swapped[10], swapped[8]   # L1 <-> R1: left and right twist
        layout = {'channels swapped': named_layout(swapped),
                  'channels unnamed': Float64MultiArray().layout}.get(kind, LAYOUT)
        assert kind not in ('channels swapped', 'channels unnamed') or \
            layout_label(swapped) != LAYOUT.dim[0].label
        rig.command(valid)
        rig.wait_registers(valid, COMMAND_DEADLINE_S, 'the valid command in the registers')
        last_valid = rig.command(invalid, layout)
        first_invalid = rig.first_published()
        seconds = rig.time_to_vent(last_valid, INVALID_VENT_DEADLINE_S,
                                   f'invalid command ({kind}) after a valid one (vent before it could go stale)')
        record_vent(f'invalid command, {kind} (from its first publication)', seconds - (first_invalid - last_valid),
                    INVALID_VENT_DEADLINE_S)
        # Stays vented while invalid commands keep coming, past the stale timeout.
        rig.assert_stays_vented(COMMAND_TIMEOUT_S + WRITE_PERIOD_S, f'invalid commands ({kind}) keep coming')


def test_a_lower_p_max_parameter_clamps_below_the_register_map(make_rig):
    p_max = 200.0
    assert p_max < REGISTER_MAP.p_max_kpa
    rig = make_rig(output={'p_max_kpa': p_max})
    rig.command(np.full(N, 500.0))
    rig.wait_registers(np.full(N, p_max), COMMAND_DEADLINE_S, f'500 kPa clamped to p_max_kpa = {p_max} kPa')
    highest = max(max(msg.data) for msg in rig.max_written)
    assert highest <= p_max, f'mock_plc/max_written_kpa reported {highest} kPa > p_max_kpa = {p_max} kPa'


# ------------------------------------------------------------ shutdown, kill, lost PLC
# SIGINT and SIGTERM of plc_output (it vents before it exits, the PLC watchdog never trips): in
# test_faults_process.py, with every other node of the lab graph.


def test_sigkill_of_plc_output_lets_the_plc_watchdog_vent(make_rig):
    rig = make_rig()
    command = distinct_command()
    rig.command(command)
    rig.wait_registers(command, COMMAND_DEADLINE_S, 'the command in the registers')
    proc = rig.graph.processes['plc_output']
    t0 = time.monotonic()
    proc.kill()
    seconds = rig.time_to_vent(t0, WATCHDOG_VENT_DEADLINE_S, 'SIGKILL of plc_output')
    record_vent(f'SIGKILL of plc_output (mock watchdog_s {WATCHDOG_S})', seconds, WATCHDOG_VENT_DEADLINE_S)
    assert proc.wait(EXIT_DEADLINE_S) == -signal.SIGKILL
    n = len(rig.diagnostics)
    wait_until(lambda: rig.latest_status(MOCK_STATUS, n), COMMAND_DEADLINE_S, what='a mock_plc status')
    values = {kv.key: kv.value for kv in rig.latest_status(MOCK_STATUS, n).values}
    assert int(values['watchdog trips']) >= 1, values


def test_plc_output_reconnects_to_a_restarted_plc_and_resends_the_command(make_rig):
    rig = make_rig()
    command = distinct_command()
    rig.command(command)
    rig.wait_registers(command, COMMAND_DEADLINE_S, 'the command in the registers')
    wait_until(lambda: (s := rig.latest_status(OUTPUT_STATUS)) and s.level == DiagnosticStatus.OK,
               LINK_UP_DIAGNOSTICS_DEADLINE_S, what='plc_output OK on /diagnostics')

    assert rig.graph.stop('mock_plc') == 0, rig.graph.log('mock_plc')
    n = len(rig.diagnostics)
    wait_until(lambda: any(s.level == DiagnosticStatus.ERROR for s in rig.statuses(OUTPUT_STATUS, n)),
               LINK_DOWN_DIAGNOSTICS_DEADLINE_S, what='plc_output ERROR on /diagnostics while the PLC is down')
    down = rig.latest_status(OUTPUT_STATUS, n)
    assert {kv.key: kv.value for kv in down.values}['connected'] == 'False', down

    n = len(rig.max_written)
    rig.start_mock()  # same port; a fresh PLC boot: registers 0, watchdog tripped
    wait_until(lambda: len(rig.max_written) > n, MOCK_START_DEADLINE_S, what='the restarted mock_plc (listening)')
    t_up = time.monotonic()
    rig.wait_registers(command, RECONNECT_DEADLINE_S, 'the latest command back in the restarted PLC',
                       hold_s=HOLD_S)
    print(f'\n[reconnect] command back {time.monotonic() - t_up - HOLD_S:.3f} s after the mock listened '
          f'(deadline {RECONNECT_DEADLINE_S:.1f} s)')
    n = len(rig.diagnostics)
    wait_until(lambda: (s := rig.latest_status(OUTPUT_STATUS, n)) and s.level == DiagnosticStatus.OK,
               LINK_UP_DIAGNOSTICS_DEADLINE_S, what='plc_output OK again on /diagnostics')
    values = {kv.key: kv.value for kv in rig.latest_status(OUTPUT_STATUS, n).values}
    assert int(values['reconnects']) >= 1 and int(values['link failures']) >= 1, values


def test_a_register_map_that_does_not_match_the_channel_map_stops_start_up(tmp_path):
    channel_map = yaml.safe_load((CONFIG / 'hardware/channel_map.yaml').read_text())
    channel_map['channels'][0], channel_map['channels'][1] = channel_map['channels'][1], channel_map['channels'][0]
    path = tmp_path / 'swapped_channel_map.yaml'
    path.write_text(yaml.safe_dump(channel_map))
    with Graph(tmp_path / 'logs') as graph:
        proc = graph.start('plc_output', PARAMS_FILES, plc_port=free_port(), channel_map_file=str(path))
        assert proc.wait(EXIT_DEADLINE_S) == 1
        log = graph.log('plc_output')
    assert 'cannot start' in log and 'field "channels"' in log, log
