"""Modbus TCP to the PLC: the client the package drives the suit with (the mock PLC it is tested
against is in mock_server.py).

- :class:`PlcClient` writes only registers of the map, always through
  :meth:`RegisterMap.encode` (clamp to [0, p_max], non-finite -> vent), numbers every command
  write when the map has a sequence register (sequence.py), and turns every failure into a
  :class:`PlcLinkError` whose ``state`` says what kind: the link is down, the PLC refused
  (an exception response: :class:`PlcRefusedError`, naming the register), or nothing answered
  for this unit id on an open connection (:class:`PlcNoAnswerError`).
pymodbus is used through pymodbus_compat.py (the one module that knows
the differences between the supported pymodbus versions).
"""
from __future__ import annotations

import time
from typing import Sequence

import numpy as np

from . import pymodbus_compat as compat
from .register_map import CLAIM_HOLDER_REGISTERS, REARM, REGISTER_MAX, VENT_REQUEST, RegisterMap
from .sequence import SEQ_MODULUS, resync

#: The states of a link that is not up, as PlcLinkError.state and plc_output's /diagnostics say.
DOWN, REFUSED, NO_ANSWER = 'down', 'refused', 'no answer'

#: Modbus exception codes and what each means for this package.
EXCEPTION_NAMES = {1: 'ILLEGAL FUNCTION', 2: 'ILLEGAL DATA ADDRESS', 3: 'ILLEGAL DATA VALUE',
                   4: 'SERVER DEVICE FAILURE', 6: 'SERVER DEVICE BUSY'}
_TABLE = {'read_holding_registers': 'holding', 'write_register': 'holding',
          'write_registers': 'holding', 'read_input_registers': 'input'}


class PlcLinkError(RuntimeError):
    """The PLC could not be reached, did not answer, or answered with an error.

    ``state``: DOWN (no connection, or it broke), REFUSED (the PLC answered with a Modbus
    exception) or NO_ANSWER (silence on an open connection: typically a wrong unit id).
    """
    state = DOWN


class PlcRefusedError(PlcLinkError):
    """The PLC answered with a Modbus exception: the link works, the request does not."""
    state = REFUSED

    def __init__(self, message: str, code: int):
        super().__init__(message)
        self.code = code


class PlcNoAnswerError(PlcLinkError):
    """No answer within the timeout although the connection stayed open."""
    state = NO_ANSWER


