"""PLC link over real Modbus TCP on 127.0.0.1 against the mock PLC, plus the pure regulator logic.

No test sleeps and hopes: every wait polls a condition with a deadline (wait_until).
"""
import dataclasses
import math
import time

import numpy as np
import pytest

from fabric_guidance.paths import config_path
from fabric_guidance.plc import FirstOrderLag, RegulatorSim, Watchdog
from fabric_guidance.plc import pymodbus_compat as compat
from fabric_guidance.plc.mock_server import MockPlcServer
from fabric_guidance.plc.modbus import PlcClient, PlcLinkError, PlcNoAnswerError, PlcRefusedError
from fabric_guidance.plc.register_map import RegisterMap

WATCHDOG_S = 0.3
TAU_S = 0.1
N = 18


def wait_until(pred, timeout_s, what='condition', interval_s=0.005):
    """Poll pred() until it is truthy; fail the test naming `what` after timeout_s seconds."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = pred()
        if value:
            return value
        if time.monotonic() > deadline:
            pytest.fail(f'timed out after {timeout_s} s waiting for {what}')
        time.sleep(interval_s)


class Controller:
    """What the control node does each cycle: bump the heartbeat, write the command vector."""

    def __init__(self, client):
        self.client, self.beat, self.last_beat_s = client, 0, None

    def cycle(self, pressures_kpa):
        self.beat += 1
        self.last_beat_s = time.monotonic()  # taken before the write: the PLC sees it later
        self.client.write_heartbeat(self.beat)
        self.client.write_pressures(pressures_kpa)

    def arm(self, server):
        """Send zero commands with heartbeats until the PLC's watchdog applies commands."""
        def armed():
            self.cycle(np.zeros(N))
            return server.watchdog_armed
        wait_until(armed, 1.0, 'the watchdog to arm')


@pytest.fixture(scope='module')
def reg_map():
    return RegisterMap.load(config_path('hardware/plc_register_map.yaml'))


@pytest.fixture
def plc(reg_map):
    server = MockPlcServer(reg_map, regulator_tau_s=TAU_S, watchdog_s=WATCHDOG_S, update_hz=200)
    server.start()
    yield server
    server.stop()


@pytest.fixture
def steady_plc(reg_map):
    """A mock PLC whose watchdog, once armed, holds for a minute: no race with a trip. The test
    arms it on the connection it writes on (one writer at a time: the first to write holds the
    write claim, and its connection's close vents)."""
    with MockPlcServer(reg_map, regulator_tau_s=TAU_S, watchdog_s=60.0, update_hz=200) as server:
        yield server


def arm_raw(raw, server, reg_map):
    """Heartbeats from a pymodbus client until the watchdog is armed (it then holds the claim)."""
    beat = [0]

    def armed():
        beat[0] += 1
        assert not compat.request(raw, 'write_register', reg_map.heartbeat_register, beat[0],
                                  unit_id=reg_map.unit_id).isError()
        return server.watchdog_armed
    wait_until(armed, 1.0, 'the watchdog to arm')


@pytest.fixture
def client(reg_map, plc):
    c = PlcClient(reg_map, '127.0.0.1', plc.port, timeout_s=0.5)
    assert c.connect()
    yield c
    c.close()


def ramp(value_kpa):
    return np.full(N, float(value_kpa))


# --------------------------------------------------------------- pure regulator logic
def test_lag_is_exact_first_order_and_rate_independent():
    one, many = FirstOrderLag(2, tau_s=0.2), FirstOrderLag(2, tau_s=0.2)
    one.step([100.0, 50.0], 0.3)
    for _ in range(30):
        many.step([100.0, 50.0], 0.01)
    expected = [100.0 * (1 - math.exp(-0.3 / 0.2)), 50.0 * (1 - math.exp(-0.3 / 0.2))]
    assert np.allclose(one.values, expected) and np.allclose(many.values, expected)


def test_lag_ignores_non_positive_dt_and_tau_zero_follows_at_once():
    lag = FirstOrderLag(1, tau_s=0.1)
    lag.step([10.0], 0.05)
    before = lag.values
    for dt in (0.0, -1.0, float('nan')):
        assert lag.step([300.0], dt) == before
    instant = FirstOrderLag(1, tau_s=0.0)
    assert instant.step([42.0], 1e-6) == [42.0]
    with pytest.raises(ValueError):
        FirstOrderLag(1, tau_s=-0.1)


