"""The lab graph against the PLC program's host build (firmware/host) in place of mock_plc:
the faults that matter on the PLC side, measured at the program's outputs (its state file
shows what reached each analog output), not only at its registers.

One graph for the module: plc_output talks to the program through a FaultProxy (link faults);
gaze_bridge, target_selector and pressure_controller as in test_graph.py, the wearer guided to
a target 40 deg left (L1, L2 at the calibrated pressure). Worst times are printed at the end
(run with -s or -rP). The program's write records are held to the same invariants as every
mock_plc's (plc/records.py), except the over-limit write this module injects on purpose.
"""
import signal
import socket
import struct
import subprocess
import threading
import time

import pytest

from deadlines import DeadlineLog
from fabric_guidance.plc.records import load_records, violations
from fabric_guidance.bench.faultproxy import FaultProxy, is_modbus_write_multiple
from plc_program import PlcProgram, need_tools, wait_listening
from rosgraph import Graph, free_port, wait_until
from guided_lab import GUIDED, GuidedLab, guided_overrides, guided_until_closed
from test_graph import F_LEFT_40, REGMAP, WATCHDOG_VENT_S

pytestmark = pytest.mark.graph  # starts a process graph with DDS
N = len(REGMAP)
P_MAX = REGMAP.p_max_counts
#: The program's watchdog and scan, as mock_plc's defaults (watchdog_s 0.5, 100 Hz).
WATCHDOG_S, SCAN_S = 0.5, 0.01
#: Heartbeat gone (plc_output killed, link lost) -> every output at 0: the watchdog, one scan,
#: the state file written in that scan, polling slack: the same deadline as test_graph.py's.
OUTPUT_VENT_S = WATCHDOG_VENT_S
#: A node restarted or the link healed -> guidance back at the registers (cold start of a
#: process on 2 loaded cores; plc_output's reconnect backoff, at most 5 s).
RESTART_DEADLINE_S = 30.0
EXIT_DEADLINE_S = 10.0
POLL_S = 0.005
#: How long the proxy holds plc_output's guidance write: longer than plc_output's reconnect plus
#: the vent after the gaze stops, so the vent is in before the old write lands.
HOLD_S = 3.0

LOG = DeadlineLog('PLC program')


class ProgramLab(GuidedLab):
    def __init__(self, log_dir):
        self.graph = Graph(log_dir)
        self.plc_port, self.gaze_port = free_port(), free_port(socket.SOCK_DGRAM)
        self.program = PlcProgram(log_dir / 'plc_program.records.json', REGMAP, port=self.plc_port,
                                  watchdog_s=WATCHDOG_S, scan_s=SCAN_S)
        proc = subprocess.Popen(self.program.args(), stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True)
        self.graph.processes['plc_program'] = self.program.proc = proc
        wait_listening(proc, 10.0)
        # Checked by the graph at the end like a mock_plc's records (see close()).
        self.graph.records_files.append(self.program.state_path)
        self.injected_over_limit: list[list[int]] = []
        self.proxy = FaultProxy('127.0.0.1', self.plc_port)
        self.overrides = guided_overrides(log_dir, self.proxy.port, self.gaze_port)
        self.start_all()

    def state(self) -> dict:
        return self.program.state()

    def guided(self, deadline_s=RESTART_DEADLINE_S, what='guidance at the registers'):
        wait_until(lambda: self.watch.matches(GUIDED), deadline_s,
                   what=f'{what}: L1, L2 at {F_LEFT_40:.1f} kPa')
        wanted = round(F_LEFT_40 * REGMAP.counts_per_kpa)
        at = [REGMAP.names.index(c) for c in GUIDED]
        wait_until(lambda: all(abs(self.state()['output_counts'][i] - wanted) <= 1 for i in at),
                   2.0, what=f'{what}: L1, L2 outputs at {wanted} counts')

    def time_to_vented_outputs(self, t0, deadline_s, what) -> float:
        while True:
            outputs = self.state()['output_counts']
            if not any(outputs):
                return time.monotonic() - t0
            if time.monotonic() - t0 > deadline_s:
                raise AssertionError(f'{what}: outputs not vented {time.monotonic() - t0:.3f} s '
                                     f'after the fault (deadline {deadline_s:.3f} s); '
                                     f'outputs {outputs}')
            time.sleep(POLL_S)

    def close(self):
        self.hololens.close()
        self.graph.stop_all(check=False)
        self.watch.client.close()
        self.proxy.close()
        # The program's records under the graphs' invariants, with the writes this module
        # injected above p_max taken out (they must be exactly those).
        records = load_records(self.program.state_path)
        assert records['over_limit_writes'] == self.injected_over_limit, records
        for address, _value in self.injected_over_limit:
            records['max_written_counts'][REGMAP.names[address]] = 0
        records['over_limit_count'], records['over_limit_writes'] = 0, []
        found = violations(records, source='PLC program')
        assert not found, '\n'.join(found)
        assert max(records['max_output_counts']) <= P_MAX, records


