"""Modbus TCP to the PLC: the client the package drives the suit with, and a mock PLC for tests.

This is the only module of the package that imports pymodbus (pinned to 3.9.2: classic
datastore API, ``slave=`` keyword). Everything else talks kPa and a :class:`RegisterMap`.

- :class:`PlcClient` writes only registers of the map, always through
  :meth:`RegisterMap.encode` (clamp to [0, p_max], non-finite -> vent), numbers every command
  write when the map has a sequence register (sequence.py), and turns every failure into
  :class:`PlcLinkError`.
- :class:`MockPlcServer` is a pymodbus TCP server in a background thread that behaves like the
  PLC (regulator lag, heartbeat watchdog, write sequence gate; see regulator.py, sequence.py)
  and records every write it gets, optionally to a file (records.py), so tests can assert
  what left the package.
"""
from __future__ import annotations

import asyncio
import threading
import time
from pathlib import Path
from typing import Sequence

import numpy as np
from pymodbus.client import ModbusTcpClient
from pymodbus.datastore import ModbusSequentialDataBlock, ModbusServerContext, ModbusSlaveContext
from pymodbus.server import ModbusTcpServer

from .records import MAX_LISTED, write_records
from .register_map import REGISTER_MAX, RegisterMap
from .regulator import RegulatorSim
from .sequence import SEQ_MODULUS, SequenceGate, resync


class PlcLinkError(RuntimeError):
    """The PLC could not be reached, did not answer, or answered with an error."""


# --------------------------------------------------------------------------- client
class PlcClient:
    """Synchronous Modbus TCP client for the pressure PLC.

    pymodbus reconnects on the next request by itself, so after a PlcLinkError the caller
    just keeps calling; ``connect()`` is only needed to find out early whether the PLC is there.
    """

    def __init__(self, register_map: RegisterMap, host: str, port: int = 502, timeout_s: float = 0.5):
        if not timeout_s > 0:
            raise ValueError(f'timeout_s must be > 0, got {timeout_s!r}')
        self.map = register_map
        self.host, self.port, self.timeout_s = host, port, timeout_s
        # retries=0: a command retried after a timeout would arrive late and out of order;
        # the caller's next cycle sends a fresh one instead.
        self._client = ModbusTcpClient(host, port=port, timeout=timeout_s, retries=0)
        self._seq: int | None = None  # last sequence number sent (kept across reconnects)
        self._synced = False          # the PLC's last applied number read on this connection

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

    def write_counts(self, counts: Sequence[int]) -> None:
        """Raw register counts to the command registers, as they are (no clamp, no scaling):
        the benchmarks' bare Modbus hop. The package's commands go through write_pressures."""
        if len(counts) != len(self.map):
            raise ValueError(f'need {len(self.map)} counts, got {len(counts)}')
        self._write_commands(list(counts))

    def _write_commands(self, counts: list[int]) -> None:
        sequenced = self.map.sequenced_block()
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
        block = self.map.command_block()
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
        """Run one pymodbus request; every way it can fail becomes PlcLinkError."""
        kwargs = {'slave': self.map.unit_id}
        if count is not None:
            kwargs['count'] = count
        try:
            response = getattr(self._client, method)(*args, **kwargs)
        except Exception as exc:  # noqa: BLE001
            # Broad on purpose: besides ModbusException and OSError, pymodbus can let decoding
            # errors through on a garbled frame; the control loop must see one error type.
            # Drop the socket: a late answer to this request must not be taken as the answer
            # to the next one (the sync client does not match transaction ids).
            self.close()
            raise PlcLinkError(f'{what} to PLC {self.host}:{self.port} failed: {exc}') from exc
        if response is None or response.isError():
            self.close()
            raise PlcLinkError(f'{what} to PLC {self.host}:{self.port}: error response {response}')
        if count is not None and len(getattr(response, 'registers', ())) != count:
            self.close()
            raise PlcLinkError(f'{what} to PLC {self.host}:{self.port}: asked for {count} registers, '
                               f'got {len(getattr(response, "registers", ()))}')
        return response


# ------------------------------------------------------------------------ mock PLC
# pymodbus' ModbusSlaveContext adds 1 to every protocol address before it reaches the data
# block, so a block starting at 1 puts protocol address a at index a.
_BLOCK_START = 1
_N_ADDRESSES = REGISTER_MAX + 1
#: The records file lags the records by at most this [s] (plus one scan).
RECORDS_PERIOD_S = 0.1