def test_watchdog_starts_tripped_arms_on_change_trips_and_rearms():
    wd = Watchdog(timeout_s=0.5)
    assert wd.update(7, 0.0) is False            # baseline only: no heartbeat seen yet
    assert wd.update(7, 10.0) is False           # unchanged forever: still vented, not a "trip"
    assert wd.trips == 0
    assert wd.update(8, 10.1) is True
    assert wd.update(8, 10.59) is True
    assert wd.update(8, 10.6) is False and wd.trips == 1
    assert wd.update(8, 11.0) is False and wd.trips == 1
    assert wd.update(9, 11.1) is True            # re-armed by the next change
    wd.reset()
    assert wd.update(9, 12.0) is False and wd.trips == 1


def test_regulator_sim_vents_until_heartbeat_and_clamps():
    clock = [0.0]
    sim = RegulatorSim(2, p_max_kpa=375.0, tau_s=0.0, watchdog_s=0.5, clock=lambda: clock[0])
    r = sim.scan([100.0, 100.0], heartbeat=0)
    assert r.vent and r.measured_kpa == [0.0, 0.0]
    clock[0] = 0.1
    r = sim.scan([1000.0, float('nan')], heartbeat=1)
    assert not r.vent and r.applied_kpa == [375.0, 0.0] and r.measured_kpa == [375.0, 0.0]
    clock[0] = 0.7
    r = sim.scan([1000.0, 0.0], heartbeat=1)
    assert r.vent and r.measured_kpa == [0.0, 0.0] and sim.watchdog.trips == 1


# ---------------------------------------------------------------- over Modbus TCP
def test_client_writes_and_reads_back(plc, client):
    Controller(client).arm(plc)  # unarmed, the PLC zeroes the command registers at once
    p = np.linspace(0.0, 340.0, N)
    rtt = client.write_pressures(p)
    assert 0.0 < rtt < 0.5
    assert np.allclose(client.read_commands_kpa(), p, atol=0.05)
    assert np.allclose(plc.commands_kpa(), p, atol=0.05)
    client.write_heartbeat(70000)  # mod 65536
    assert plc.heartbeat_value() == 70000 - 65536
    assert plc.out_of_map_writes == [] and plc.over_limit_writes == []


def test_client_clamps_and_vents_before_the_wire(plc, client):
    Controller(client).arm(plc)
    p = ramp(100.0)
    p[:3] = [1000.0, float('nan'), -20.0]
    client.write_pressures(p)
    assert np.allclose(client.read_commands_kpa()[:4], [375.0, 0.0, 0.0, 100.0])
    with pytest.raises(ValueError):
        client.write_pressures([1.0] * (N - 1))
    assert plc.over_limit_writes == []
    assert plc.max_written_kpa()['F1'] == 375.0


def test_commands_not_applied_before_first_heartbeat(plc, client):
    client.write_pressures(ramp(200.0))
    wait_until(lambda: not plc.commands_kpa().any(), 1.0, 'the PLC to zero commands sent without a heartbeat')
    assert plc.max_written_kpa()['F1'] == 200.0             # the write did arrive
    assert not plc.measured_kpa().any() and not client.read_measured_kpa().any()
    assert plc.watchdog_trips == 0 and not plc.watchdog_armed


def test_measured_pressure_follows_command_with_lag(plc, client):
    ctl, target, trace = Controller(client), ramp(200.0), []

    def settled():
        ctl.cycle(target)
        trace.append(client.read_measured_kpa())
        return np.all(np.abs(trace[-1] - target) < 1.0)

    wait_until(settled, 3.0, 'measured pressure to reach the command')
    f1 = np.array([m[0] for m in trace])
    assert np.all(np.diff(f1) >= -0.1)                     # rises, never overshoots back down
    assert np.any((f1 > 10.0) & (f1 < 190.0))              # a lag, not a jump
    assert plc.watchdog_trips == 0 and plc.out_of_map_writes == []


