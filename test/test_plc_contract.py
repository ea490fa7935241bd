"""The PLC contract (docs/plc.md), one suite for every server that claims it: the PLC program's
host build (firmware/) and the Python MockPlcServer. Raw Modbus TCP frames, so the exact bytes
are checked, plus mbpoll (libmodbus) as a foreign client comparing the two.

Everything here is observable on the wire, so the same assertions hold for both servers.
"""
from __future__ import annotations

import re
import socket
import struct
import subprocess
import threading
import time

import pytest

from deadlines import DeadlineLog
from fabric_guidance.plc import MockPlcServer, RegisterMap
from plc_program import PlcProgram, need_tools
from rosgraph import CONFIG, wait_until

REGMAP = RegisterMap.load(CONFIG / 'hardware/plc_register_map.yaml')
N = len(REGMAP)
SEQ, HEARTBEAT, VENT = N, N + 1, N + 2
#: Holding and input registers: commands, sequence, heartbeat, vent register; measured, the
#: claim holder's address (3).
HOLDING, INPUT = N + 3, N + 3
UNIT = REGMAP.unit_id
P_MAX = REGMAP.p_max_counts
WATCHDOG_S = 0.5
#: Watchdog trip -> registers read 0: one scan (10 ms) plus a read round trip and load slack.
WATCHDOG_VENT_S = WATCHDOG_S + 0.01 + 0.3
#: How long silence must last to count as no answer.
SILENCE_S = 0.5

SERVERS = ['program', 'mock']
LOG = DeadlineLog('contract')


class Server:
    """A running server of either kind; port and unit id are what a client needs."""

    def __init__(self, kind: str, tmp_path):
        self.kind = kind
        if kind == 'program':
            self._impl = PlcProgram(tmp_path / 'plc.state.json', REGMAP,
                                    watchdog_s=WATCHDOG_S).start()
        else:
            self._impl = MockPlcServer(REGMAP, port=0, watchdog_s=WATCHDOG_S).start()
        self.port = self._impl.port

    def stop(self) -> None:
        self._impl.stop()


@pytest.fixture(params=SERVERS)
def server(request, tmp_path):
    s = Server(request.param, tmp_path)
    try:
        yield s
    finally:
        s.stop()


report = LOG.report_at_module_end('worst times, PLC contract')


class Raw:
    """Modbus TCP by hand: one request, the answer's PDU (None: no answer)."""

    def __init__(self, port: int):
        self.sock = socket.create_connection(('127.0.0.1', port), timeout=2.0)
        self.tid = 0
        # One request out at a time: the heartbeat thread shares this connection (a write is
        # taken only from the connection that holds the write claim).
        self.lock = threading.RLock()

    def ask_adu(self, pdu: bytes, unit: int = UNIT, timeout_s: float = 2.0) -> bytes | None:
        with self.lock:
            return self._ask_adu(pdu, unit, timeout_s)

    def _ask_adu(self, pdu: bytes, unit: int, timeout_s: float) -> bytes | None:
        self.tid = (self.tid + 1) & 0xFFFF
        self.sock.sendall(struct.pack('>HHHB', self.tid, 0, len(pdu) + 1, unit) + pdu)
        self.sock.settimeout(timeout_s)
        try:
            header = self._exactly(7)
        except socket.timeout:
            return None
        length = struct.unpack('>H', header[4:6])[0]
        return header + self._exactly(length - 1)

    def ask(self, pdu: bytes, unit: int = UNIT, timeout_s: float = 2.0) -> bytes | None:
        with self.lock:
            adu = self._ask_adu(pdu, unit, timeout_s)
            if adu is None:
                return None
            tid, protocol, _length, answered_unit = struct.unpack('>HHHB', adu[:7])
            assert (tid, protocol, answered_unit) == (self.tid, 0, unit), adu.hex()
            return adu[7:]

    def _exactly(self, n: int) -> bytes:
        data = b''
        while len(data) < n:
            chunk = self.sock.recv(n - len(data))
            if not chunk:
                raise ConnectionError(f'connection closed after {len(data)} of {n} bytes')
            data += chunk
        return data

    # ---- the requests
    def read(self, start: int, quantity: int, fc: int = 3) -> bytes:
        return self.ask(struct.pack('>BHH', fc, start, quantity))

    def registers(self, start: int, quantity: int, fc: int = 3) -> list[int]:
        answer = self.read(start, quantity, fc)
        assert answer[:2] == bytes([fc, 2 * quantity]), answer.hex()
        return list(struct.unpack(f'>{quantity}H', answer[2:]))

    def write6(self, address: int, value: int) -> bytes:
        return self.ask(struct.pack('>BHH', 6, address, value))

    def write16(self, start: int, values: list[int], quantity: int | None = None,
                byte_count: int | None = None) -> bytes:
        q = len(values) if quantity is None else quantity
        bc = 2 * len(values) if byte_count is None else byte_count
        return self.ask(struct.pack(f'>BHHB{len(values)}H', 16, start, q, bc, *values))

    def command(self, counts: list[int], seq: int) -> bytes:
        """Commands for every channel and a sequence number in one request, as plc_output."""
        return self.write16(0, (counts + [0] * N)[:N] + [seq])

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def raw(server):
    r = Raw(server.port)
    yield r
    r.close()