@pytest.fixture(scope='module')
def lab(tmp_path_factory):
    need_tools('make', 'g++')
    with guided_until_closed(ProgramLab(tmp_path_factory.mktemp('plc_program_graph')), LOG,
                             'worst times, graph against the PLC program') as lab:
        yield lab


def raw_request(port: int, pdu: bytes) -> bytes:
    """One Modbus TCP request on a fresh connection; the answer's PDU."""
    with socket.create_connection(('127.0.0.1', port), timeout=2.0) as s:
        s.sendall(struct.pack('>HHHB', 1, 0, len(pdu) + 1, REGMAP.unit_id) + pdu)
        data = b''
        while len(data) < 7 or len(data) < 6 + struct.unpack('>H', data[4:6])[0]:
            chunk = s.recv(260)
            assert chunk, 'connection closed by the PLC program'
            data += chunk
        return data[7:]


def command_pdu(counts: list[int], seq: int) -> bytes:
    values = counts + [seq]
    return struct.pack(f'>BHHB{len(values)}H', 16, 0, len(values), 2 * len(values), *values)


def sequence_now(lab) -> int:
    """The last sequence number the program applied (plc_output's, in this graph)."""
    answer = raw_request(lab.plc_port, struct.pack('>BHH', 3, REGMAP.sequence_register, 1))
    assert answer[:2] == b'\x03\x02', answer.hex()
    return struct.unpack('>H', answer[2:4])[0]


def test_guidance_reaches_the_outputs_and_nothing_else_is_driven(lab):
    lab.guided()
    outputs = lab.state()['output_counts']
    others = [o for name, o in zip(REGMAP.names, outputs) if name not in GUIDED]
    assert others == [0] * (N - len(GUIDED))


def test_sigkill_of_plc_output_vents_the_outputs_within_the_watchdog(lab):
    """The kernel closes the killed process's connection: the program vents as soon as it sees
    the close of the write claim's holder (one scan), not only at the watchdog."""
    lab.guided()
    lost, trips = lab.state()['owner_lost_count'], lab.state()['watchdog_trips']
    proc = lab.graph.processes['plc_output']
    t0 = time.monotonic()
    proc.kill()
    seconds = lab.time_to_vented_outputs(t0, OUTPUT_VENT_S, 'SIGKILL of plc_output')
    LOG.record('SIGKILL of plc_output -> outputs 0 (its connection closed)', seconds, OUTPUT_VENT_S)
    assert proc.wait(EXIT_DEADLINE_S) == -signal.SIGKILL
    assert lab.state()['owner_lost_count'] == lost + 1
    assert lab.state()['watchdog_trips'] == trips + 1
    wait_until(lambda: lab.watch.matches({}), 1.0,
               what='the command registers zeroed with the outputs')
    lab.start('plc_output')
    lab.guided(what='guidance back with a new plc_output')


def test_a_second_client_s_write_is_refused_and_changes_nothing(lab):
    """plc_output holds the write claim: a second client's command write, numbered ahead of
    plc_output's, gets exception 06 and no output moves (the sequence gate alone would have
    taken it)."""
    lab.guided()
    before = lab.state()['busy_count']
    ahead = (sequence_now(lab) + 1024) % 65536
    answer = raw_request(lab.plc_port, command_pdu([3000] * N, ahead))
    assert answer == bytes([0x90, 6]), answer.hex()
    wait_until(lambda: lab.state()['busy_count'] >= before + 1, 2.0, what='the refused write counted')
    # No channel guidance leaves at 0 ever had an output: 3000 counts there would only come from
    # the refused write (the program keeps each output's maximum; plc_output's next write would
    # hide it from a read of the registers).
    maxima = lab.state()['max_output_counts']
    assert [n for n, m in zip(REGMAP.names, maxima) if m and n not in GUIDED] == [], maxima
    # and guidance goes on as it was (waited for: a loaded machine may vent on a late gaze sample
    # in between, and resume with the next)
    lab.guided(deadline_s=20.0, what='guidance after the refused write')


