"""Several PLCs, and errors that name their cause.

The register map with `endpoints` (plc/register_map.py PlcLayout): validation, the contract's
default layout per endpoint, the single-PLC form unchanged. Then graphs: plc_output driving two
mock_plc processes (one per endpoint) and venting both when one goes; plc_output against a PLC
that refuses (exception 02) or stays silent (wrong unit id): /diagnostics names the cause, not
"link down", and no command lands. Every wait polls a condition against a named deadline.
"""
import signal
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import pytest
from std_msgs.msg import Float64MultiArray
import yaml

from deadlines import DeadlineLog
from fabric_guidance.interface import DIAGNOSTICS, PRESSURE_COMMAND
from fabric_guidance.nodes.qos import COMMAND_QOS
from fabric_guidance.plc import PlcClient, PlcLayout, PlcLinkError, RegisterMap
from fabric_guidance.plc.register_map import RegisterMapError
from rosgraph import CONFIG, Graph, Probe, free_port, wait_until
from test_node_plc import LAYOUT as CHANNEL_LAYOUT, MOCK, OUTPUT, PARAMS_FILES

pytestmark = pytest.mark.graph  # starts a process graph with DDS

CHANNELS = tuple(yaml.safe_load((CONFIG / 'hardware/channel_map.yaml').read_text())['channels'])
SUIT, ARM = CHANNELS[:12], CHANNELS[12:]
TOLERANCE_KPA = 0.1
WATCHDOG_S = MOCK['watchdog_s']
MODBUS_TIMEOUT_S = OUTPUT['modbus_timeout_s']
DIAGNOSTICS_PERIOD_S = OUTPUT['diagnostics_period_s']
RECONNECT_MAX_S = OUTPUT['reconnect_max_s']
# ---- deadlines
STARTUP_DEADLINE_S = 20.0
COMMAND_DEADLINE_S = 2.0
#: One PLC gone -> the other vented by plc_output: a request times out (or fails at once),
#: then the vent write; slack for a loaded 2-core machine.
OTHER_VENT_DEADLINE_S = MODBUS_TIMEOUT_S + 1.0
#: A fault -> its state on /diagnostics: the retry that finds it, one period, slack.
DIAGNOSTICS_DEADLINE_S = MODBUS_TIMEOUT_S + DIAGNOSTICS_PERIOD_S + 2.0
#: The stopped PLC back -> commands on both again: the longest backoff, a cycle, slack.
HEAL_DEADLINE_S = RECONNECT_MAX_S + 2.0
#: How long commands are published against a refusing or silent PLC without landing.
NEVER_LANDS_S = 1.5
LOG = DeadlineLog('endpoints')


report = LOG.report_at_module_end('worst times, several PLCs')


def two_endpoints(port_a=1502, port_b=1503, **b_overrides):
    def channels(names):
        return [{'name': c, 'command_register': i, 'measured_register': i}
                for i, c in enumerate(names)]
    return {'p_max_kpa': 375.0, 'counts_per_kpa': 10, 'endpoints': [
        {'name': 'suit', 'host': '127.0.0.1', 'port': port_a, 'unit_id': 1,
         'channels': channels(SUIT)},
        {'name': 'arm', 'host': '127.0.0.1', 'port': port_b, 'unit_id': 2,
         'channels': channels(ARM), **b_overrides}]}


# ------------------------------------------------------------------ the layout itself
def test_endpoints_get_the_contract_layout_and_their_place_in_the_command_vector():
    layout = PlcLayout.from_dict(two_endpoints(), 'two.yaml', expected_channels=CHANNELS)
    suit, arm = layout.endpoints
    assert (suit.map.sequence_register, suit.map.heartbeat_register) == (12, 13)
    assert (arm.map.sequence_register, arm.map.heartbeat_register) == (6, 7)
    assert suit.indices == tuple(range(12)) and arm.indices == tuple(range(12, 18))
    assert (arm.host, arm.port, arm.map.unit_id) == ('127.0.0.1', 1503, 2)
    assert layout.endpoint('arm') is arm and layout.names == CHANNELS
    # The order of the endpoints need not be the channel map's: indices say where each goes.
    swapped = two_endpoints()
    swapped['endpoints'].reverse()
    layout = PlcLayout.from_dict(swapped, 'two.yaml', expected_channels=CHANNELS)
    assert layout.endpoint('arm').indices == tuple(range(12, 18))