def exception(fc: int, code: int) -> bytes:
    return bytes([fc | 0x80, code])


def echo16(start: int, quantity: int) -> bytes:
    return struct.pack('>BHH', 16, start, quantity)


class Heartbeat:
    """Changes the heartbeat register every 50 ms on the commanding client's connection
    (plc_output's job)."""

    def __init__(self, raw: 'Raw'):
        self.raw = raw
        self.value = 0
        self._stop = threading.Event()
        self._paused = False
        self._lock = threading.Lock()   # held during each write: pause() waits for one in flight
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        while not self._stop.is_set():
            with self._lock:
                if not self._paused:
                    self.value = (self.value + 1) & 0xFFFF
                    self.raw.write6(HEARTBEAT, self.value)
            self._stop.wait(0.05)

    def pause(self):
        """No heartbeat write after this returns (the watchdog then trips after WATCHDOG_S)."""
        with self._lock:
            self._paused = True

    def stop(self):
        self._stop.set()
        self._thread.join(2)


def arm(raw: Raw, port: int) -> tuple[Heartbeat, int]:
    """A live heartbeat, and the watchdog armed: a probe command (on the last channel, with
    sequence numbers 1, 2, ...) is written until it stays. Returns the heartbeat and the last
    sequence number used; the tests number their writes from there."""
    heartbeat = Heartbeat(raw)
    seqs = iter(range(1, 200))

    def probe():
        seq = next(seqs)
        raw.write16(N - 1, [1, seq])
        return raw.registers(N - 1, 1) == [1] and seq
    try:
        seq = wait_until(probe, 3.0, what='the watchdog armed by a live heartbeat')
        raw.write16(N - 1, [0, seq + 1])
    except BaseException:
        heartbeat.stop()
        raise
    return heartbeat, seq + 1


@pytest.fixture
def armed(server, raw):
    """The last sequence number used while arming; the heartbeat runs for the whole test."""
    heartbeat, seq = arm(raw, server.port)
    raw.heartbeat = heartbeat
    yield seq
    heartbeat.stop()


# ------------------------------------------------------------------------------ answers
def test_in_map_reads_and_writes_answer_normally(server, raw, armed):
    assert raw.command([100, 200, 300], seq=armed + 1) == echo16(0, N + 1)
    assert raw.registers(0, N + 1) == [100, 200, 300] + [0] * (N - 3) + [armed + 1]
    assert len(raw.registers(0, HOLDING)) == HOLDING   # the whole map in one read
    assert len(raw.registers(0, INPUT, fc=4)) == INPUT   # measured pressures, the claim holder


