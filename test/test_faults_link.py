"""Faults on the Modbus TCP link, injected by a proxy (faultproxy.py) between the client and
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
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import pytest
from std_msgs.msg import Float64MultiArray
import yaml

from faultproxy import FaultProxy, is_modbus_write_multiple
from fabric_guidance.nodes.common import COMMAND_QOS, DIAGNOSTICS, MEASURED_PRESSURE, PRESSURE_COMMAND
from fabric_guidance.plc import PlcClient, PlcLinkError, RegisterMap
from fabric_guidance.plc.modbus import MockPlcServer
from rosgraph import CONFIG, Graph, Probe, free_port, wait_until

PARAMS_FILES = ('guidance.yaml', 'sim.yaml')


def _parameters(node):
    merged = {}
    for name in PARAMS_FILES:
        merged.update(yaml.safe_load((CONFIG / name).read_text()).get(node, {}).get('ros__parameters', {}))
    return merged


OUTPUT, MOCK = _parameters('plc_output'), _parameters('mock_plc')
REGISTER_MAP = RegisterMap.load(CONFIG / 'plc_register_map.yaml')
N = len(REGISTER_MAP)
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

OUTPUT_STATUS = 'plc_output: PLC output'
TIMES: dict[str, list[tuple[float, float]]] = {}


def record(kind, seconds, deadline_s):
    TIMES.setdefault(kind, []).append((seconds, deadline_s))
    print(f'\n[link] {kind}: {seconds:.3f} s (deadline {deadline_s:.3f} s)')


@pytest.fixture(scope='module', autouse=True)
def report():
    yield
    if TIMES:
        print('\nworst times, link faults:')
        for kind, times in TIMES.items():
            worst, deadline = max(times)
            print(f'  {kind:<60} worst {worst:.3f} s of {len(times)}, deadline {deadline:.3f} s')


def command(k):
    """A distinct, non-round command vector per k, below p_max."""
    return np.round(10.0 + 7.3 * k + 11.1 * np.arange(N), 1) % 300.0


# ------------------------------------------------------------ the PLC layer on its own
@pytest.mark.parametrize('sequenced', [True, False], ids=['sequence register', 'no sequence register'])
def test_a_write_delayed_on_a_dead_connection_never_overwrites_a_newer_one(sequenced):
    reg_map = REGISTER_MAP if sequenced else dataclasses.replace(REGISTER_MAP, sequence_register=None)
    assert (reg_map.sequenced_block() is not None) == sequenced
    # A long watchdog, armed once: only the writes under test change the registers.
    with MockPlcServer(reg_map, watchdog_s=60.0, regulator_tau_s=0.0) as plc, \
            FaultProxy('127.0.0.1', plc.port) as proxy:
        client = PlcClient(reg_map, '127.0.0.1', proxy.port, timeout_s=0.2)
        direct = PlcClient(reg_map, '127.0.0.1', plc.port, timeout_s=1.0)
        try:
            beat = [0]

            def armed():
                beat[0] += 1
                direct.write_heartbeat(beat[0])
                return plc.watchdog_armed
            wait_until(armed, 2.0, what='the watchdog to arm')
            a, b, c = command(1), command(2), command(3)
            client.write_pressures(a)
            assert np.allclose(plc.commands_kpa(), a, atol=TOLERANCE_KPA)

            proxy.hold(HOLD_S, when=is_modbus_write_multiple)
            with pytest.raises(PlcLinkError):
                client.write_pressures(b)        # held in the proxy: times out, the client drops it
            assert proxy.get('held_chunks') == 1
            client.write_pressures(c)            # a new connection, not held
            assert np.allclose(plc.commands_kpa(), c, atol=TOLERANCE_KPA)
            wait_until(lambda: proxy.get('held_delivered') == 1, HOLD_S + 2.0, what='the held write delivered')
            assert proxy.get('delivered_after_client_closed') == 1
            # The late write has been handed to the server; give it its scan, then look.
            wait_until(lambda: (len(plc.stale_writes) == 1) if sequenced else
                       np.allclose(plc.commands_kpa(), b, atol=TOLERANCE_KPA), 2.0, what='the late write handled')
            now = plc.commands_kpa()
        finally:
            client.close()
            direct.close()
    if sequenced:
        np.testing.assert_allclose(now, c, atol=TOLERANCE_KPA, err_msg='the late, older write overwrote C')
        (seq, last), = plc.stale_writes
        assert seq != last
    else:
        # Without numbers the older command B wins over C: what the sequence register prevents.
        np.testing.assert_allclose(now, b, atol=TOLERANCE_KPA)


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
