"""Faults on the Modbus TCP link, injected by a proxy (bench/faultproxy.py) between the client and
the mock PLC: drop, disconnect, half-open, and a delay that lets an old command arrive late.

First the PLC layer alone (PlcClient against MockPlcServer, no ROS): a write held on a dead
connection and delivered after a newer one is refused by the write sequence number, and
without the sequence register it would overwrite the newer command (the hazard is real).
Then plc_output and mock_plc as processes with the proxy between them, one graph for every
link fault: the outage shows at ERROR on /diagnostics, the PLC's watchdog vents meanwhile,
and once the link heals the latest command is back in the registers. Deadlines are asserted,
the worst times printed (run with -s or -rP).
"""
import dataclasses
import time

from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np
import pytest

from deadlines import DeadlineLog
from fabric_guidance.bench.faultproxy import FaultProxy, is_modbus_write_multiple
from fabric_guidance.plc import PlcClient, PlcLinkError
from fabric_guidance.plc.modbus import PlcRefusedError
from fabric_guidance.plc.mock_server import MockPlcServer
from rosgraph import free_port, wait_until
from test_node_plc import MOCK, N, OUTPUT, REGISTER_MAP   # the parameters as the graph gets them

pytestmark = pytest.mark.graph  # starts a process graph with DDS

TOLERANCE_KPA = 0.1
MODBUS_TIMEOUT_S = OUTPUT['modbus_timeout_s']
WATCHDOG_S = MOCK['watchdog_s']
DIAGNOSTICS_PERIOD_S = OUTPUT['diagnostics_period_s']
RECONNECT_MIN_S, RECONNECT_MAX_S = OUTPUT['reconnect_min_s'], OUTPUT['reconnect_max_s']
COMMAND_RATE_HZ = 20.0
POLL_S = 0.01

# ---- deadlines
STARTUP_DEADLINE_S = 20.0
COMMAND_DEADLINE_S = 2.0
#: Outage -> plc_output ERROR on /diagnostics: a request times out, then at most one period.
OUTAGE_ERROR_DEADLINE_S = MODBUS_TIMEOUT_S + DIAGNOSTICS_PERIOD_S + 1.0
#: Outage -> the PLC's watchdog vented (heartbeats stop with the link; scan, poll, slack).
OUTAGE_VENT_DEADLINE_S = WATCHDOG_S + 0.5
#: Link healed -> the latest command back in the registers: the longest backoff, a write
#: cycle, the watchdog re-arming on the second heartbeat, and slack.
HEAL_DEADLINE_S = RECONNECT_MAX_S + 1.5
#: Half-open -> the command flows again: one request timeout, the shortest backoff, slack
#: (the PLC's watchdog need not even trip).
HALF_OPEN_RESUME_DEADLINE_S = MODBUS_TIMEOUT_S + RECONNECT_MIN_S + 1.5
#: How long a write is held on its dead connection: well past the client's timeout, so that
#: the client has reconnected and written a newer command before it lands.
HOLD_S = 0.8
#: The most a loaded two-core machine added to a round trip through the delaying proxy, beyond
#: the injected delay: 124 ms over 245 writes at load 7-12 (python -m
#: fabric_guidance.bench.link_margin --delay-ms 60; p99 41 ms, p99.9 111 ms).
LOADED_EXCESS_S = 0.125

OUTPUT_STATUS = 'plc_output: PLC output'
LOG = DeadlineLog('link')
record = LOG.record


report = LOG.report_at_module_end('worst times, link faults')


def command(k):
    """A distinct, non-round command vector per k, below p_max."""
    return np.round(10.0 + 7.3 * k + 11.1 * np.arange(N), 1) % 300.0


# ------------------------------------------------------------ the PLC layer on its own
@pytest.mark.parametrize('sequenced', [True, False], ids=['sequence register', 'no sequence register'])
def test_a_write_delayed_on_a_dead_connection_never_overwrites_a_newer_one(sequenced):
    """The dead connection still holds the PLC's write claim until its held write and the close
    behind it arrive: the client's new connection is refused (exception 06) until then, so the
    newer command C lands after the late B, never before it, with or without sequence numbers."""
    reg_map = REGISTER_MAP if sequenced else dataclasses.replace(REGISTER_MAP, sequence_register=None)
    assert (reg_map.sequenced_block() is not None) == sequenced
    # A long watchdog: only the writes under test and the claim holder's close change the registers.
    with MockPlcServer(reg_map, watchdog_s=60.0, regulator_tau_s=0.0, log_registers=True) as plc, \
            FaultProxy('127.0.0.1', plc.port) as proxy:
        client = PlcClient(reg_map, '127.0.0.1', proxy.port, timeout_s=0.2)
        beat = [0]

        def armed():
            beat[0] += 1
            client.write_heartbeat(beat[0])
            return plc.watchdog_armed
        try:
            wait_until(armed, 2.0, what='the watchdog to arm')
            a, b, c = command(1), command(2), command(3)
            client.write_pressures(a)
            assert np.allclose(plc.commands_kpa(), a, atol=TOLERANCE_KPA)
            proxy.hold(HOLD_S, when=is_modbus_write_multiple)
            with pytest.raises(PlcLinkError):
                client.write_pressures(b)        # held in the proxy: times out, the client drops it
            assert proxy.get('held_chunks') == 1
            refusals = []

            def c_written():   # on a new connection, refused while the dead one holds the claim
                try:
                    client.write_pressures(c)
                except PlcRefusedError as exc:
                    refusals.append(exc.code)
                    return False
                return True
            wait_until(c_written, HOLD_S + 2.0, what='C written once the dead connection is gone')
            assert proxy.get('delivered_after_client_closed') == 1
            assert refusals and set(refusals) == {6}, refusals
            wait_until(armed, 2.0, what='the watchdog armed again by the new connection')
            client.write_pressures(c)
            now = plc.commands_kpa()
            log = plc.take_register_log()
        finally:
            client.close()
    np.testing.assert_allclose(now, c, atol=TOLERANCE_KPA, err_msg='C is not the command in force')
    encoded = {k: tuple(reg_map.encode(v)) for k, v in (('b', b), ('c', c))}
    first_c = next(i for i, e in enumerate(log) if e[2] == encoded['c'])
    assert not [e for e in log[first_c:] if e[2] == encoded['b']], 'the late, older write overwrote C'