OUT_OF_MAP = {
    'FC3 one past the vent register': (struct.pack('>BHH', 3, HOLDING, 1), 3),
    'FC3 block running past the map': (struct.pack('>BHH', 3, 0, HOLDING + 1), 3),
    'FC3 old heartbeat address 100': (struct.pack('>BHH', 3, 100, 1), 3),
    'FC4 past the claim holder': (struct.pack('>BHH', 4, INPUT, 1), 4),
    'FC6 past the vent register': (struct.pack('>BHH', 6, HOLDING, 1), 6),
    'FC6 old heartbeat address 100': (struct.pack('>BHH', 6, 100, 1), 6),
    'FC16 running past the map': (struct.pack('>BHHB3H', 16, N + 1, 3, 6, 1, 2, 1), 16),
    'FC3 at 65535': (struct.pack('>BHH', 3, 0xFFFF, 2), 3),
}


@pytest.mark.parametrize('case', list(OUT_OF_MAP))
def test_out_of_map_answers_exception_02(server, raw, case):
    pdu, fc = OUT_OF_MAP[case]
    assert raw.ask(pdu) == exception(fc, 2)
    assert raw.registers(0, HOLDING) == [0] * HOLDING   # nothing written


@pytest.mark.parametrize('fc', [1, 2, 5, 15, 23, 43, 100])
def test_unknown_function_answers_exception_01(server, raw, fc):
    assert raw.ask(struct.pack('>BHH', fc, 0, 1)) == exception(fc, 1)


BAD_QUANTITY = {
    'FC3 quantity 0': (struct.pack('>BHH', 3, 0, 0), 3),
    'FC3 quantity 126': (struct.pack('>BHH', 3, 0, 126), 3),
    'FC4 quantity 0': (struct.pack('>BHH', 4, 0, 0), 4),
    'FC4 quantity 126': (struct.pack('>BHH', 4, 0, 126), 4),
    # 124 registers cannot fit in a Modbus frame (PDU <= 253 bytes): the header claims them.
    'FC16 quantity 124': (struct.pack('>BHHB2H', 16, 0, 124, 248, 0, 0), 16),
    'FC16 quantity 0': (struct.pack('>BHHB', 16, 0, 0, 0), 16),
    'FC16 byte count != 2 * quantity': (struct.pack('>BHHB2H', 16, 0, 2, 3, 1, 2), 16),
}


@pytest.mark.parametrize('case', list(BAD_QUANTITY))
def test_bad_quantity_answers_exception_03(server, raw, case):
    pdu, fc = BAD_QUANTITY[case]
    assert raw.ask(pdu) == exception(fc, 3)


def test_exception_frame_bytes(server, raw):
    """MBAP echoed (transaction id, protocol 0, length 3, unit id), function | 0x80, code."""
    adu = raw.ask_adu(struct.pack('>BHH', 3, 100, 1))
    assert adu == struct.pack('>HHHBBB', raw.tid, 0, 3, UNIT, 0x83, 2)


def test_another_unit_id_gets_no_answer_and_the_connection_stays_open(server, raw):
    assert raw.ask(struct.pack('>BHH', 3, 0, 1), unit=UNIT + 1, timeout_s=SILENCE_S) is None
    assert raw.ask(struct.pack('>BHH', 6, 0, 1), unit=UNIT + 1, timeout_s=SILENCE_S) is None
    # The same connection still works for the right unit id (a late answer to the requests
    # above would show up here as a wrong transaction id).
    assert raw.registers(0, 1) == [0]


def test_a_request_split_over_two_segments_is_answered(server, raw):
    """TCP is a byte stream: a request may arrive in pieces."""
    frame = struct.pack('>HHHBBHH', 7, 0, 6, UNIT, 3, 0, 2)
    raw.sock.sendall(frame[:5])
    time.sleep(0.05)   # the first part alone on the wire
    raw.sock.sendall(frame[5:])
    answer = raw._exactly(7 + 6)
    assert answer[:2] == b'\x00\x07' and answer[7:9] == b'\x03\x04', answer.hex()