def test_the_single_plc_form_is_one_endpoint_addressed_by_the_node():
    layout = PlcLayout.load(CONFIG / 'hardware/plc_register_map.yaml', expected_channels=CHANNELS)
    (only,) = layout.endpoints
    assert only.host is None and only.port is None and layout.endpoint('') is only
    assert only.map == RegisterMap.load(CONFIG / 'hardware/plc_register_map.yaml')
    assert (only.map.sequence_register, only.map.heartbeat_register) == (18, 19)


@pytest.mark.parametrize('change, field, reason', [
    (lambda d: d['endpoints'][1]['channels'].append(
        {'name': 'F1', 'command_register': 6, 'measured_register': 6}),
     'endpoints', "'F1' is served by both"),
    (lambda d: d['endpoints'][1]['channels'].pop(), 'endpoints', "missing ['arm_vi']"),
    (lambda d: d['endpoints'][1].update(name='suit'), 'endpoints[1].name', 'duplicates'),
    (lambda d: d['endpoints'][1].update(port=1502, unit_id=1),
     'endpoints[1]', 'is also endpoints[0]'),
    (lambda d: d['endpoints'][0].pop('host'), 'endpoints[0].host', 'missing'),
    (lambda d: d['endpoints'][0].update(slave=3), 'endpoints[0].slave', 'not a known field'),
    (lambda d: d.update(unit_id=1), 'unit_id', 'each endpoint'),
    (lambda d: d['endpoints'][1].update(heartbeat_register=3),
     'heartbeat_register', 'command register'),
])
def test_a_bad_endpoint_names_the_field_and_the_reason(change, field, reason):
    data = two_endpoints()
    change(data)
    with pytest.raises(RegisterMapError) as info:
        PlcLayout.from_dict(data, 'two.yaml', expected_channels=CHANNELS)
    assert str(info.value).startswith('two.yaml') and f'"{field}"' in str(info.value), info.value
    assert reason in str(info.value)


def test_a_single_map_reader_refuses_several_endpoints_with_the_way_out():
    with pytest.raises(RegisterMapError, match='names 2 PLCs.*name the endpoint'):
        RegisterMap.from_dict(two_endpoints(), 'two.yaml')
    with pytest.raises(RegisterMapError, match="no endpoint named 'hand'"):
        PlcLayout.from_dict(two_endpoints(), 'two.yaml').endpoint('hand')