class Writer:
    """A Modbus client of its own on the program: heartbeat and commands on one connection."""

    def __init__(self, port: int):
        self.sock = socket.create_connection(('127.0.0.1', port), timeout=2.0)
        self.beat = 0

    def ask(self, pdu: bytes) -> bytes:
        self.sock.sendall(struct.pack('>HHHB', 1, 0, len(pdu) + 1, REGMAP.unit_id) + pdu)
        data = b''
        while len(data) < 7 or len(data) < 6 + struct.unpack('>H', data[4:6])[0]:
            chunk = self.sock.recv(260)
            assert chunk, 'connection closed by the PLC program'
            data += chunk
        return data[7:]

    def heartbeat(self) -> bytes:
        self.beat += 1
        return self.ask(struct.pack('>BHH', 6, REGMAP.heartbeat_register, self.beat))

    def close(self) -> None:
        self.sock.close()


def test_over_limit_counts_never_reach_an_output(lab):
    """plc_output stopped (its close vents and frees the PLC), a client of its own claims it,
    arms the watchdog and writes 65535 counts: F1's output goes to p_max, never above; its close
    vents, and guidance comes back with a new plc_output."""
    lab.guided()
    lab.graph.stop('plc_output')
    wait_until(lambda: lab.state()['owner'] == 0 and not any(lab.state()['output_counts']), 5.0,
               what='the PLC free and vented after plc_output stopped')
    f1 = REGMAP.names.index('F1')
    counts = [0] * N
    counts[f1] = 0xFFFF
    writer = Writer(lab.plc_port)
    try:
        def armed():
            assert writer.heartbeat() == struct.pack('>BHH', 6, REGMAP.heartbeat_register, writer.beat)
            return not lab.state()['vented']
        wait_until(armed, 3.0, what='the watchdog armed by the new client')
        lab.injected_over_limit.append([f1, 0xFFFF])
        assert writer.ask(command_pdu(counts, 1)) == struct.pack('>BHH', 16, 0, N + 1)

        def at_p_max():
            writer.heartbeat()
            return lab.state()['output_counts'][f1] == P_MAX
        wait_until(at_p_max, 2.0, what='F1 output at p_max')
    finally:
        writer.close()
    state = lab.state()
    assert max(state['max_output_counts']) <= P_MAX, state['max_output_counts']
    lab.start('plc_output')
    lab.guided(what='guidance back with a new plc_output')
    assert max(lab.state()['max_output_counts']) <= P_MAX


@pytest.mark.parametrize('fault', ['drop', 'disconnect'])
def test_link_loss_vents_the_outputs_within_the_watchdog(lab, fault):
    lab.guided()
    t0 = time.monotonic()
    getattr(lab.proxy, fault)()
    seconds = lab.time_to_vented_outputs(t0, OUTPUT_VENT_S, f'link {fault}')
    LOG.record(f'link {fault} -> outputs 0 (watchdog, or the close reaching the PLC)', seconds, OUTPUT_VENT_S)
    assert lab.state()['vented']
    lab.proxy.heal()
    lab.guided(what=f'guidance back after the link {fault} healed')


def test_a_guidance_write_delayed_past_the_vent_is_undone_by_the_program(lab):
    """A command write held on a dead connection lands after the suit was vented: refused (the
    dead connection lost the write claim when its heartbeat fell silent), undone by the sequence
    gate, or applied to a vented watchdog, no output moves."""
    lab.guided()
    lab.proxy.hold(HOLD_S, when=is_modbus_write_multiple)
    wait_until(lambda: lab.proxy.get('held_chunks'), 2.0,
               what="a guidance write of plc_output's held")
    held_at = time.monotonic()
    lab.hololens.sending.clear()   # the gaze stops: the controller vents, plc_output writes zeros
    wait_until(lambda: lab.watch.matches({}) and not any(lab.state()['output_counts']),
               HOLD_S - 0.5, what='registers and outputs vented on a new connection')
    assert lab.proxy.get('held_delivered') == 0, \
        'the held write landed before the vent: nothing shown'
    outputs_seen = []
    done = threading.Event()

    def watch():
        while not done.is_set():
            outputs_seen.append(max(lab.state()['output_counts']))
            time.sleep(0.002)
    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    try:
        wait_until(lambda: lab.proxy.get('delivered_after_client_closed'), HOLD_S + 2.0,
                   what='the held write delivered after plc_output dropped that connection')
        time.sleep(0.1)   # ten scans after it
    finally:
        done.set()
        watcher.join(2)
    print(f'\n[PLC program] late write landed {time.monotonic() - held_at:.2f} s after it was '
          f'sent; '
          f'refused {lab.state()["busy_count"]}, stale writes {lab.state()["stale_writes"]}; '
          f'{len(outputs_seen)} output reads all 0')
    assert max(outputs_seen) == 0, 'an output moved after the vent'
    assert lab.watch.matches({})
    lab.proxy.heal()
    lab.hololens.sending.set()
    lab.guided(what='guidance back with the gaze')
