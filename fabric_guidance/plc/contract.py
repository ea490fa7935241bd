"""The PLC contract's registers and what the PLC program does with one request (docs/plc.md),
without sockets: the mock PLC (mock_server.py) serves it over Modbus TCP, the chaos tests drive
it directly. Kept apart from the server so each file stays one job.
"""
from __future__ import annotations

import socket
import struct
import threading
import time

from .register_map import CLAIM_HOLDER_REGISTERS, REARM, VENT_REQUEST, RegisterMap
from .sequence import SequenceGate

#: Quantity limits of the Modbus specification: read 1..125 registers, write 1..123.
MAX_READ, MAX_WRITE = 125, 123
#: The exception a write from a connection without the write claim gets (SERVER DEVICE BUSY).
BUSY = 6
#: A connection's address as the server saw it (IPv4 dotted, port); ('', 0) unknown.
Peer = tuple[str, int]


class _Registers:
    """The PLC's registers and what the PLC program does with a request (the contract).

    Only the map's registers exist: holding = the command registers, the sequence register, the
    heartbeat register and the vent register; input = the measured registers and the claim
    holder's address (with the contract's layout, the arrays 0..N+2 and 0..N+2). Thread-safe
    through ``lock``; no sockets here.
    """

    def __init__(self, register_map: RegisterMap, lock: threading.RLock):
        m = register_map
        self._map, self.lock = m, lock
        self.commands = tuple(m.command_registers)
        self.vent = m.vent_register
        self.holding_addresses = frozenset(self.commands) | {m.heartbeat_register} | {
            a for a in (m.sequence_register, m.vent_register) if a is not None}
        self.input_addresses = frozenset(m.measured_registers)
        #: The claim holder's address registers (input), computed when read.
        self.holder_addresses = () if m.claim_holder_register is None else tuple(
            range(m.claim_holder_register, m.claim_holder_register + CLAIM_HOLDER_REGISTERS))
        # The gate works on the request that carries commands and number together; a map
        # without that block has no sequencing (its client writes the commands alone).
        self.sequence = m.sequence_register if m.sequenced_block() is not None else None
        self._channel_of = {c.command_register: c.name for c in m.channels}
        self.holding: dict[int, int] = {}
        self.input: dict[int, int] = {}
        self.gate = SequenceGate()
        self.max_written_counts: dict[str, int] = {}
        self.out_of_map_writes: list[tuple[int, int]] = []
        self.over_limit_writes: list[tuple[int, int]] = []
        #: (sequence number or None when the request had none, last applied) of undone writes
        self.stale_writes: list[tuple[int | None, int | None]] = []
        self.writes = 0    # client write requests that reached the registers
        #: The connection holding the write claim (None: free), whether its time is still to be
        #: taken at the next scan, writes refused with exception 06, claims lost to a close.
        self.owner: int | None = None
        self.owner_peer: Peer = ('', 0)
        self.claim_pending = False
        #: The vent latch (vent register): set by any connection, released by the holder only.
        self.latched = False
        self.vent_requests = self.rearms = 0
        self.busy = 0
        self.owner_lost = 0
        self.version = 0   # bumped on every change of the records
        #: (time.monotonic_ns(), first address, values) per client write, when timing is on
        #: (the benchmarks' landing times); None: off, nothing is recorded.
        self.write_times: list[tuple[int, int, tuple[int, ...]]] | None = None
        #: (time.monotonic_ns(), cause, command counts as applied, largest command count sent)
        #: whenever the applied commands change or a write sends more than p_max, when the
        #: register log is on (the chaos run's invariants); None: off.
        self.register_log: list[tuple[int, str, tuple[int, ...], int]] | None = None
        self._logged_state: tuple[int, ...] | None = None
        self.power_up()

    def power_up(self) -> None:
        """All registers 0, the gate without a reference; the records are kept."""
        with self.lock:
            self.holding = dict.fromkeys(self.holding_addresses, 0)
            self.input = dict.fromkeys(self.input_addresses, 0)
            self.input.update(dict.fromkeys(self.holder_addresses, 0))
            self.gate.reset()
            self.owner, self.owner_peer, self.claim_pending = None, ('', 0), False
            # A power cycle releases the latch, as the program's (not kept in EEPROM).
            self.latched = False
            self.log_state('power_up')

    def log_state(self, cause: str, sent_max: int = 0) -> None:
        """One register log entry if the applied commands changed or sent_max is above p_max
        (called with the lock held)."""
        if self.register_log is None:
            return
        state = tuple(self.holding[a] for a in self.commands)
        if state == self._logged_state and sent_max <= self._map.p_max_counts:
            return
        self._logged_state = state
        self.register_log.append((time.monotonic_ns(), cause, state, sent_max))

    # ---- one request (PDU in, PDU out; None: no answer)
    def handle(self, pdu: bytes, connection: int = 0, peer: Peer = ('', 0)) -> bytes:
        """The answer to one request from `connection` (numbered by the server, never reused),
        whose address is `peer` (shown in the claim holder's input registers while it holds it)."""
        fc = pdu[0]
        try:
            if fc in (3, 4):
                if len(pdu) != 5:
                    return _exception(fc, 3)
                start, quantity = struct.unpack('>HH', pdu[1:5])
                if not 1 <= quantity <= MAX_READ:
                    return _exception(fc, 3)
                table = self.holding if fc == 3 else self.input
                with self.lock:
                    if fc == 4:
                        self._holder_into_inputs()
                    if not self._mapped(table, start, quantity):
                        return _exception(fc, 2)
                    values = [table[a] for a in range(start, start + quantity)]
                return struct.pack(f'>BB{quantity}H', fc, 2 * quantity, *values)
            if fc == 6:
                if len(pdu) != 5:
                    return _exception(fc, 3)
                address, value = struct.unpack('>HH', pdu[1:5])
                if not self._mapped(self.holding, address, 1):
                    self._record_out_of_map(address, [value])
                    return _exception(fc, 2)
                refused = self._vent_check(address, [value])
                if refused:
                    return _exception(fc, refused)
                if not self._vent_only(address, [value]) and not self._may_write(connection, peer):
                    return _exception(fc, BUSY)
                self.write(address, [value])
                return pdu[:5]
            if fc == 16:
                if len(pdu) < 6:
                    return _exception(fc, 3)
                start, quantity, byte_count = struct.unpack('>HHB', pdu[1:6])
                if (not 1 <= quantity <= MAX_WRITE or byte_count != 2 * quantity
                        or len(pdu) != 6 + byte_count):
                    return _exception(fc, 3)
                values = list(struct.unpack(f'>{quantity}H', pdu[6:]))
                if not self._mapped(self.holding, start, quantity):
                    self._record_out_of_map(start, values)
                    return _exception(fc, 2)
                refused = self._vent_check(start, values)
                if refused:
                    return _exception(fc, refused)
                if not self._vent_only(start, values) and not self._may_write(connection, peer):
                    return _exception(fc, BUSY)
                self.write(start, values)
                return pdu[:5]
        except struct.error:
            return _exception(fc, 3)
        return _exception(fc, 1)

    def _vent_check(self, start: int, values: list[int]) -> int:
        """0 when a write's value for the vent register (if it covers it) is VENT_REQUEST or REARM,
        else exception 03 (ILLEGAL DATA VALUE)."""
        if self.vent is None or not start <= self.vent < start + len(values):
            return 0
        return 0 if values[self.vent - start] in (VENT_REQUEST, REARM) else 3

    def _vent_only(self, start: int, values: list[int]) -> bool:
        """A vent request alone: anyone's, whatever the write claim (it takes none), so a stop
        reaches the suit from every connection. A re-arm is the claim holder's only."""
        return start == self.vent and values == [VENT_REQUEST]

    def _holder_into_inputs(self) -> None:
        """The claim holder's IPv4 address (high, low 16 bits) and port into its input registers
        (all 0 while the claim is free or the address is not IPv4); lock held."""
        if not self.holder_addresses:
            return
        ip, port = self.owner_peer if self.owner is not None else ('', 0)
        try:
            packed = struct.unpack('>HH', socket.inet_aton(ip)) if ip else (0, 0)
        except OSError:
            packed, port = (0, 0), 0
        for a, v in zip(self.holder_addresses, (*packed, port)):
            self.input[a] = v

    def _may_write(self, connection: int, peer: Peer = ('', 0)) -> bool:
        """False when another connection holds the write claim (the whole request refused,
        heartbeat included: another client's heartbeat must never keep the watchdog armed for
        commands it did not write); a free claim is taken by `connection`."""
        with self.lock:
            if self.owner is not None and self.owner != connection:
                self.busy += 1
                self.version += 1
                return False
            if self.owner is None:
                self.owner, self.owner_peer, self.claim_pending = connection, peer, True
                # A new writer's numbers have no relation to the last one's: its first is taken,
                # as after power-up (an earlier connection's late writes are refused above).
                self.gate.reset()
            return True

    def connection_closed(self, connection: int) -> bool:
        """The server closed `connection`; True when it held the write claim (now free, the
        command registers zeroed: the caller vents the outputs)."""
        with self.lock:
            if self.owner is None or self.owner != connection:
                return False
            self.owner, self.owner_peer, self.claim_pending = None, ('', 0), False
            self.owner_lost += 1
            self.version += 1
            for a in self.commands:
                self.holding[a] = 0
            self.log_state('owner closed')
            return True

    @staticmethod
    def _mapped(table: dict, start: int, quantity: int) -> bool:
        return all(a in table for a in range(start, start + quantity))

    def _record_out_of_map(self, start: int, values: list[int]) -> None:
        # Refused with exception 02 and never stored, but recorded: the package must not try.
        with self.lock:
            self.out_of_map_writes.extend((a, v) for a, v in enumerate(values, start)
                                          if a not in self.holding)
            self.version += 1

    def write(self, start: int, values: list[int]) -> None:
        """A client write to mapped holding registers, as the PLC program applies it."""
        m = self._map
        with self.lock:
            self.writes += 1
            self.version += 1
            landed_ns = time.monotonic_ns()
            # The vent register first: a request that re-arms and commands applies its commands.
            if self.vent is not None and start <= self.vent < start + len(values):
                if values[self.vent - start] == VENT_REQUEST:
                    self.latched, self.vent_requests = True, self.vent_requests + 1
                else:
                    self.latched, self.rearms = False, self.rearms + 1
                values = list(values)
                values[self.vent - start] = int(self.latched)   # it reads 1 while latched
            if self.latched:   # at once, and at every scan while latched
                for a in self.commands:
                    self.holding[a] = 0
            before = dict(self.holding)
            sent_max = max((v for a, v in enumerate(values, start) if a in self._channel_of), default=0)
            for a, v in enumerate(values, start):
                name = self._channel_of.get(a)
                if name is not None:
                    # Recorded as sent (before the clamp and the gate): the records are about
                    # what the package wrote.
                    self.max_written_counts[name] = max(v, self.max_written_counts.get(name, 0))
                    if v > m.p_max_counts:
                        self.over_limit_writes.append((a, v))
                    v = min(v, m.p_max_counts)   # stored clamped: never reaches an output
                    if self.latched:
                        v = 0   # latched: the gate moves, a command is stored as 0
                self.holding[a] = v
            if self._undo_unless_sequenced(before, start, values):
                self.log_state('stale write undone', sent_max)
                return
            self.log_state('write', sent_max)
            if self.write_times is not None:
                # CLOCK_MONOTONIC is system-wide: comparable with a sender's stamps in another
                # process. Taken under the lock, so a take_write_times() never misses one.
                self.write_times.append((landed_ns, start, tuple(values)))

    def _undo_unless_sequenced(self, before: dict[int, int], start: int,
                               values: list[int]) -> bool:
        """The sequence gate on a write just stored; True when it was undone."""
        seq = self.sequence
        if seq is None:
            return False
        commands_changed = any(self.holding[a] != before[a] for a in self.commands)
        seq_changed = self.holding[seq] != before[seq]
        if not (commands_changed or seq_changed):
            return False
        last = self.gate.last
        if seq_changed and self.gate.accept(self.holding[seq]):
            return False
        # Not newer, or no number at all: answered normally but undone (the library the PLC
        # program runs on writes first and offers no hook; the program restores).
        for a in self.commands + (seq,):
            self.holding[a] = before[a]
        written_seq = values[seq - start] if start <= seq < start + len(values) else None
        self.stale_writes.append((written_seq, last))
        return True

    def force_commands_zero(self, cause: str = 'watchdog') -> None:
        """The watchdog's (or the vent latch's) vent: done by the PLC itself, not a client write
        (not recorded)."""
        with self.lock:
            for a in self.commands:
                self.holding[a] = 0
            self.log_state(cause)


def _exception(fc: int, code: int) -> bytes:
    """An exception response PDU: the function code with its high bit set, then the code."""
    return bytes([(fc | 0x80) & 0xFF, code])