# --------------------------------------------------------------------------- graphs
class Lab:
    """mock_plc processes (one per endpoint) and plc_output, a probe publishing commands."""

    def __init__(self, log_dir, register_map: dict, mocks: dict[str, str], output_overrides=None):
        self.path = log_dir / 'register_map.yaml'
        log_dir.mkdir(parents=True, exist_ok=True)
        self.path.write_text(yaml.safe_dump(register_map))
        self.layout = PlcLayout.load(self.path)
        self.graph = Graph(log_dir / 'logs')
        # process name -> (endpoint, the mock's own register map file or None, port)
        self.mocks = mocks
        for name in mocks:
            self.start_mock(name)
        self.graph.start('plc_output', PARAMS_FILES, register_map_file=str(self.path),
                         **(output_overrides or {}))
        # The graph's controller as plc_output knows it (its name), commands labelled as it does.
        self.probe = Probe(self.graph.domain_id, 'pressure_controller')
        self.diagnostics = self.probe.subscribe(DiagnosticArray, DIAGNOSTICS, COMMAND_QOS)
        self.pub = self.probe.node.create_publisher(Float64MultiArray, PRESSURE_COMMAND,
                                                    COMMAND_QOS)
        self.data = None
        self.probe.node.create_timer(0.05, self._publish)
        self.readers = {}

    def start_mock(self, name):
        endpoint, map_file, port = self.mocks[name]
        self.graph.start('mock_plc', PARAMS_FILES, as_name=name, port=port,
                         register_map_file=str(map_file or self.path),
                         endpoint=endpoint if not map_file else '')

    def _publish(self):
        if self.data is not None:
            self.pub.publish(Float64MultiArray(layout=CHANNEL_LAYOUT, data=self.data))

    def command(self, values):
        self.data = [float(v) for v in values]

    def registers(self, endpoint: str, port: int | None = None,
                  register_map: RegisterMap | None = None):
        """An endpoint's command registers read back (kPa), None while it does not answer."""
        e = self.layout.endpoint(endpoint)
        if endpoint not in self.readers:
            self.readers[endpoint] = PlcClient(register_map or e.map, '127.0.0.1', port or e.port,
                                               timeout_s=0.3)
        try:
            return self.readers[endpoint].read_commands_kpa()
        except PlcLinkError:
            return None

    def wait_registers(self, endpoint, expected, deadline_s, what):
        expected = np.asarray(expected, dtype=float)
        wait_until(lambda: (r := self.registers(endpoint)) is not None
                   and np.max(np.abs(r - expected)) <= TOLERANCE_KPA + 1e-9,
                   deadline_s, 0.01, what)

    def wait_level(self, name, level, deadline_s, what, start=0):
        wait_until(lambda: (s := self.status(name, start)) and s.level == level, deadline_s,
                   what=what)

    def state(self, name):
        return {kv.key: kv.value for kv in self.status(name).values}['state']

    def status(self, name, start=0):
        found = [s for msg in self.diagnostics[start:] for s in msg.status if s.name == name]
        return found[-1] if found else None

    def close(self, check=True):
        self.data = None
        if self.graph.processes['plc_output'].poll() is None:
            self.graph.stop('plc_output', signal.SIGINT, 10.0)
        self.probe.close()
        for reader in self.readers.values():
            reader.close()
        self.graph.stop_all(check=check)


def command_vector():
    return 12.34 + 17.3 * np.arange(len(CHANNELS))


def test_plc_output_drives_two_plcs_and_vents_both_when_one_goes(tmp_path):
    data = two_endpoints(free_port(), free_port())
    ports = {e['name']: e['port'] for e in data['endpoints']}
    lab = Lab(tmp_path, data, {'mock_suit': ('suit', None, ports['suit']),
                               'mock_arm': ('arm', None, ports['arm'])})
    try:
        command = command_vector()
        lab.command(command)
        lab.wait_registers('suit', command[:12], STARTUP_DEADLINE_S, 'the command on the suit PLC')
        lab.wait_registers('arm', command[12:], COMMAND_DEADLINE_S, 'the command on the arm PLC')
        lab.wait_level('plc_output: PLC link arm', DiagnosticStatus.OK, DIAGNOSTICS_DEADLINE_S,
                       'the arm link OK on /diagnostics')

        t0 = time.monotonic()
        lab.graph.stop('mock_arm', signal.SIGKILL)
        lab.wait_registers('suit', np.zeros(12), OTHER_VENT_DEADLINE_S,
                           'the suit PLC vented by plc_output')
        LOG.record('one PLC killed -> the other vented by plc_output', time.monotonic() - t0,
                   OTHER_VENT_DEADLINE_S)
        n = len(lab.diagnostics)
        lab.wait_level('plc_output: PLC link arm', DiagnosticStatus.ERROR, DIAGNOSTICS_DEADLINE_S,
                       'the arm link ERROR on /diagnostics', start=n)
        assert 'PLC link down (arm)' in lab.status('plc_output: PLC link arm', n).message
        assert lab.status('plc_output: PLC link suit', n).level == DiagnosticStatus.OK
        assert 'venting all PLCs' in lab.status('plc_output: PLC output', n).message
        end = time.monotonic() + 0.5   # stays vented while the arm PLC is gone
        while time.monotonic() < end:
            r = lab.registers('suit')
            assert r is None or not r.any(), r
            time.sleep(0.02)

        t0 = time.monotonic()
        lab.start_mock('mock_arm')
        lab.wait_registers('arm', command[12:], STARTUP_DEADLINE_S + HEAL_DEADLINE_S,
                           'the arm PLC back')
        lab.wait_registers('suit', command[:12], COMMAND_DEADLINE_S, 'the suit PLC back')
        print(f'\n[endpoints] both PLCs commanded again {time.monotonic() - t0:.3f} s after '
              'restarting one')
    finally:
        lab.close()