def test_watchdog_vents_after_heartbeat_stops_and_resumes_only_on_new_write(plc, client):
    ctl, target = Controller(client), ramp(150.0)

    def pressurised():
        ctl.cycle(target)
        return np.all(plc.measured_kpa() > 140.0)

    wait_until(pressurised, 3.0, 'pressurisation')
    # No more heartbeats from here.
    wait_until(lambda: not plc.commands_kpa().any(), WATCHDOG_S + 0.5, 'the watchdog to vent')
    vented_after = time.monotonic() - ctl.last_beat_s
    assert vented_after >= WATCHDOG_S, f'vented {vented_after:.3f} s after the last heartbeat'
    assert plc.watchdog_trips == 1
    wait_until(lambda: np.all(plc.measured_kpa() < 1.0), 2.0, 'pressure to fall after venting')

    # Commands without heartbeats stay vented.
    client.write_pressures(target)
    wait_until(lambda: not plc.commands_kpa().any(), 1.0, 'commands without heartbeat to be zeroed')

    # Heartbeats alone re-arm the watchdog but do not bring back the old command.
    def rearmed():
        ctl.beat += 1
        client.write_heartbeat(ctl.beat)
        return plc.watchdog_armed

    wait_until(rearmed, 1.0, 'the watchdog to re-arm')
    assert not client.read_commands_kpa().any() and np.all(plc.measured_kpa() < 1.0)

    # A new write with live heartbeats is applied again.
    def resumed():
        ctl.cycle(ramp(80.0))
        return np.all(np.abs(client.read_measured_kpa() - 80.0) < 1.0)

    wait_until(resumed, 3.0, 'pressure to resume')
    assert plc.watchdog_trips == 1 and plc.out_of_map_writes == []


def test_max_written_is_recorded(plc, client):
    for value in (50.0, 300.0, 1000.0, 20.0):
        p = ramp(0.0)
        p[0], p[12] = value, value / 2
        client.write_pressures(p)
    written = plc.max_written_kpa()
    assert written['F1'] == 375.0                          # 1000 was clamped by the client
    assert written['arm_i'] == 375.0                       # 500 kPa clamped too
    assert written['F2'] == 0.0
    assert set(written) == set(client.map.names)
    assert plc.over_limit_writes == [] and plc.out_of_map_writes == []


def test_raw_writes_outside_map_are_refused_and_over_limit_stored_clamped(reg_map, steady_plc):
    """A pymodbus client (whatever its version) sees the contract's answers: exception 02 outside
    the map, nothing stored there; a count above p_max stored as p_max, and both recorded."""
    raw = compat.make_client('127.0.0.1', steady_plc.port, 1.0)
    assert raw.connect()
    try:
        arm_raw(raw, steady_plc, reg_map)
        refused = compat.request(raw, 'write_register', 200, 1234, unit_id=reg_map.unit_id)
        assert compat.exception_code(refused) == 2
        # Starts on the last command register and runs past the end of the map (19 is the
        # heartbeat, 20 the vent register, 21 is outside): refused whole.
        refused = compat.request(raw, 'write_registers', 17, [1, 2, 3, 4, 5], unit_id=reg_map.unit_id)
        assert compat.exception_code(refused) == 2
        seq = compat.request(raw, 'read_holding_registers', N, unit_id=reg_map.unit_id,
                             count=1).registers[0] + 1
        answer = compat.request(raw, 'write_registers', 0, [5000] + [0] * (N - 1) + [seq],
                                unit_id=reg_map.unit_id)
        assert not answer.isError()
        stored = compat.request(raw, 'read_holding_registers', 0, unit_id=reg_map.unit_id,
                                count=N + 2)
        assert stored.registers[0] == reg_map.p_max_counts and stored.registers[N] == seq
        assert compat.exception_code(compat.request(raw, 'read_input_registers', N + 3,
                                                    unit_id=reg_map.unit_id, count=1)) == 2
    finally:
        raw.close()
    assert steady_plc.out_of_map_writes == [(200, 1234), (21, 5)]
    assert steady_plc.over_limit_writes == [(0, 5000)]
    assert steady_plc.max_written_kpa()['F1'] == 500.0


def test_an_unsequenced_command_write_is_answered_and_undone(reg_map, steady_plc):
    plc = steady_plc
    raw = compat.make_client('127.0.0.1', plc.port, 1.0)
    assert raw.connect()
    try:
        arm_raw(raw, plc, reg_map)
        assert not compat.request(raw, 'write_registers', 0, [500] * N + [7],
                                  unit_id=reg_map.unit_id).isError()
        answer = compat.request(raw, 'write_register', 0, 1000, unit_id=reg_map.unit_id)
        assert not answer.isError()   # the library answers; the program restores
        assert np.allclose(plc.commands_kpa(), 50.0)
    finally:
        raw.close()
    assert plc.stale_writes[-1][0] is None