# --------------------------------------------------------------------------- client
class PlcClient:
    """Synchronous Modbus TCP client for one pressure PLC (one endpoint of the register map).

    pymodbus reconnects on the next request by itself, so after a PlcLinkError the caller
    just keeps calling; ``connect()`` is only needed to find out early whether the PLC is there.
    """

    def __init__(self, register_map: RegisterMap, host: str, port: int = 502, timeout_s: float = 0.5):
        if not timeout_s > 0:
            raise ValueError(f'timeout_s must be > 0, got {timeout_s!r}')
        self.map = register_map
        self.host, self.port, self.timeout_s = host, port, timeout_s
        self._client = compat.make_client(host, port, timeout_s)
        # The map is frozen: its blocks are worked out once, not on every command write.
        self._sequenced, self._block = register_map.sequenced_block(), register_map.command_block()
        self._seq: int | None = None  # last sequence number sent (kept across reconnects)
        self._synced = False          # the PLC's last applied number read on this connection
        self._answered = False        # the PLC has answered this unit id at least once

    @property
    def address(self) -> str:
        return f'{self.host}:{self.port}'

    def connect(self) -> bool:
        """Open the TCP connection; False if the PLC is not reachable."""
        return bool(self._client.connect())

    def close(self) -> None:
        self._synced = False
        self._client.close()

    @property
    def connected(self) -> bool:
        """True while a TCP connection is open (a dead peer is only noticed at the next request)."""
        return bool(self._client.connected)

    def __enter__(self) -> 'PlcClient':
        self.connect()
        return self

    def __exit__(self, *_exc) -> None:
        self.close()

    # ---- writes: only ever to the command registers and the heartbeat register
    def write_pressures(self, pressures_kpa: Sequence[float]) -> float:
        """Write one command vector (kPa, channel order); returns the round-trip time in seconds.

        Clamping and NaN handling happen in ``RegisterMap.encode``. With contiguous command
        registers all channels go in one request, so the PLC never sees half an update;
        otherwise each register is written on its own (a failure may then leave a partial
        update, which the caller must treat like any link failure: vent / retry).
        """
        counts = self.map.encode(pressures_kpa)  # ValueError on a wrong length, before any I/O
        t0 = time.perf_counter()
        self._write_commands(counts)
        return time.perf_counter() - t0

    def vent(self) -> float:
        """Command 0 kPa on every channel; returns the round-trip time in seconds."""
        return self.write_pressures([0.0] * len(self.map))

    def write_heartbeat(self, value: int) -> None:
        """Write the heartbeat counter (taken mod 65536, so a plain ever-growing counter works)."""
        self._call('write heartbeat', 'write_register', self.map.heartbeat_register,
                   int(value) & REGISTER_MAX)

    # ---- the vent latch (register_map.VENT_REQUEST / REARM; docs/plc.md "Vent request")
    def request_vent(self) -> None:
        """Write the vent request: taken from any client, write claim or not; the PLC vents at
        once and stays vented until the claim's holder re-arms."""
        self._call('write vent request', 'write_register', self._vent_register(), VENT_REQUEST)

    def rearm(self) -> None:
        """Release the vent latch (the claim's holder only; others get exception 06). Starts
        nothing: the commands stay 0 until the next command write."""
        self._call('write re-arm', 'write_register', self._vent_register(), REARM)

    def read_vent_latched(self) -> bool:
        """True while the PLC's vent latch holds."""
        return bool(self._call('read vent register', 'read_holding_registers', self._vent_register(),
                               count=1).registers[0])

    def read_claim_holder(self) -> str:
        """'address:port' of the client holding the PLC's write claim; '' while it is free or when
        the map has no claim_holder_register."""
        first = self.map.claim_holder_register
        if first is None:
            return ''
        hi, lo, port = self._call('read claim holder', 'read_input_registers', first,
                                  count=CLAIM_HOLDER_REGISTERS).registers
        if not (hi or lo or port):
            return ''
        return f'{hi >> 8}.{hi & 0xFF}.{lo >> 8}.{lo & 0xFF}:{port}'

    def _vent_register(self) -> int:
        if self.map.vent_register is None:
            raise ValueError(f'{self.map.source}: no vent_register: this PLC has no vent latch')
        return self.map.vent_register

    def write_counts(self, counts: Sequence[int]) -> None:
        """Raw register counts to the command registers, as they are (no clamp, no scaling):
        the benchmarks' bare Modbus hop. The package's commands go through write_pressures."""
        if len(counts) != len(self.map):
            raise ValueError(f'need {len(self.map)} counts, got {len(counts)}')
        self._write_commands(list(counts))

    def _write_commands(self, counts: list[int]) -> None:
        sequenced = self._sequenced
        if sequenced is not None:
            if not self._synced:
                # A fresh connection: start ahead of whatever may still be in flight.
                last = self._call('read sequence', 'read_holding_registers', self.map.sequence_register,
                                  count=1).registers[0]
                self._seq = resync(self._seq, last)
                self._synced = True
            # Used up even if the write fails: it may still arrive, and must then be the older one.
            self._seq = (self._seq + 1) % SEQ_MODULUS
            self._call('write pressures', 'write_registers', sequenced[0], counts + [self._seq])
            return
        block = self._block
        if block is not None:
            self._call('write pressures', 'write_registers', block[0], counts)
            return
        for address, count in zip(self.map.command_registers, counts):
            self._call('write pressure', 'write_register', address, count)

    # ---- reads
    def read_measured_kpa(self) -> np.ndarray:
        """Measured pressures (kPa, channel order) from the input registers."""
        counts = self._read('read_input_registers', self.map.measured_registers, self.map.measured_block())
        return self.map.decode(counts)

    def read_commands_kpa(self) -> np.ndarray:
        """Command registers read back (kPa, channel order); for tests and diagnostics."""
        counts = self._read('read_holding_registers', self.map.command_registers, self.map.command_block())
        return self.map.decode(counts)

    def _read(self, method: str, addresses: Sequence[int], block: tuple[int, int] | None) -> list[int]:
        if block is not None:
            return self._call(method, method, block[0], count=block[1]).registers
        # Not contiguous: one register per request, so nothing outside the map is touched.
        return [self._call(method, method, a, count=1).registers[0] for a in addresses]

    def _call(self, what: str, method: str, *args, count: int | None = None):
        """Run one pymodbus request; every way it can fail becomes a PlcLinkError that says why."""
        where = f'PLC {self.address} (unit id {self.map.unit_id})'
        # Connect here rather than inside the request, so that a timeout below is known to be
        # silence on an open connection (pymodbus 3.6 closes the socket on a timeout itself).
        if not compat.is_open(self._client) and not self._client.connect():
            self.close()
            raise PlcLinkError(f'{what} to {where} failed: cannot connect')
        t0 = time.monotonic()
        try:
            response = compat.request(self._client, method, *args, unit_id=self.map.unit_id,
                                      count=count)
        except Exception as exc:  # noqa: BLE001
            # Broad on purpose: besides ModbusException and OSError, pymodbus can let decoding
            # errors through on a garbled frame; the control loop must see one error type.
            raise self._failed(what, where, str(exc), t0) from exc
        if response is None:
            raise self._failed(what, where, 'no response', t0)
        if response.isError():
            code = compat.exception_code(response)
            if code is not None:
                self._answered = True
            if code is None:  # pymodbus 3.6 returns a timeout instead of raising it
                raise self._failed(what, where, f'error response {response}', t0)
            explained = self._explain(code, method, args, count)
            raise PlcRefusedError(f'{what} to {where} refused: {explained}', code)
        self._answered = True
        if count is not None and len(getattr(response, 'registers', ())) != count:
            self.close()
            raise PlcLinkError(f'{what} to {where}: asked for {count} registers, '
                               f'got {len(getattr(response, "registers", ()))}')
        return response

    def _failed(self, what: str, where: str, detail: str, t0: float) -> PlcLinkError:
        """The error for a request that got no valid answer; drops the connection."""
        # Silence for the whole timeout on an open connection from a PLC that never answered
        # this client: it is there but ignores this unit id (a wrong unit_id). Once it has
        # answered, the unit id is right and a timeout is a link fault.
        silent = not self._answered and time.monotonic() - t0 >= 0.9 * self.timeout_s
        # Drop the socket: a late answer to this request must not be taken as the answer
        # to the next one (the sync client does not match transaction ids).
        self.close()
        if silent:
            return PlcNoAnswerError(
                f'{what}: no answer from unit id {self.map.unit_id} at PLC {self.address} within '
                f'{self.timeout_s:g} s on an open connection: check unit_id in {self.map.source} '
                f'(a PLC stays silent for a unit id that is not its own)')
        return PlcLinkError(f'{what} to {where} failed: {detail}')

    def _explain(self, code: int, method: str, args: tuple, count: int | None) -> str:
        """One line on a Modbus exception: which registers, and what must be wrong."""
        name = EXCEPTION_NAMES.get(code, 'unknown exception')
        table = _TABLE.get(method, '?')
        first = int(args[0]) if args else 0
        n = count if count is not None else (len(args[1]) if method == 'write_registers' else 1)
        span = f'{first}' if n == 1 else f'{first}..{first + n - 1}'
        if code == 2:
            plural = 's' if n > 1 else ''
            return (f'exception 02 {name} for {table} register{plural} {span}: the PLC has no '
                    f'such register, so the register map ({self.map.source}) or the PLC program '
                    f'is wrong (they must agree: docs/plc.md)')
        if code == 1:
            return (f'exception 01 {name} ({method}): the PLC program does not implement this '
                    f'Modbus function; it must answer function codes 3, 4, 6 and 16')
        if code == 6:
            return (f'exception 06 {name} for {table} registers {span}: another Modbus client '
                    f'holds this PLC\'s write claim (a second plc_output, a tool writing to it, or '
                    f'this client\'s own earlier connection the PLC has not yet seen close); one '
                    f'writer at a time. The claim is freed when that connection closes or its '
                    f'heartbeat stops for the watchdog time (docs/plc.md)')
        if code == 3:
            return (f'exception 03 {name} for {table} registers {span}: the PLC program refuses '
                    f'this quantity or value')
        return f'exception {code:02d} {name} for {table} registers {span}'
