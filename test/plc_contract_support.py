"""The servers, the hand-made Modbus TCP client, the heartbeat and the fixtures that the PLC
contract suite's two files share (test_plc_contract.py: the answers on the wire, the sequence gate,
mbpoll's answers; test_plc_safety.py: the write claim, the vent latch, the clamp, the watchdog)."""
from __future__ import annotations

import re
import socket
import struct
import subprocess
import threading

import pytest

from fabric_guidance.plc import MockPlcServer, RegisterMap
from plc_program import PlcProgram
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


# The fixtures are imported by name into the test modules: each function's own name differs from
# the fixture's (name=), so a test's argument does not shadow the import.
@pytest.fixture(params=SERVERS, name='server')
def server_fixture(request, tmp_path):
    s = Server(request.param, tmp_path)
    try:
        yield s
    finally:
        s.stop()


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


@pytest.fixture(name='raw')
def raw_fixture(server):
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


@pytest.fixture(name='armed')
def armed_fixture(server, raw):
    """The last sequence number used while arming; the heartbeat runs for the whole test."""
    heartbeat, seq = arm(raw, server.port)
    raw.heartbeat = heartbeat
    yield seq
    heartbeat.stop()


def mbpoll(port: int, *options: str, values: tuple[str, ...] = ()) -> str:
    """mbpoll's answer, without the banner and the port line (which differ per server)."""
    out = subprocess.run(['mbpoll', '-m', 'tcp', '-0', '-1', '-o', '1', '-p', str(port), *options,
                          '127.0.0.1', *values], capture_output=True, text=True, timeout=20)
    text = out.stdout + out.stderr
    body = text.split('Data type', 1)[-1]
    body = re.sub(r'127\.0\.0\.1, port \d+', 'PORT', body)
    return f'exit {out.returncode}\n' + '\n'.join(line.rstrip() for line in body.splitlines()[1:]
                                                  if line.strip())