def test_a_restarted_client_is_not_taken_for_a_stale_one():
    """A new plc_output process starts its counter afresh: it reads the PLC's last number and
    jumps ahead of it, instead of being refused until its counter catches up."""
    with MockPlcServer(REGISTER_MAP, watchdog_s=60.0, regulator_tau_s=0.0) as plc:
        first = PlcClient(REGISTER_MAP, '127.0.0.1', plc.port, timeout_s=0.5)
        for k in range(5):
            first.write_pressures(command(k))
        first.close()
        second = PlcClient(REGISTER_MAP, '127.0.0.1', plc.port, timeout_s=0.5)
        try:
            second.write_pressures(command(9))
            assert np.allclose(second.read_commands_kpa(), command(9), atol=TOLERANCE_KPA)
        finally:
            second.close()
        assert plc.stale_writes == []


# ------------------------------------------- plc_output and mock_plc with the proxy between
class LinkRig:
    """test_node_plc's Rig (mock_plc, plc_output, a probe playing the controller, a read-only
    client on the mock), with plc_output talking to the mock through a FaultProxy."""

    def __init__(self, log_dir):
        from test_node_plc import Rig
        port = free_port()
        self.proxy = FaultProxy('127.0.0.1', port)
        self.rig = Rig(log_dir, output={'plc_port': self.proxy.port}, port=port)

    def status_since(self, n):
        return self.rig.statuses(OUTPUT_STATUS, n)

    def output_values(self):
        return {kv.key: kv.value for kv in self.rig.latest_status(OUTPUT_STATUS).values}

    def mock_records(self):
        from fabric_guidance.plc.records import load_records
        return load_records(self.rig.graph.records_files[-1])

    def close(self):
        self.proxy.heal()
        try:
            self.rig.close()
        finally:
            self.proxy.close()


@pytest.fixture(scope='module')
def link(tmp_path_factory):
    rig = LinkRig(tmp_path_factory.mktemp('link'))
    yield rig
    rig.close()


def _wait_status(link, n, level, deadline_s, what):
    return wait_until(lambda: any(s.level == level for s in link.status_since(n)), deadline_s, what=what)


@pytest.mark.parametrize('fault', ['drop', 'disconnect'])
def test_an_outage_shows_at_error_vents_and_heals_with_the_latest_command(link, fault):
    rig, proxy = link.rig, link.proxy
    a, b = command(10 + LOG.count('outage vented by the PLC watchdog')), command(40)
    rig.command(a)
    rig.wait_registers(a, COMMAND_DEADLINE_S, 'command A in the registers before the fault')
    before = link.output_values() if rig.latest_status(OUTPUT_STATUS) else {'link failures': '0', 'reconnects': '0'}
    n = len(rig.diagnostics)
    t0 = time.monotonic()
    getattr(proxy, fault)()
    seconds = rig.time_to_vent(t0, OUTAGE_VENT_DEADLINE_S, f'{fault}: the PLC watchdog venting during the outage')
    record('outage vented by the PLC watchdog', seconds, OUTAGE_VENT_DEADLINE_S)
    _wait_status(link, n, DiagnosticStatus.ERROR, OUTAGE_ERROR_DEADLINE_S,
                 f'plc_output ERROR on /diagnostics ({fault})')
    record('outage -> ERROR on /diagnostics', time.monotonic() - t0, OUTAGE_ERROR_DEADLINE_S)
    error = next(s for s in link.status_since(n) if s.level == DiagnosticStatus.ERROR)
    assert 'PLC link down' in error.message, error
    rig.command(b)                       # the controller goes on; its latest command changes
    rig.assert_stays_vented(0.5, f'{fault}: no command may reach the PLC while the link is down')
    assert proxy.get('dropped_chunks' if fault == 'drop' else 'refused') > 0, proxy.counts

    t_heal = time.monotonic()
    proxy.heal()
    rig.wait_registers(b, HEAL_DEADLINE_S, f'{fault} healed: the latest command B in the registers', hold_s=0.2)
    record('link healed -> latest command in the registers', time.monotonic() - t_heal - 0.2, HEAL_DEADLINE_S)
    n = len(rig.diagnostics)
    _wait_status(link, n, DiagnosticStatus.OK, DIAGNOSTICS_PERIOD_S + 2.0, 'plc_output OK again')
    after = link.output_values()
    assert int(after['link failures']) > int(before['link failures']), (before, after)
    assert int(after['reconnects']) > int(before['reconnects']), (before, after)