def test_the_program_answers_two_requests_sent_back_to_back(tmp_path):
    """Not in the contract (plc_output has one request out at a time; pymodbus 3.9.2's server
    answers only the first of two requests in one segment), but the program does."""
    server = Server('program', tmp_path)
    try:
        raw = Raw(server.port)
        raw.sock.sendall(struct.pack('>HHHBBHH', 7, 0, 6, UNIT, 3, 0, 2)
                         + struct.pack('>HHHBBHH', 8, 0, 6, UNIT, 4, 0, 1))
        answers = raw._exactly(7 + 6) + raw._exactly(7 + 4)
        raw.close()
    finally:
        server.stop()
    assert answers[:2] == b'\x00\x07' and answers[7:9] == b'\x03\x04', answers.hex()
    assert answers[13:15] == b'\x00\x08' and answers[20:22] == b'\x04\x02', answers.hex()


# ----------------------------------------------------------------------- sequence gate
def test_stale_write_is_answered_normally_and_undone(server, raw, armed):
    s = armed + 1000
    assert raw.command([500, 600], seq=s) == echo16(0, N + 1)
    assert raw.command([3000, 3000], seq=s - 1) == echo16(0, N + 1)      # older
    assert raw.command([3000, 3000], seq=s) == echo16(0, N + 1)          # the same number again
    assert raw.command([3000, 3000], seq=s + 0x8000) == echo16(0, N + 1)  # half the ring: stale
    assert raw.registers(0, 2) + raw.registers(SEQ, 1) == [500, 600, s]
    assert raw.command([700], seq=s + 0x7FFF) == echo16(0, N + 1)        # farthest still newer
    assert raw.registers(0, 1) == [700]


def test_sequence_numbers_wrap_modulo_65536(server, raw, armed):
    for seq in (armed + 30000, armed + 60000, 65535):   # up the ring in steps under half of it
        raw.command([100], seq=seq)
    raw.command([200], seq=0)
    assert raw.registers(0, 1) + raw.registers(SEQ, 1) == [200, 0]
    raw.command([300], seq=65535)
    assert raw.registers(0, 1) + raw.registers(SEQ, 1) == [200, 0]


def test_unsequenced_command_writes_are_answered_normally_and_undone(server, raw, armed):
    raw.command([500, 600], seq=armed + 10)
    assert raw.write6(1, 3000) == struct.pack('>BHH', 6, 1, 3000)
    assert raw.write16(0, [3000, 3000, 3000]) == echo16(0, 3)
    assert raw.registers(0, 3) + raw.registers(SEQ, 1) == [500, 600, 0, armed + 10]


def test_sequence_register_alone_moves_the_gate_and_heartbeat_is_always_accepted(
        server, raw, armed):
    raw.command([500], seq=armed + 10)
    assert raw.write6(SEQ, armed + 20) == struct.pack('>BHH', 6, SEQ, armed + 20)
    assert raw.registers(0, 1) + raw.registers(SEQ, 1) == [500, armed + 20]
    raw.command([900], seq=armed + 15)    # behind the moved gate
    raw.write6(SEQ, armed + 5)            # stale on its own
    assert raw.registers(0, 1) + raw.registers(SEQ, 1) == [500, armed + 20]
    # A stale command write that also carries the heartbeat: the heartbeat is taken (the
    # heartbeat thread paused, so 4242 can only come from this write).
    raw.heartbeat.pause()
    raw.write16(0, [900] * N + [armed + 3, 4242])
    assert raw.registers(0, 1) + raw.registers(SEQ, 2) == [500, armed + 20, 4242]


