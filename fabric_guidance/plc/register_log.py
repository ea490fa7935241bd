"""The mock PLC's register log (mock_plc's register_log_file) read back, and the invariants a
fault run is held to, judged from that log alone: what the PLC applied, when.

Each line is JSON: ``{"t_ns", "cause", "counts", "sent_max"}`` when the command registers as
applied changed (cause: a client ``write``, a ``stale write undone``, the PLC's own ``watchdog``
vent, a ``power_up``) or a write sent more than p_max counts (``sent_max``, the largest command
count of that write as sent, before the PLC's clamp); ``{"drained_ns"}`` closes every drain: every
change before that time is in the file. Times are CLOCK_MONOTONIC, the same clock as
``time.monotonic()`` in any process of the machine, so a fault's time taken by the process that
injected it compares with the PLC's.

The invariants (each a function returning one line per breach, [] when none):

- ``over_p_max``: no write ever sent a command above p_max counts;
- ``vent_time`` / ``late_vents``: after a fault, every command register reads 0 within the
  fault's deadline;
- ``gate_breaches``: after a restarted controller, once vented, nothing nonzero is applied
  before the operator's enable.

Plain Python: no ROS, no Modbus.
"""
from __future__ import annotations

from dataclasses import dataclass
import json
from pathlib import Path


@dataclass(frozen=True)
class Entry:
    t: float                 # CLOCK_MONOTONIC [s]
    cause: str
    counts: tuple[int, ...]  # the command registers as applied
    sent_max: int = 0        # the largest command count of the write as sent

    @property
    def vented(self) -> bool:
        return not any(self.counts)


def parse_line(line: str, where: str) -> Entry | float | None:
    """An Entry, a drained time [s] (float), or None for a blank line; ValueError naming where."""
    if not line.strip():
        return None
    try:
        d = json.loads(line)
        if 'drained_ns' in d:
            return int(d['drained_ns']) * 1e-9
        return Entry(int(d['t_ns']) * 1e-9, str(d['cause']), tuple(int(c) for c in d['counts']),
                     int(d.get('sent_max', 0)))
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f'{where}: not a register log line ({exc}): {line.strip()[:80]!r}') from None