class _RecordingHoldingBlock(ModbusSequentialDataBlock):
    """Holding registers (full 16-bit address space) that record every write from a client.

    Writes by the simulated PLC itself (the watchdog venting) go through ``force()`` and are
    not recorded: the records are about what the package sent.
    """

    def __init__(self, register_map: RegisterMap, lock: threading.RLock):
        super().__init__(_BLOCK_START, [0] * _N_ADDRESSES)
        self._map = register_map
        self._lock = lock
        self._channel_of = {c.command_register: c.name for c in register_map.channels}
        self.max_written_counts: dict[str, int] = {}
        self.out_of_map_writes: list[tuple[int, int]] = []
        self.over_limit_writes: list[tuple[int, int]] = []
        self.gate = SequenceGate()
        self.stale_writes: list[tuple[int, int]] = []  # (sequence number, last applied) of refused writes
        self.writes = 0    # client write requests to holding registers
        self.version = 0   # bumped on every change of the records
        #: (time.monotonic_ns(), first address, values) per applied client write, when timing is
        #: on (the benchmarks' landing times); None: off, nothing is recorded.
        self.write_times: list[tuple[int, int, tuple[int, ...]]] | None = None

    def _check(self, address: int, count: int) -> int:
        start = address - _BLOCK_START
        if start < 0 or start + count > _N_ADDRESSES:
            # Raising makes pymodbus answer with an exception response instead of growing the list.
            raise ValueError(f'registers {start}..{start + count - 1} outside 0..{REGISTER_MAX}')
        return start

    def getValues(self, address, count=1):
        with self._lock:
            self._check(address, count)
            return super().getValues(address, count)

    def setValues(self, address, values):
        values = list(values) if isinstance(values, (list, tuple)) else [values]
        with self._lock:
            start = self._check(address, len(values))
            self.writes += 1
            self.version += 1
            # Recorded before the sequence check: the records are about what was sent.
            for a, v in enumerate(values, start):
                name = self._channel_of.get(a)
                if name is not None:
                    self.max_written_counts[name] = max(v, self.max_written_counts.get(name, 0))
                    if v > self._map.p_max_counts:
                        self.over_limit_writes.append((a, v))
                elif a != self._map.heartbeat_register and a != self._map.sequence_register:
                    self.out_of_map_writes.append((a, v))
            seq_at = self._map.sequence_register
            if seq_at is not None and start <= seq_at < start + len(values):
                seq, last = values[seq_at - start], self.gate.last
                if not self.gate.accept(seq):
                    self.stale_writes.append((seq, last))
                    # Refused whole, with an exception response (the registers keep the newer
                    # command); its sender is normally gone already.
                    raise ValueError(f'stale write: sequence {seq} is not newer than {last}')
            if self.write_times is not None:
                # CLOCK_MONOTONIC is system-wide: comparable with a sender's stamps in another
                # process. Taken under the lock, so a take_write_times() never misses an earlier one.
                self.write_times.append((time.monotonic_ns(), start, tuple(values)))
            super().setValues(address, values)

    def read(self, address: int) -> int:
        with self._lock:
            return self.values[address]

    def force(self, address: int, value: int) -> None:
        with self._lock:
            self.values[address] = value

    def clear(self) -> None:
        """Registers to 0 (PLC power-up); the write records are kept across restarts."""
        with self._lock:
            self.values = [0] * _N_ADDRESSES
            self.gate.reset()