def test_first_write_after_power_up_is_accepted_whatever_its_number(server, raw):
    # The sequence register shows it (the commands themselves are zeroed while the watchdog
    # has not been armed yet).
    assert raw.command([123], seq=40000) == echo16(0, N + 1)
    assert raw.registers(SEQ, 1) == [40000]
    raw.command([123], seq=40000 - 1)
    assert raw.registers(SEQ, 1) == [40000]


# ------------------------------------------------------------------ one writer at a time
#: A closed connection of the claim holder -> registers 0: one scan, a read round trip, slack.
CLOSE_VENT_S = 0.01 + 0.3


def test_a_second_client_s_writes_are_refused_with_exception_06(server, raw, armed):
    raw.command([500], seq=armed + 1)
    other = Raw(server.port)
    try:
        assert other.command([3000] * N, seq=armed + 1024) == exception(16, 6)
        assert other.write6(HEARTBEAT, 4242) == exception(6, 6)
        assert other.write6(SEQ, armed + 2000) == exception(6, 6)
        assert other.write16(0, [3000]) == exception(16, 6)
        # Reads are anyone's; the map's addresses are checked first (02 before 06).
        assert other.registers(0, 1) + other.registers(SEQ, 2)[:1] == [500, armed + 1]
        assert other.write6(HOLDING, 1) == exception(6, 2)
    finally:
        other.close()
    assert raw.registers(0, 1) + raw.registers(SEQ, 1) == [500, armed + 1]


def test_a_second_writer_that_dies_never_holds_pressure(server, raw, armed):
    """The two-writer fault: the survivor (raw, first to connect) writes zeros with its own
    heartbeat; a second client numbered 1024 ahead writes 200 kPa with its heartbeat and dies.
    Its writes must never have held the registers, whatever its numbers."""
    raw.command([0] * N, seq=armed + 1)
    second = Raw(server.port)
    answers = [second.command([2000] * N, seq=armed + 1024)]
    for k in range(10):
        answers.append(second.write6(HEARTBEAT, 30000 + k))
    second.close()
    for k in range(2, 30):   # the survivor's zeros go on, with its heartbeat
        raw.command([0] * N, seq=armed + k)
        assert raw.registers(0, N) == [0] * N
        time.sleep(0.02)
    assert answers == [exception(16, 6)] + [exception(6, 6)] * 10


@pytest.mark.parametrize('death', ['closed', 'silent'])
def test_the_claim_holder_s_loss_vents_and_frees_the_claim(server, death):
    """The claim holder commands 200 kPa and dies: its connection closed (a process killed) or
    silent and open (a half-open link). The other client's writes (heartbeat included) are
    refused meanwhile, so they cannot keep the watchdog armed; the registers read 0 within one
    scan of the close, or within the watchdog of the silence, and then the other client claims
    and commands, whatever its sequence number."""
    holder, survivor = Raw(server.port), Raw(server.port)
    heartbeat, seq = arm(holder, server.port)
    try:
        holder.command([2000] * N, seq=seq + 5000)
        assert holder.registers(0, 2) == [2000, 2000]
        heartbeat.pause()
        t0 = time.monotonic()
        if death == 'closed':
            holder.close()
        deadline = CLOSE_VENT_S if death == 'closed' else WATCHDOG_VENT_S
        beat = iter(range(100, 10000))

        def vented():   # the survivor keeps trying: heartbeat and zeros, refused until free
            survivor.write6(HEARTBEAT, next(beat))
            return survivor.registers(0, N) == [0] * N
        wait_until(vented, deadline, what=f'registers 0 after the claim holder {death} ({server.kind})')
        LOG.record(f'claim holder {death} -> registers 0 ({server.kind})', time.monotonic() - t0, deadline)
        # Free (at once when closed, within the watchdog when silent): the survivor claims; its
        # first write is taken though its number is far behind the holder's.
        wait_until(lambda: survivor.command([700], seq=seq + 1) == echo16(0, N + 1)
                   and survivor.registers(SEQ, 1) == [seq + 1], WATCHDOG_VENT_S, what='the claim taken')
        survivor_beat = Heartbeat(survivor)
        try:
            wait_until(lambda: survivor.command([700], seq=seq + 2 + next(beat) % 100) and
                       survivor.registers(0, 1) == [700], 2.0, what='the survivor commanding')
        finally:
            survivor_beat.stop()
        if death == 'silent':   # the silent holder is refused now
            assert holder.write6(HEARTBEAT, 1) == exception(6, 6)
    finally:
        heartbeat.stop()
        holder.close()
        survivor.close()