def _misconfigured_lab(tmp_path, **changes):
    """plc_output with the shipped register map changed by `changes`, one mock PLC serving the
    shipped map (the contract's layout), a command sent: (lab, the PLC's port)."""
    port = free_port()
    shipped = CONFIG / 'hardware/plc_register_map.yaml'
    data = {**yaml.safe_load(shipped.read_text()), **changes}
    lab = Lab(tmp_path, data, {'mock_plc': ('', shipped, port)}, {'plc_port': port})
    try:
        lab.command(command_vector())
    except BaseException:
        lab.close(check=False)
        raise
    return lab, port


def test_a_refusing_plc_is_not_down_and_no_command_lands(tmp_path):
    """plc_output's map (the single-PLC form) puts the heartbeat at 100; the PLC (the shipped map:
    the contract's layout) answers exception 02 there. /diagnostics names the register and says
    the map or the program is wrong; not one command lands meanwhile."""
    lab, port = _misconfigured_lab(tmp_path, heartbeat_register=100)
    try:
        lab.wait_level('plc_output: PLC output', DiagnosticStatus.ERROR, STARTUP_DEADLINE_S,
                       'the refusal on /diagnostics')
        message = lab.status('plc_output: PLC output').message
        assert 'refuses' in message and 'down' not in message, message
        assert 'exception 02' in message and 'holding register 100' in message, message
        assert 'register map' in message and 'PLC program' in message, message
        wait_until(lambda: lab.status('plc_output: PLC link plc'), DIAGNOSTICS_DEADLINE_S,
                   what='the link status')
        assert lab.state('plc_output: PLC link plc') == 'refused'
        end = time.monotonic() + NEVER_LANDS_S
        shipped = RegisterMap.load(CONFIG / 'hardware/plc_register_map.yaml')
        while time.monotonic() < end:
            r = lab.registers('', port, shipped)
            assert r is not None and not r.any(), f'a command landed on a refusing PLC: {r}'
            time.sleep(0.02)
    finally:
        lab.close(check=False)
    found = lab.graph.plc_violations()
    # The tries at register 100 are recorded as out-of-map writes (refused, never stored).
    assert found and all('outside the register map' in line and '[100,' in line
                         for line in found), found


def test_a_wrong_unit_id_says_check_the_unit_id(tmp_path):
    lab, port = _misconfigured_lab(tmp_path, unit_id=2)  # the PLC answers unit id 1 only
    try:
        lab.wait_level('plc_output: PLC output', DiagnosticStatus.ERROR, STARTUP_DEADLINE_S,
                       'the silence on /diagnostics')
        message = lab.status('plc_output: PLC output').message
        assert 'check unit_id' in message and 'unit id 2' in message, message
        assert 'down' not in message, message
        wait_until(lambda: lab.status('plc_output: PLC link plc'), DIAGNOSTICS_DEADLINE_S,
                   what='the link status')
        assert lab.state('plc_output: PLC link plc') == 'no answer'
        r = lab.registers('', port, RegisterMap.load(CONFIG / 'hardware/plc_register_map.yaml'))
        assert r is not None and not r.any(), r
    finally:
        lab.close()
