"""A mock PLC on Modbus TCP for tests and the demo (the client is modbus.py).

:class:`MockPlcServer` is a Modbus TCP server of its own (asyncio, in a background thread, no
pymodbus) that keeps the PLC contract (docs/plc.md) exactly as the PLC program does: the
register map's addresses only (exception 02 elsewhere), function codes 3, 4, 6, 16 (01 for
others), the quantity limits (03), silence for another unit id, the write sequence gate (a stale
or unnumbered command write is answered normally and undone), the clamp to p_max counts, the
heartbeat watchdog, the write claim (one connection writes; others get exception 06; the
holder's close or silence vents and frees it), the vent latch (a vent request from any
connection; the holder's re-arm) and the regulator lag (regulator.py); the registers and the
request handling are contract.py's. It records every write it gets,
optionally to a file (records.py), so tests can assert what left the package.
"""
from __future__ import annotations

import asyncio
import itertools
import struct
import threading
import time
from pathlib import Path

import numpy as np

from .contract import _Registers
from .records import MAX_LISTED, write_records
from .register_map import REGISTER_MAX, RegisterMap
from .regulator import RegulatorSim

__all__ = ['MockPlcServer', '_Registers']

# ------------------------------------------------------------------------ mock PLC
#: The records file lags the records by at most this [s] (plus one scan).
RECORDS_PERIOD_S = 0.1
_MBAP = struct.Struct('>HHHB')   # transaction id, protocol id, length (unit id + PDU), unit id
#: Largest PDU of Modbus TCP (a 260-byte ADU less the 7-byte MBAP header).
MAX_PDU = 253
#: A connection silent this long is closed, and one that sent part of a request and then
#: nothing for PARTIAL_S (the PLC program's kIdleMs and kPartialFrameMs, plc_link.h).
IDLE_S, PARTIAL_S = 10.0, 1.0