def test_a_half_open_link_is_noticed_by_the_timeout_and_reconnected(link):
    rig, proxy = link.rig, link.proxy
    a, b = command(50), command(51)
    rig.command(a)
    rig.wait_registers(a, COMMAND_DEADLINE_S, 'command A in the registers')
    wait_until(lambda: rig.latest_status(OUTPUT_STATUS), 5.0, what='a plc_output status')
    before = link.output_values()
    accepted = proxy.get('accepted')
    t0 = time.monotonic()
    proxy.half_open()
    rig.command(b)
    rig.wait_registers(b, HALF_OPEN_RESUME_DEADLINE_S, 'command B through a new connection after the half-open one')
    record('half-open link -> command flowing on a new connection', time.monotonic() - t0,
           HALF_OPEN_RESUME_DEADLINE_S)
    assert proxy.get('half_opened') >= 1 and proxy.get('accepted') > accepted, proxy.counts
    n = len(rig.diagnostics)
    wait_until(lambda: link.status_since(n), DIAGNOSTICS_PERIOD_S + 2.0, what='a plc_output status')
    after = link.output_values()
    assert int(after['link failures']) > int(before['link failures']), (before, after)


def test_a_delayed_link_never_lets_an_old_command_overwrite_a_newer_one(link):
    """A write of A held on the connection plc_output drops: its new connection is refused by
    the PLC (the dead one holds the write claim) until A and the close behind it have landed;
    then B, and from then on every read is B."""
    rig, proxy = link.rig, link.proxy
    a, b = command(60), command(61)
    rig.command(a)
    rig.wait_registers(a, COMMAND_DEADLINE_S, 'command A in the registers')
    proxy.hold(HOLD_S, when=is_modbus_write_multiple)
    wait_until(lambda: proxy.get('held_chunks'), 2.0, what='a write of A held on the current connection')
    rig.command(b)
    wait_until(lambda: proxy.get('delivered_after_client_closed'), HOLD_S + 2.0,
               what='the held write of A delivered after plc_output dropped that connection')
    rig.wait_registers(b, MODBUS_TIMEOUT_S + RECONNECT_MAX_S + WATCHDOG_S + 1.0, 'B written on a new connection')
    # From here the registers must hold B.
    seen = []
    t_end = time.monotonic() + 0.3
    while time.monotonic() < t_end:
        r = rig.registers()
        if r is not None:
            seen.append(r)
        time.sleep(0.002)
    wrong = [r for r in seen if np.max(np.abs(r - b)) > TOLERANCE_KPA]
    assert not wrong, f'{len(wrong)} of {len(seen)} reads were not B, e.g. {wrong[0]}'
    records = link.mock_records()
    print(f'\n[link] writes refused while the dead connection held the claim: {records.get("busy_count")}; '
          f'{len(seen)} reads all B')
    proxy.heal()


def test_a_slow_link_below_the_timeout_keeps_commands_flowing(link):
    """delay mode: 25 ms each way, a round trip 50 times the link's own, and below
    modbus_timeout_s by more than a loaded machine adds on top of it: slower round trips, no
    link failure. With 60 ms each way (80 ms left) a loaded run counted a failure."""
    rig, proxy = link.rig, link.proxy
    delay_s = 0.025
    assert 2 * delay_s + LOADED_EXCESS_S <= MODBUS_TIMEOUT_S
    rig.command(command(70))
    rig.wait_registers(command(70), COMMAND_DEADLINE_S, 'command in the registers')
    # The baseline from a status published after the link carried this command (an earlier
    # test's failure may still have been on its way to /diagnostics).
    n = len(rig.diagnostics)
    wait_until(lambda: link.status_since(n), DIAGNOSTICS_PERIOD_S + 2.0, what='a fresh plc_output status')
    failures = int(link.output_values()['link failures'])
    proxy.delay(delay_s)
    try:
        rig.command(command(71))
        rig.wait_registers(command(71), COMMAND_DEADLINE_S + 4 * delay_s, 'the command through the slow link')
        n = len(rig.diagnostics)

        def round_trip_ms(status):
            return float(dict((kv.key, kv.value) for kv in status.values)['last round trip ms'])
        wait_until(lambda: [s for s in link.status_since(n) if round_trip_ms(s) >= 2e3 * delay_s],
                   DIAGNOSTICS_PERIOD_S + 2.0, what=f'a round trip of at least {2e3 * delay_s:.0f} ms on /diagnostics')
    finally:
        proxy.heal()
    assert int(link.output_values()['link failures']) == failures
