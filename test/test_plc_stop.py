"""A stop from any connection, on the graph (docs/safety.md, "A stop from any connection"):
mock_plc and plc_output as processes (test_node_plc's rig: the test plays the controller, here
with its `vent` service too), the registers read over Modbus by the rig's read-only client.

- Another Modbus client (a pymodbus loop writing 200 kPa with its heartbeat every 0.1 s on one
  connection, as a tool left running) holds the PLC after plc_output's death; plc_output,
  restarted, is refused (06), writes the vent request after the PLC watchdog's time: the
  registers read 0 and stay 0 while the foreign writer goes on; its /diagnostics say ERROR with
  the other client's address; the controller's vent is called. The foreign writer gone, plc_output
  holds the PLC, still vented, until the controller commands pressure again after that vent
  (the operator's enable).
- A vent request from a tool (mbpoll when installed, else a pymodbus client) while plc_output
  guides: registers 0 at once, the controller vented, held until its next command with pressure;
  with no answer to that vent, held whatever the controller commands.
- A command stamped in the future (its publisher under faketime: a clock stepped back looks the
  same to plc_output) is not taken for fresh: vented, counted invalid with the reason.
"""
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from std_srvs.srv import Trigger

from fabric_guidance.nodes.plc_stop import KEPT_OUT_WATCHDOGS
from fabric_guidance.plc import PlcClient, PlcLinkError
from fabric_guidance.plc.records import load_records
from rosgraph import wait_until
from test_node_plc import (COMMAND_DEADLINE_S, DIAGNOSTICS_PERIOD_S, N, OUTPUT, OUTPUT_STATUS, PARAMS_FILES,
                           REGISTER_MAP, Rig, STARTUP_DEADLINE_S, VENT_MARGIN_S, record_vent)

pytestmark = pytest.mark.graph  # starts a process graph with DDS

FOREIGN_KPA = 200.0
GUIDED_KPA = 120.0
PLC_WATCHDOG_S = OUTPUT['plc_watchdog_s']
#: plc_output's first refusal (the mock's busy count, its records file lagging 0.1 s) -> the
#: registers read 0: two PLC watchdog times (plc_stop.KEPT_OUT_WATCHDOGS), the records' lag and
#: slack for a write cycle on a loaded machine.
KEPT_OUT_VENT_S = KEPT_OUT_WATCHDOGS * PLC_WATCHDOG_S + 0.1 + VENT_MARGIN_S
#: A vent request -> registers 0 (the request zeroes them; a read round trip and slack).
VENT_REQUEST_S = 0.3
#: The registers are watched this long for a pressure that must not come.
HOLD_S = 1.5
#: plc_output calls the controller's vent: service discovery on a loaded machine.
VENT_CALL_S = 10.0
#: The foreign writer gone -> plc_output holds the PLC again (its longest backoff) and says so.
BACK_S = OUTPUT['reconnect_max_s'] + DIAGNOSTICS_PERIOD_S + 3.0


class ForeignWriter:
    """A Modbus client of its own writing FOREIGN_KPA and its heartbeat every 0.1 s, on one
    connection (it keeps the write claim once it has it)."""

    def __init__(self, port: int):
        self.client = PlcClient(REGISTER_MAP, '127.0.0.1', port, timeout_s=0.5)
        self.errors: list[str] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        beat = 0
        while not self._stop.is_set():
            beat += 1
            try:
                self.client.write_heartbeat(beat)
                self.client.write_pressures([FOREIGN_KPA] * N)
            except PlcLinkError as exc:
                self.errors.append(str(exc))
            self._stop.wait(0.1)

    def close(self):
        self._stop.set()
        self._thread.join(2)
        self.client.close()


class ControllerVent:
    """The `vent` service of the test's controller: counts the calls; a vented controller
    publishes zeros (as pressure_controller does until the operator's enable)."""

    def __init__(self, rig: Rig):
        self.rig, self.calls = rig, []
        rig.probe.node.create_service(Trigger, '~/vent', self._on_vent)

    def _on_vent(self, request, response):
        self.rig.command(np.zeros(N))
        self.calls.append(time.monotonic())
        response.success, response.message = True, 'vented; call enable to guide again'
        return response