def test_a_half_sent_request_of_the_claim_holder_closes_its_connection(server):
    """A holder that sends part of a request and then nothing (a link gone mid-frame) is closed
    by the PLC after 1 s, as a dead peer, and the registers read 0."""
    holder, other = Raw(server.port), Raw(server.port)
    heartbeat, seq = arm(holder, server.port)
    try:
        holder.command([2000] * N, seq=seq + 1)
        heartbeat.pause()
        holder.sock.sendall(struct.pack('>HHH', 9, 0, 6)[:5])
        t0 = time.monotonic()
        holder.sock.settimeout(3.0)
        assert holder.sock.recv(1) == b'', 'the PLC kept the connection'
        closed_s = time.monotonic() - t0
        assert other.registers(0, N) == [0] * N
        LOG.record(f'half-sent request -> connection closed, registers 0 ({server.kind})', closed_s, 1.0 + 0.3)
        assert 0.9 <= closed_s <= 1.3, closed_s
    finally:
        heartbeat.stop()
        holder.close()
        other.close()


# --------------------------------------------------------------------- the vent latch
#: A vent request -> registers read 0: at once (the request zeroes them), a read round trip and slack.
VENT_REQUEST_S = 0.01 + 0.3


def hold_commands(raw: Raw, seq: int, counts: list[int], duration_s: float, check) -> int:
    """The holder's ordinary writes (commands numbered on, its heartbeat running) for
    duration_s, `check()` after each; returns the last sequence number used."""
    end = time.monotonic() + duration_s
    while time.monotonic() < end:
        seq += 1
        raw.command(counts, seq=seq)
        check()
        time.sleep(0.02)
    return seq


def test_a_vent_request_from_any_client_vents_until_the_holder_re_arms(server, raw, armed):
    raw.command([2000] * N, seq=armed + 1)
    assert raw.registers(0, 2) == [2000, 2000]
    other = Raw(server.port)
    try:
        t0 = time.monotonic()
        assert other.write6(VENT, 1) == struct.pack('>BHH', 6, VENT, 1)   # no claim needed
        wait_until(lambda: other.registers(0, N) == [0] * N, VENT_REQUEST_S,
                   what=f'registers 0 after another client\'s vent request ({server.kind})')
        LOG.record(f'vent request from a second client -> registers 0 ({server.kind})',
                   time.monotonic() - t0, VENT_REQUEST_S)
        assert other.registers(VENT, 1) == [1]

        def still_vented():
            assert other.registers(0, N) == [0] * N and raw.registers(VENT, 1) == [1]
        # The holder's commands and heartbeat go on: they do not lift it.
        seq = hold_commands(raw, armed + 1, [2000] * N, 1.0, still_vented)
        # Only the holder re-arms; 0 or any other value is no re-arm.
        assert other.write6(VENT, 2) == exception(6, 6)
        assert other.write6(VENT, 0) == exception(6, 3)
        assert raw.write6(VENT, 0) == exception(6, 3)
        assert raw.write16(SEQ, [seq + 1, 77, 1234]) == exception(16, 3)
        still_vented()
        # The re-arm starts nothing: the commands stay 0 until the holder's next command.
        assert raw.write6(VENT, 2) == struct.pack('>BHH', 6, VENT, 2)
        assert raw.registers(VENT, 1) == [0]
        assert other.registers(0, N) == [0] * N
        raw.command([700], seq=seq + 1)
        assert raw.registers(0, 1) == [700]
    finally:
        other.close()