def test_a_second_client_is_refused_with_server_device_busy(reg_map, plc, client):
    """One writer at a time: a second PlcClient (a second plc_output) gets a PlcRefusedError
    that says another client holds the write claim, and writes nothing."""
    Controller(client).arm(plc)
    client.write_pressures(ramp(40.0))
    with PlcClient(reg_map, '127.0.0.1', plc.port, timeout_s=0.5) as second:
        with pytest.raises(PlcRefusedError) as info:
            second.write_pressures(ramp(200.0))
        second.read_measured_kpa()   # reads are anyone's: the connection is still good
        with pytest.raises(PlcRefusedError):
            second.write_heartbeat(12345)
    assert info.value.code == 6 and info.value.state == 'refused'
    assert 'another Modbus client holds' in str(info.value)
    assert np.allclose(plc.commands_kpa(), 40.0) and plc.heartbeat_value() != 12345


def test_an_illegal_address_names_the_register_and_the_map(reg_map, plc):
    wrong = dataclasses.replace(reg_map, heartbeat_register=100)
    with PlcClient(wrong, '127.0.0.1', plc.port, timeout_s=0.5) as c:
        with pytest.raises(PlcRefusedError) as info:
            c.write_heartbeat(1)
        c.read_measured_kpa()   # the connection is still good: a refusal is not a dead link
    err = info.value
    assert err.state == 'refused' and err.code == 2
    assert 'holding register 100' in str(err) and reg_map.source in str(err)
    assert 'register map' in str(err) and 'PLC program' in str(err)


def test_wrong_unit_id_says_check_the_unit_id(reg_map, plc):
    other = PlcClient(dataclasses.replace(reg_map, unit_id=reg_map.unit_id + 1), '127.0.0.1', plc.port,
                      timeout_s=0.3)
    try:
        for _ in range(2):   # the second time too: silence is not taken for a dead link
            with pytest.raises(PlcNoAnswerError,
                               match=f'unit id {reg_map.unit_id + 1}.*check unit_id'):
                other.write_pressures(ramp(10.0))
    finally:
        other.close()
    assert not plc.commands_kpa().any()


def test_a_stopped_plc_is_down_not_silent(reg_map, plc):
    with PlcClient(reg_map, '127.0.0.1', plc.port, timeout_s=0.3) as c:
        c.write_heartbeat(1)
        plc.stop()
        with pytest.raises(PlcLinkError) as info:
            c.write_heartbeat(2)
    assert info.value.state == 'down'


def test_link_error_while_stopped_and_recovery_after_restart(plc, client):
    port = plc.port
    client.write_pressures(ramp(10.0))
    plc.stop()
    for call in (lambda: client.write_pressures(ramp(20.0)), client.read_measured_kpa,
                 lambda: client.write_heartbeat(1), client.vent):
        with pytest.raises(PlcLinkError):
            call()
    assert not client.connected and not client.connect()
    plc.start()
    assert plc.port == port
    Controller(client).arm(plc)                            # reconnects by itself
    client.write_pressures(ramp(30.0))
    assert np.allclose(client.read_commands_kpa(), 30.0)
    client.vent()
    assert not client.read_commands_kpa().any()
    assert plc.max_written_kpa()['F1'] == 30.0 and plc.out_of_map_writes == []


def test_non_contiguous_map_writes_register_by_register(reg_map):
    shuffled = dataclasses.replace(reg_map, channels=tuple(
        dataclasses.replace(c, command_register=300 - 3 * i) for i, c in enumerate(reg_map.channels)))
    assert shuffled.command_block() is None
    with MockPlcServer(shuffled) as server:
        with PlcClient(shuffled, '127.0.0.1', server.port, timeout_s=0.5) as c:
            Controller(c).arm(server)
            p = np.linspace(5.0, 90.0, N)
            c.write_pressures(p)
            assert np.allclose(c.read_commands_kpa(), p, atol=0.05)
            assert np.allclose(server.commands_kpa(), p, atol=0.05)
        assert server.out_of_map_writes == []


def test_start_fails_loudly_when_the_port_is_taken(reg_map, plc):
    second = MockPlcServer(reg_map, port=plc.port)
    with pytest.raises(RuntimeError, match='did not start'):
        second.start()
    assert not second.running


def test_package_xml_states_the_supported_pymodbus_range_and_this_one_is_in_it():
    import xml.etree.ElementTree as ET
    from pathlib import Path
    root = Path(__file__).resolve().parent.parent
    (dep,) = [e for e in ET.parse(root / 'package.xml').getroot().findall('exec_depend')
              if e.text == 'python3-pymodbus']
    assert (dep.get('version_gte'), dep.get('version_lt')) == compat.SUPPORTED

    def version(text):
        return tuple(int(part) for part in text.split('.')[:3] if part.isdigit())
    low, high = (version(v) for v in compat.SUPPORTED)
    assert low <= version(compat.PYMODBUS_VERSION) < high