@pytest.fixture
def rig(tmp_path):
    made = []

    def make(**overrides):
        made.append(Rig(tmp_path / f'graph{len(made)}', **overrides))
        return made[-1]
    yield make
    for r in made:
        r.close()


def hold_zero(rig, what):
    end = time.monotonic() + HOLD_S
    reads = 0
    while time.monotonic() < end:
        r = rig.registers()
        assert r is not None and not np.any(r), f'{what}: registers read {r}'
        reads += 1
        time.sleep(0.01)
    return reads


def status_with(rig, text, level=None):
    for s in reversed(rig.statuses(OUTPUT_STATUS)):
        if text in s.message and (level is None or s.level == level):
            return s
    return None


def busy_count(rig) -> int:
    path = rig.graph.records_files[-1]
    try:
        return load_records(path).get('busy_count', 0)
    except (OSError, ValueError):
        return 0


def test_a_foreign_writer_cannot_keep_the_operator_s_stop_from_the_suit(rig):
    r = rig()
    vent = ControllerVent(r)
    r.command(np.full(N, GUIDED_KPA))
    r.wait_registers(np.full(N, GUIDED_KPA), COMMAND_DEADLINE_S, 'the controller guiding')
    # plc_output dies (its close vents); a foreign writer takes the PLC at 200 kPa.
    r.graph.stop('plc_output', signal.SIGKILL)
    foreign = ForeignWriter(r.port)
    try:
        r.wait_registers(np.full(N, FOREIGN_KPA), COMMAND_DEADLINE_S, 'the foreign writer holding the PLC')
        holder = r.client.read_claim_holder()
        assert holder.startswith('127.0.0.1:'), holder
        # plc_output restarted: refused (06), then the vent request.
        r.graph.start('plc_output', PARAMS_FILES, **r.output_overrides)
        wait_until(lambda: busy_count(r) > 0, STARTUP_DEADLINE_S, what='plc_output refused by the PLC (06)')
        refused = time.monotonic()
        seconds = r.time_to_vent(refused, KEPT_OUT_VENT_S, 'plc_output kept out by a foreign writer')
        record_vent('kept out by a foreign writer (from the first 06 seen)', seconds, KEPT_OUT_VENT_S)
        reads = hold_zero(r, 'the foreign writer writing 200 kPa after the vent request')
        assert not foreign.errors, foreign.errors[:3]   # it kept the PLC all along
        wait_until(lambda: status_with(r, holder, b'\x02'), DIAGNOSTICS_PERIOD_S + 3.0,
                   what=f'plc_output ERROR naming the claim holder {holder}')
        wait_until(lambda: vent.calls, VENT_CALL_S, what="the controller's vent called")
        print(f'\n[stop] kept out: registers 0 {seconds:.3f} s after the first refusal, {reads} reads '
              f'0 while the foreign writer went on; diagnostics: {status_with(r, holder).message}')
    finally:
        foreign.close()
    # The foreign writer gone: plc_output holds the PLC, which stays vented (latched) ...
    wait_until(lambda: status_with(r, 'vent latch set'), BACK_S, what='plc_output back, the latch reported')
    hold_zero(r, 'plc_output holding the PLC, the controller vented')
    assert r.client.read_vent_latched()
    # ... until the controller commands pressure again (after the operator's enable).
    r.command(np.full(N, GUIDED_KPA))
    r.wait_registers(np.full(N, GUIDED_KPA), COMMAND_DEADLINE_S, "guidance again after the operator's enable")
    assert not r.client.read_vent_latched()