class RegisterLog:
    """The log of one file, read as it grows: ``poll()`` adds the complete lines written since."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.entries: list[Entry] = []
        self.drained = -float('inf')   # every change before this time [s] is in `entries`
        self._offset = 0
        self._line_no = 0

    def poll(self) -> 'RegisterLog':
        if not self.path.exists():
            return self
        with open(self.path) as f:
            f.seek(self._offset)
            text = f.read()
        complete = text[:text.rfind('\n') + 1]   # a line still being written waits for the next poll
        self._offset += len(complete.encode())
        for line in complete.splitlines():
            self._line_no += 1
            item = parse_line(line, f'{self.path}:{self._line_no}')
            if isinstance(item, Entry):
                self.entries.append(item)
            elif item is not None:
                self.drained = max(self.drained, item)
        return self

    def state_at(self, t: float) -> Entry | None:
        """The entry in force at time t (the last one at or before t)."""
        found = None
        for e in self.entries:
            if e.t > t:
                break
            found = e
        return found


def over_p_max(entries: list[Entry], p_max_counts: int, source: str = 'register log') -> list[str]:
    """Every write that sent a command above p_max counts (or stored one), one line each."""
    return [f'{source}: at t={e.t:.3f} s a write sent {e.sent_max} counts (p_max {p_max_counts}); applied '
            f'{list(e.counts)}' for e in entries
            if e.sent_max > p_max_counts or max(e.counts, default=0) > p_max_counts]


def vent_time(entries: list[Entry], t_fault: float, t_end: float | None = None) -> float | None:
    """Seconds from t_fault to the vent: without t_end, the first moment every command register
    reads 0; with t_end, the start of the vent that still holds at t_end (a vent the fault caused
    lasts until the fault ends; a calibration's own vented rest between two steps does not).
    0.0 when vented already at t_fault; None when not vented (at t_end)."""
    if t_end is None:
        before = [e for e in entries if e.t <= t_fault]
        if not before or before[-1].vented:
            return 0.0
        for e in entries:
            if e.t > t_fault and e.vented:
                return e.t - t_fault
        return None
    upto = [e for e in entries if e.t <= t_end]
    if not upto or not upto[-1].vented:
        return None if upto else 0.0
    start = upto[-1].t
    for e in reversed(upto):
        if not e.vented:
            break
        start = e.t
    return max(0.0, start - t_fault)


@dataclass(frozen=True)
class Fault:
    """One injected fault as the run saw it: its kind, when, the deadline by which the suit must
    be vented (None: the fault need not vent), when it ended (SIGCONT, the link healed, a killed
    node restarted...: the vent must hold until then, and until the deadline at least), and for
    a restarted controller the time the operator's enable was called (the enable gate holds the
    suit vented from the vent until then)."""
    kind: str
    t: float
    deadline_s: float | None
    t_end: float | None = None
    t_enable: float | None = None

    @property
    def held_until(self) -> float:
        """Until when the log must reach before the fault is judged: its end, and its deadline."""
        return max(self.t_end if self.t_end is not None else self.t, self.t + (self.deadline_s or 0.0))


def vent_intervals(entries: list[Entry], t_from: float) -> list[tuple[float, float]]:
    """The spans [start, end) in which every command register read 0, of those still in force
    at or after t_from (end inf: still vented at the log's end). Before the first entry the
    registers read 0 (power-up)."""
    spans, start = [], -float('inf')
    for e in entries:
        if e.vented and start is None:
            start = e.t
        elif not e.vented and start is not None:
            spans.append((start, e.t))
            start = None
    if start is not None:
        spans.append((start, float('inf')))
    return [(s, end) for s, end in spans if end > t_from]


def fault_vent(entries: list[Entry], f: Fault) -> tuple[float | None, str]:
    """(seconds from the fault to the start of the vent it owes, '') or (None, why not).

    The vent it owes starts within the deadline and lasts until the fault ended: pressure before
    the vent (inside the deadline) is allowed, and so is guidance resumed after the fault ended,
    even when that is sooner than the deadline (a respawned node back quickly). Without an end
    the vent must hold until the deadline."""
    due = f.t + (f.deadline_s or 0.0)
    until = f.t_end if f.t_end is not None else due
    spans = vent_intervals(entries, f.t)
    in_time = [(s, end) for s, end in spans if s <= due]
    for s, end in in_time:
        if end >= until:
            return max(0.0, s - f.t), ''
    if in_time:
        s, end = in_time[-1]
        return None, (f'vented after {max(0.0, s - f.t):.3f} s but pressure again {end - f.t:.3f} s after it, '
                      f'before the fault ended at {until - f.t:.3f} s')
    late = [s for s, end in spans if end >= until]
    if late:
        return None, f'vented after {late[0] - f.t:.3f} s (deadline {f.deadline_s:.3f} s)'
    return None, f'not vented {until - f.t:.3f} s later, when the fault ended (deadline {f.deadline_s:.3f} s)'


def late_vents(entries: list[Entry], faults: list[Fault], drained: float) -> list[str]:
    """Every fault with a deadline whose vent came late, or did not hold until the fault ended
    (judged once the log covers that time)."""
    found = []
    for f in faults:
        if f.deadline_s is None or drained < f.held_until:
            continue
        seconds, why = fault_vent(entries, f)
        if seconds is None:
            found.append(f'{f.kind} at t={f.t:.3f} s: {why}')
    return found


def gate_breaches(entries: list[Entry], faults: list[Fault]) -> list[str]:
    """Every restarted controller after whose vent something nonzero was applied before the
    operator's enable (guidance resumed without passing the enable gate)."""
    found = []
    for f in faults:
        if f.t_enable is None:
            continue
        seconds, _ = fault_vent(entries, f)
        if seconds is None:
            continue   # not vented: late_vents reports it
        t_vented = f.t + seconds
        for e in entries:
            if t_vented < e.t < f.t_enable and not e.vented:
                found.append(f'{f.kind} at t={f.t:.3f} s: {list(e.counts)} applied at t={e.t:.3f} s, '
                             f'{f.t_enable - e.t:.3f} s before the operator enabled ({e.cause})')
                break
    return found


__all__ = ['Entry', 'Fault', 'RegisterLog', 'fault_vent', 'gate_breaches', 'late_vents', 'over_p_max', 'parse_line',
           'vent_intervals', 'vent_time']