class MockPlcServer:
    """A simulated pressure PLC on Modbus TCP, for tests and the demo.

    Runs a pymodbus ``ModbusTcpServer`` on its own asyncio loop in a daemon thread, plus a scan
    task at ``update_hz`` that runs :class:`RegulatorSim` (watchdog + first-order lag) and
    writes the measured pressures into the input registers. Restartable: ``stop()`` then
    ``start()`` listens on the same port again (a fresh PLC boot: registers 0, watchdog
    tripped), keeping the write records and the trip count.
    """

    def __init__(self, register_map: RegisterMap, host: str = '127.0.0.1', port: int = 0,
                 regulator_tau_s: float = 0.15, watchdog_s: float = 0.5, update_hz: float = 100.0,
                 records_path: str | Path | None = None, time_writes: bool = False):
        if not update_hz > 0:
            raise ValueError(f'update_hz must be > 0, got {update_hz!r}')
        self.map = register_map
        # Where the write records go (JSON, records.py), for checks after the process is gone:
        # rewritten within RECORDS_PERIOD_S of a change and on stop().
        self.records_path = Path(records_path) if records_path else None
        self._records_written: tuple[int, int] | None = None
        self.host = host
        self._port = port
        self.update_hz = float(update_hz)
        self._lock = threading.RLock()
        self._holding = _RecordingHoldingBlock(register_map, self._lock)
        if time_writes:
            self._holding.write_times = []
        self._input = ModbusSequentialDataBlock(_BLOCK_START, [0] * _N_ADDRESSES)
        slave = ModbusSlaveContext(di=ModbusSequentialDataBlock.create(), co=ModbusSequentialDataBlock.create(),
                                   hr=self._holding, ir=self._input)
        # single=False: requests for another unit id get an error, as from a real PLC.
        self._context = ModbusServerContext(slaves={register_map.unit_id: slave}, single=False)
        self._sim = RegulatorSim(len(register_map), register_map.p_max_kpa, regulator_tau_s, watchdog_s)
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop_event: asyncio.Event | None = None
        self._cond = threading.Condition()
        self._listening = False
        self._error: BaseException | None = None
        self._server: ModbusTcpServer | None = None

    # ---- life cycle
    @property
    def port(self) -> int:
        """The TCP port (the one actually bound once started with port=0)."""
        return self._port

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self, timeout_s: float = 5.0) -> 'MockPlcServer':
        """Start listening; returns once connections are accepted (RuntimeError otherwise)."""
        if self.running:
            raise RuntimeError('MockPlcServer already running')
        with self._lock:
            self._holding.clear()
            self._input.values = [0] * _N_ADDRESSES
            self._sim.reset()
        self._listening, self._error, self._stop_event = False, None, None
        self._thread = threading.Thread(target=self._run, name=f'mock-plc-{self._port}', daemon=True)
        self._thread.start()
        with self._cond:
            self._cond.wait_for(lambda: self._listening or self._error is not None, timeout=timeout_s)
        if not self._listening:
            self.stop()
            raise RuntimeError(f'mock PLC did not start on {self.host}:{self._port}: '
                               f'{self._error or "timed out"}')
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        """Close the listener and all connections, stop the loop and join the thread."""
        thread, loop = self._thread, self._loop
        if thread is None:
            return
        if loop is not None and self._stop_event is not None:
            try:
                loop.call_soon_threadsafe(self._stop_event.set)
            except RuntimeError:  # loop already closed: the thread is ending anyway
                pass
        thread.join(timeout_s)
        if thread.is_alive():
            raise RuntimeError(f'mock PLC thread did not stop within {timeout_s} s')
        self._thread = None
        self.save_records()

    @property
    def client_count(self) -> int:
        """Clients connected now (read from another thread: a snapshot)."""
        server = self._server
        return len(server.active_connections) if server is not None and self.running else 0

    def wait_until_vented(self, timeout_s: float, poll_s: float = 0.02) -> bool:
        """Wait until no client is connected and every command register is 0, at most
        timeout_s; True if so. A PLC going away under a client that is still venting would
        leave the last command as the PLC's last state."""
        deadline = time.monotonic() + timeout_s
        while self.client_count or np.any(self.commands_kpa()):
            if time.monotonic() >= deadline:
                return False
            time.sleep(poll_s)
        return True

    def __enter__(self) -> 'MockPlcServer':
        return self.start()

    def __exit__(self, *_exc) -> None:
        self.stop()

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._serve())
        except BaseException as exc:  # noqa: BLE001 - reported to start(), not lost in the thread
            self._signal(error=exc)
        finally:
            loop.close()
            self._loop = None

    def _signal(self, *, listening: bool = False, error: BaseException | None = None) -> None:
        with self._cond:
            self._listening = self._listening or listening
            self._error = error
            self._cond.notify_all()

    async def _serve(self) -> None:
        self._stop_event = asyncio.Event()
        server = ModbusTcpServer(self._context, address=(self.host, self._port))
        self._server = server
        await server.serve_forever(background=True)
        listener = server.transport  # an asyncio.Server; pymodbus leaves it None if bind failed
        if listener is None:
            raise OSError(f'cannot listen on {self.host}:{self._port} (see pymodbus log)')
        # With port=0 the OS picked one; remember it so a restart comes back on the same port.
        self._port = listener.sockets[0].getsockname()[1]
        scan = asyncio.create_task(self._scan_loop())
        self._signal(listening=True)
        try:
            await self._stop_event.wait()
        finally:
            scan.cancel()
            await server.shutdown()  # closes the listener and every client connection
            others = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
            for task in others:
                task.cancel()
            # Lets the cancelled tasks and the transports' connection_lost callbacks run, so
            # sockets are closed before the loop is.
            await asyncio.gather(*others, return_exceptions=True)
            await asyncio.sleep(0)

    async def _scan_loop(self) -> None:
        period = 1.0 / self.update_hz
        next_s = time.monotonic()
        next_records_s = next_s
        while True:
            self._scan(time.monotonic())
            if time.monotonic() >= next_records_s:
                next_records_s = time.monotonic() + RECORDS_PERIOD_S
                self.save_records()
            next_s += period
            delay = next_s - time.monotonic()
            if delay < 0:  # fell behind (e.g. a busy test machine): resume the grid from now
                next_s, delay = time.monotonic(), 0.0
            await asyncio.sleep(delay)

    def _scan(self, now_s: float) -> None:
        """One PLC scan: watchdog, vent if tripped, regulator step, measured -> input registers."""
        m, h = self.map, self._holding
        with self._lock:
            counts = [h.read(a) for a in m.command_registers]
            result = self._sim.scan(list(m.decode(counts)), h.read(m.heartbeat_register), now_s)
            if result.vent:
                for a, c in zip(m.command_registers, counts):
                    if c:
                        h.force(a, 0)
            for a, p in zip(m.measured_registers, result.measured_kpa):
                self._input.values[a] = min(max(int(round(p * m.counts_per_kpa)), 0), REGISTER_MAX)

    # ---- records
    def records(self) -> dict:
        """What clients wrote, as records.py describes it (lists cut at MAX_LISTED entries)."""
        with self._lock:
            h = self._holding
            return {
                'p_max_kpa': self.map.p_max_kpa, 'p_max_counts': self.map.p_max_counts,
                'counts_per_kpa': self.map.counts_per_kpa, 'writes': h.writes,
                'max_written_counts': {name: int(h.max_written_counts.get(name, 0)) for name in self.map.names},
                'over_limit_count': len(h.over_limit_writes), 'over_limit_writes': h.over_limit_writes[:MAX_LISTED],
                'out_of_map_count': len(h.out_of_map_writes), 'out_of_map_writes': h.out_of_map_writes[:MAX_LISTED],
                'stale_count': len(h.stale_writes), 'stale_writes': h.stale_writes[:MAX_LISTED],
                'watchdog_trips': self._sim.watchdog.trips,
            }

    def save_records(self) -> None:
        """Write the records file if there is one and something changed since the last time."""
        if self.records_path is None:
            return
        with self._lock:
            version = (self._holding.version, self._sim.watchdog.trips)
            if version == self._records_written:
                return
            records = self.records()
        write_records(self.records_path, records)
        self._records_written = version

    @property
    def stale_writes(self) -> list[tuple[int, int]]:
        """(sequence number, last applied) of every write refused as older than the last applied."""
        with self._lock:
            return list(self._holding.stale_writes)

    # ---- observation (thread-safe; kPa in channel order unless said otherwise)
    def commands_kpa(self) -> np.ndarray:
        """The command holding registers as they are now."""
        with self._lock:
            return self.map.decode([self._holding.read(a) for a in self.map.command_registers])

    def measured_kpa(self) -> np.ndarray:
        """The measured-pressure input registers as they are now."""
        with self._lock:
            return self.map.decode([self._input.values[a] for a in self.map.measured_registers])

    def take_write_times(self) -> list[tuple[int, int, tuple[int, ...]]]:
        """The (time.monotonic_ns(), first address, values) of every client write since the last
        call, oldest first; [] unless started with time_writes=True."""
        with self._lock:
            taken = self._holding.write_times
            if taken is None:
                return []
            self._holding.write_times = []
            return taken

    def heartbeat_value(self) -> int:
        return self._holding.read(self.map.heartbeat_register)

    def max_written_kpa(self) -> dict[str, float]:
        """Largest value ever written by a client to each command channel (kPa); unwritten: 0."""
        with self._lock:
            return {name: self._holding.max_written_counts.get(name, 0) / self.map.counts_per_kpa
                    for name in self.map.names}

    @property
    def out_of_map_writes(self) -> list[tuple[int, int]]:
        """(address, value) of every client write to a holding register that is not in the map."""
        with self._lock:
            return list(self._holding.out_of_map_writes)

    @property
    def over_limit_writes(self) -> list[tuple[int, int]]:
        """(address, counts) of every client write above p_max counts to a command register."""
        with self._lock:
            return list(self._holding.over_limit_writes)

    @property
    def watchdog_trips(self) -> int:
        """How often the watchdog vented after heartbeats stopped (kept across restarts)."""
        with self._lock:
            return self._sim.watchdog.trips

    @property
    def watchdog_armed(self) -> bool:
        """True while commands are applied (heartbeat alive)."""
        with self._lock:
            return self._sim.watchdog.armed