def vent_request_by_a_tool(port: int) -> str:
    """The vent request from a client of its own: mbpoll when installed (a foreign tool), else
    a pymodbus client; returns which."""
    if shutil.which('mbpoll'):
        out = subprocess.run(['mbpoll', '-m', 'tcp', '-0', '-1', '-a', str(REGISTER_MAP.unit_id), '-t', '4',
                              '-r', str(REGISTER_MAP.vent_register), '-p', str(port), '127.0.0.1', '1'],
                             capture_output=True, text=True, timeout=20)
        assert out.returncode == 0, out.stdout + out.stderr
        return 'mbpoll'
    with PlcClient(REGISTER_MAP, '127.0.0.1', port) as client:
        client.request_vent()
    return 'pymodbus'


def test_a_vent_request_from_a_tool_stops_the_controller_until_it_guides_again(rig):
    r = rig()
    vent = ControllerVent(r)
    r.command(np.full(N, GUIDED_KPA))
    r.wait_registers(np.full(N, GUIDED_KPA), COMMAND_DEADLINE_S, 'the controller guiding')
    t0 = time.monotonic()
    tool = vent_request_by_a_tool(r.port)
    seconds = r.time_to_vent(t0, VENT_REQUEST_S + 1.0, f'a vent request by {tool}')
    record_vent(f'vent request by {tool} (from its start)', seconds, VENT_REQUEST_S + 1.0)
    wait_until(lambda: vent.calls, VENT_CALL_S, what="the controller's vent called by plc_output")
    hold_zero(r, 'plc_output writing on, the controller vented')
    r.command(np.full(N, GUIDED_KPA))
    r.wait_registers(np.full(N, GUIDED_KPA), COMMAND_DEADLINE_S, "guidance again after the operator's enable")


def test_without_the_controller_s_vent_answered_pressure_never_re_arms(rig):
    """The controller never answers plc_output's vent (none is offered here): its commands with
    pressure go on, and plc_output's ordinary writes of them never lift the PLC's latch."""
    r = rig()
    r.command(np.full(N, GUIDED_KPA))
    r.wait_registers(np.full(N, GUIDED_KPA), COMMAND_DEADLINE_S, 'the controller guiding')
    tool = vent_request_by_a_tool(r.port)
    r.time_to_vent(time.monotonic(), VENT_REQUEST_S + 1.0, f'a vent request by {tool}')
    wait_until(lambda: status_with(r, 'vent latch set'), DIAGNOSTICS_PERIOD_S + 3.0,
               what='plc_output reporting the latch')
    hold_zero(r, 'pressure commanded on, no vent answered')
    assert r.client.read_vent_latched()


@pytest.mark.skipif(shutil.which('faketime') is None, reason='faketime not installed (Debian package faketime)')
def test_a_command_stamped_in_the_future_is_not_taken_for_fresh(rig):
    r = rig()
    script = str(Path(__file__).with_name('stamped_publisher.py'))

    def publish(*prefix):
        # A session of its own: faketime runs the publisher as its child, and killing faketime
        # alone left the publisher sending into later tests' graphs for its 60 s.
        return subprocess.Popen([*prefix, sys.executable, script, str(r.graph.domain_id), str(GUIDED_KPA), '60'],
                                env=dict(r.graph.env, PYTHONPATH=os.pathsep.join(sys.path)), start_new_session=True)

    def end(proc):
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    ahead = publish('faketime', '-f', '+5s')
    try:
        # Heard (found invalid, or written: the old behaviour, age 0), then watched.
        wait_until(lambda: status_with(r, 'in the future') or np.any(r.registers()), STARTUP_DEADLINE_S,
                   what='plc_output hearing the command stamped 5 s ahead')
        hold_zero(r, 'commands stamped 5 s in the future')
        assert 's in the future by its source timestamp' in status_with(r, 'in the future').message
    finally:
        end(ahead)
    # The control: the same publisher on the host's clock is written.
    honest = publish()
    try:
        r.wait_registers(np.full(N, GUIDED_KPA), STARTUP_DEADLINE_S, 'the same command, stamped now')
    finally:
        end(honest)