class MockPlcServer:
    """A simulated pressure PLC on Modbus TCP, for tests and the demo.

    Runs a Modbus TCP server (asyncio streams, the contract in :class:`_Registers`) on its own
    loop in a daemon thread, plus a scan
    task at ``update_hz`` that runs :class:`RegulatorSim` (watchdog + first-order lag) and
    writes the measured pressures into the input registers. Restartable: ``stop()`` then
    ``start()`` listens on the same port again (a fresh PLC boot: registers 0, watchdog
    tripped), keeping the write records and the trip count.
    """

    def __init__(self, register_map: RegisterMap, host: str = '127.0.0.1', port: int = 0,
                 regulator_tau_s: float = 0.15, watchdog_s: float = 0.5, update_hz: float = 100.0,
                 records_path: str | Path | None = None, time_writes: bool = False,
                 log_registers: bool = False):
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
        self._holding = _Registers(register_map, self._lock)
        if time_writes:
            self._holding.write_times = []
        if log_registers:
            self._holding.register_log = []
        self._sim = RegulatorSim(len(register_map), register_map.p_max_kpa, regulator_tau_s, watchdog_s)
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop_event: asyncio.Event | None = None
        self._cond = threading.Condition()
        self._listening = False
        self._error: BaseException | None = None
        self._writers: set[asyncio.StreamWriter] = set()
        self._connection_ids = itertools.count(1)
        # The owner's last sign of life at a scan: the claim, or a heartbeat change.
        self._scan_heartbeat: int | None = None
        self._owner_heard_s = 0.0

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
            self._holding.power_up()
            self._sim.reset()
            self._scan_heartbeat = None
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
        return len(self._writers) if self.running else 0

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
        listener = await asyncio.start_server(self._serve_connection, self.host, self._port)
        # With port=0 the OS picked one; remember it so a restart comes back on the same port.
        self._port = listener.sockets[0].getsockname()[1]
        scan = asyncio.create_task(self._scan_loop())
        self._signal(listening=True)
        try:
            await self._stop_event.wait()
        finally:
            scan.cancel()
            listener.close()
            for writer in list(self._writers):
                writer.close()
            others = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
            for task in others:
                task.cancel()
            # Lets the cancelled tasks and the transports' connection_lost callbacks run, so
            # sockets are closed before the loop is.
            await asyncio.gather(*others, return_exceptions=True)
            await asyncio.sleep(0)

    async def _serve_connection(self, reader: asyncio.StreamReader,
                                writer: asyncio.StreamWriter) -> None:
        """One client connection: request, answer, in order (Modbus TCP, MBAP framing)."""
        self._writers.add(writer)
        connection = next(self._connection_ids)
        peername = writer.get_extra_info('peername')
        peer = (str(peername[0]), int(peername[1])) if peername else ('', 0)
        try:
            while True:
                # Nothing for IDLE_S, or a request cut short: a dead peer's connection is closed
                # (and vents if it held the write claim), as the PLC program reaps its sockets.
                first = await asyncio.wait_for(reader.readexactly(1), IDLE_S)
                header = first + await asyncio.wait_for(reader.readexactly(_MBAP.size - 1), PARTIAL_S)
                tid, protocol, length, unit = _MBAP.unpack(header)
                if protocol != 0 or not 2 <= length <= MAX_PDU + 1:
                    return  # not Modbus TCP: drop the connection, as a device does
                pdu = await asyncio.wait_for(reader.readexactly(length - 1), PARTIAL_S)
                if unit != self.map.unit_id:
                    continue  # another unit id: no answer at all; the connection stays open
                answer = self._holding.handle(pdu, connection, peer)
                writer.write(_MBAP.pack(tid, 0, len(answer) + 1, unit) + answer)
                await writer.drain()
        except (asyncio.IncompleteReadError, ConnectionError, asyncio.TimeoutError):
            return  # the client went away, or fell silent
        except asyncio.CancelledError:
            return  # stop(): the connection is closed below
        finally:
            self._writers.discard(writer)
            writer.close()
            with self._lock:
                h = self._holding
                pressurised = any(h.holding[a] for a in h.commands)
                if h.connection_closed(connection) and self._sim.watchdog.armed:
                    # Tripped by the close, not by the time: the outputs vent at once. Counted as
                    # a trip only when it vented something: a writer that vented, then closed
                    # (plc_output's shutdown), left nothing for the PLC to vent.
                    self._sim.watchdog.armed = False
                    if pressurised:
                        self._sim.watchdog.trips += 1

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
            if h.latched and any(h.holding[a] for a in h.commands):
                h.force_commands_zero('vent latch')
            counts = [h.holding[a] for a in m.command_registers]
            result = self._sim.scan(list(m.decode(counts)), h.holding[m.heartbeat_register], now_s)
            if result.vent:
                h.force_commands_zero()
            self._claim_scan(now_s)
            for a, p in zip(m.measured_registers, result.measured_kpa):
                h.input[a] = min(max(int(round(p * m.counts_per_kpa)), 0), REGISTER_MAX)

    def _claim_scan(self, now_s: float) -> None:
        """The write claim at a scan (lock held), as the PLC program's Core::scan: only the
        holder's heartbeat arms the watchdog; a holder silent for the watchdog's time loses it."""
        h, watchdog = self._holding, self._sim.watchdog
        heartbeat = h.holding[self.map.heartbeat_register]
        if self._scan_heartbeat is not None and heartbeat != self._scan_heartbeat:
            self._owner_heard_s = now_s
            if h.owner is None and watchdog.armed:   # its writer closed before this scan
                watchdog.armed = False
                h.force_commands_zero()
        self._scan_heartbeat = heartbeat
        if h.claim_pending:
            h.claim_pending = False
            self._owner_heard_s = now_s
        if h.owner is not None and now_s - self._owner_heard_s >= watchdog.timeout_s:
            h.owner = None

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
                'busy_count': h.busy, 'owner_lost_count': h.owner_lost,
                'vent_request_count': h.vent_requests, 'rearm_count': h.rearms,
                'vent_latched': h.latched,
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
    def stale_writes(self) -> list[tuple[int | None, int | None]]:
        """(sequence number, last applied) of every command write answered but undone: its number
        was not newer than the last applied one, or it had none (None)."""
        with self._lock:
            return list(self._holding.stale_writes)

    # ---- observation (thread-safe; kPa in channel order unless said otherwise)
    def commands_kpa(self) -> np.ndarray:
        """The command holding registers as they are now."""
        with self._lock:
            return self.map.decode([self._holding.holding[a] for a in self.map.command_registers])

    def measured_kpa(self) -> np.ndarray:
        """The measured-pressure input registers as they are now."""
        with self._lock:
            return self.map.decode([self._holding.input[a] for a in self.map.measured_registers])

    def take_write_times(self) -> list[tuple[int, int, tuple[int, ...]]]:
        """The (time.monotonic_ns(), first address, values) of every client write since the last
        call, oldest first; [] unless started with time_writes=True."""
        with self._lock:
            taken = self._holding.write_times
            if taken is None:
                return []
            self._holding.write_times = []
            return taken

    def take_register_log(self) -> list[tuple[int, str, tuple[int, ...], int]]:
        """The register log entries since the last call, oldest first (each: time.monotonic_ns(),
        cause, command counts as applied, largest command count sent); [] unless started with
        log_registers=True. A power-up entry is logged at every start."""
        with self._lock:
            taken = self._holding.register_log
            if taken is None:
                return []
            self._holding.register_log = []
            return taken

    def heartbeat_value(self) -> int:
        with self._lock:
            return self._holding.holding[self.map.heartbeat_register]

    def max_written_kpa(self) -> dict[str, float]:
        """Largest value ever written by a client to each command channel (kPa); unwritten: 0."""
        with self._lock:
            return {name: self._holding.max_written_counts.get(name, 0) / self.map.counts_per_kpa
                    for name in self.map.names}

    @property
    def out_of_map_writes(self) -> list[tuple[int, int]]:
        """(address, value) of every client write to a holding register that is not in the map
        (each refused with exception 02)."""
        with self._lock:
            return list(self._holding.out_of_map_writes)

    @property
    def over_limit_writes(self) -> list[tuple[int, int]]:
        """(address, counts) of every client write above p_max counts to a command register
        (stored clamped to p_max counts; still a violation of the package's invariant)."""
        with self._lock:
            return list(self._holding.over_limit_writes)

    @property
    def watchdog_trips(self) -> int:
        """How often the watchdog vented after heartbeats stopped (kept across restarts)."""
        with self._lock:
            return self._sim.watchdog.trips

    @property
    def vent_latched(self) -> bool:
        """True while the vent latch holds (a vent request, not yet re-armed by the holder)."""
        with self._lock:
            return self._holding.latched

    @property
    def watchdog_armed(self) -> bool:
        """True while commands are applied (heartbeat alive)."""
        with self._lock:
            return self._sim.watchdog.armed