def test_a_vent_request_takes_no_claim_and_outlives_the_holder(server):
    requester, holder = Raw(server.port), Raw(server.port)
    try:
        assert requester.write6(VENT, 1) == struct.pack('>BHH', 6, VENT, 1)
        heartbeat = Heartbeat(holder)   # the claim was free: the holder takes it
        try:
            seq = hold_commands(holder, 100, [2000], 0.8,
                                lambda: holder.registers(0, 1) == [0] or pytest.fail('not vented'))
            assert requester.write6(HEARTBEAT, 5) == exception(6, 6)   # holder's claim
        finally:
            heartbeat.stop()
        holder.close()
        assert requester.registers(VENT, 1) == [1]   # a new holder must re-arm explicitly
        assert seq > 100
    finally:
        requester.close()
        holder.close()


def test_any_client_reads_the_claim_holder_s_address(server, raw, armed):
    other = Raw(server.port)
    try:
        port = raw.sock.getsockname()[1]
        assert other.registers(N, 3, fc=4) == [0x7F00, 0x0001, port]
        raw.heartbeat.stop()
        raw.close()
        wait_until(lambda: other.registers(N, 3, fc=4) == [0, 0, 0], CLOSE_VENT_S,
                   what='the claim holder\'s address cleared after its close')
    finally:
        other.close()


def test_mbpoll_vents_a_foreign_writer_that_holds_the_claim(server, raw, armed):
    """A tool (mbpoll, a foot switch on Modbus) stops the suit although another client holds
    the PLC at 200 kPa with a live heartbeat."""
    need_tools('mbpoll')
    raw.command([2000] * N, seq=armed + 1)
    t0 = time.monotonic()
    out = mbpoll(server.port, '-a', str(UNIT), '-t', '4', '-r', str(VENT), values=('1',))
    assert out.startswith('exit 0'), out
    wait_until(lambda: raw.registers(0, N) == [0] * N, VENT_REQUEST_S, what='vented by mbpoll')
    LOG.record(f'mbpoll vent request -> registers 0 ({server.kind})', time.monotonic() - t0,
               VENT_REQUEST_S + 1.0)
    hold_commands(raw, armed + 1, [2000] * N, 0.5,
                  lambda: raw.registers(0, N) == [0] * N or pytest.fail('the writer lifted it'))


# ------------------------------------------------------------------------------- clamp
def test_over_limit_values_are_stored_clamped(server, raw, armed):
    assert raw.command([P_MAX + 1, 0xFFFF, P_MAX], seq=armed + 1) == echo16(0, N + 1)
    assert raw.registers(0, 3) == [P_MAX, P_MAX, P_MAX]


# ---------------------------------------------------------------------------- watchdog
def test_watchdog_starts_vented(server, raw):
    """Commands written before any heartbeat change never stay: the registers are zeroed."""
    raw.command([1000, 1000], seq=1)
    raw.write6(HEARTBEAT, 0)   # written, but not changed: no proof of a live client
    wait_until(lambda: raw.registers(0, N) == [0] * N, 1.0, what='commands zeroed while vented')
    # A second write is zeroed too: the zeroing is not a one-off at power-up.
    raw.command([1000, 1000], seq=2)
    wait_until(lambda: raw.registers(0, 2) == [0, 0], 1.0, what='second write zeroed while vented')


def test_watchdog_holds_while_the_heartbeat_changes_and_trips_when_it_stops(server, raw):
    heartbeat, seq = arm(raw, server.port)
    try:
        raw.command([1000, 2000], seq=seq + 1)
        t_end = time.monotonic() + 2 * WATCHDOG_S
        while time.monotonic() < t_end:   # longer than the watchdog: the heartbeat keeps it armed
            assert raw.registers(0, 2) == [1000, 2000]
            time.sleep(0.05)
    finally:
        heartbeat.stop()
    t0 = time.monotonic()
    wait_until(lambda: raw.registers(0, N) == [0] * N, WATCHDOG_VENT_S,
               what=f'registers zeroed by the watchdog ({server.kind})')
    LOG.record(f'heartbeat stopped -> registers 0 ({server.kind})', time.monotonic() - t0,
               WATCHDOG_VENT_S)


# --------------------------------------------------------------------------- mbpoll
def mbpoll(port: int, *options: str, values: tuple[str, ...] = ()) -> str:
    """mbpoll's answer, without the banner and the port line (which differ per server)."""
    out = subprocess.run(['mbpoll', '-m', 'tcp', '-0', '-1', '-o', '1', '-p', str(port), *options,
                          '127.0.0.1', *values], capture_output=True, text=True, timeout=20)
    text = out.stdout + out.stderr
    body = text.split('Data type', 1)[-1]
    body = re.sub(r'127\.0\.0\.1, port \d+', 'PORT', body)
    return f'exit {out.returncode}\n' + '\n'.join(line.rstrip() for line in body.splitlines()[1:]
                                                  if line.strip())


def mbpoll_session(port: int) -> dict[str, str]:
    """In-map, out-of-map and stale requests from mbpoll, after a known command (raw), with a
    live heartbeat (else the watchdog zeroes the commands). Not the input registers: the two
    servers simulate the regulators differently."""
    raw = Raw(port)
    heartbeat, _seq = arm(raw, port)
    try:
        raw.command([1111, 2222], seq=1000)
        assert raw.registers(0, 2) + raw.registers(SEQ, 1) == [1111, 2222, 1000]
        values = tuple(str(v) for v in [3333] * N + [999])  # a whole command write, older number
        unit = ('-a', str(UNIT))
        return {
            'in-map read': mbpoll(port, *unit, '-t', '4', '-r', '0', '-c', str(N + 1)),
            'out-of-map read': mbpoll(port, *unit, '-t', '4', '-r', str(HOLDING), '-c', '1'),
            'out-of-map write': mbpoll(port, *unit, '-t', '4', '-r', '100', values=('5',)),
            'unknown function (coils)': mbpoll(port, *unit, '-t', '0', '-r', '0', '-c', '1'),
            # raw holds the write claim: a second client's write is refused, whatever its number.
            'write from a second client': mbpoll(port, *unit, '-t', '4', '-r', '0', values=values),
            'read after the refused write': mbpoll(port, *unit, '-t', '4', '-r', '0', '-c', '2'),
        }
    finally:
        heartbeat.stop()
        raw.close()


EXPECTED_MBPOLL = {
    'in-map read': rf'^exit 0\n.*\[0\]:\s+1111\n\[1\]:\s+2222\n.*\[{N}\]:\s+1000$',
    'out-of-map read': r'^exit 1\n.*Illegal data address',
    'out-of-map write': r'^exit 1\n.*Illegal data address',
    'unknown function (coils)': r'^exit 1\n.*Illegal function',
    'write from a second client': r'^exit 1\n.*busy',
    'read after the refused write': r'^exit 0\n.*\[0\]:\s+1111\n\[1\]:\s+2222',
}


def test_mbpoll_gets_the_contract_answers(server):
    need_tools('mbpoll')
    session = mbpoll_session(server.port)
    for probe, pattern in EXPECTED_MBPOLL.items():
        assert re.search(pattern, session[probe], re.S), f'{probe}:\n{session[probe]}'


def test_mbpoll_gets_the_same_answers_from_the_mock_and_the_program(tmp_path):
    need_tools('mbpoll')
    sessions = {}
    for kind in ('program', 'mock'):
        s = Server(kind, tmp_path)
        try:
            sessions[kind] = mbpoll_session(s.port)
        finally:
            s.stop()
    for probe in sessions['program']:
        assert sessions['mock'][probe] == sessions['program'][probe], probe
