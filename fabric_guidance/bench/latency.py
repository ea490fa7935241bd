"""Gaze in, register out: the sender, the mock PLC's write log, and matching a sample to the
moment its value landed. Both ends stamp CLOCK_MONOTONIC (time.monotonic_ns), one clock for
every process of this machine.
"""
from __future__ import annotations

import bisect
from dataclasses import dataclass
from pathlib import Path
import socket
import time
from typing import Callable, Sequence

import numpy as np

from ..graph.process_graph import wait_until


def percentiles_ms(latencies_ns: Sequence[int]) -> dict:
    """p50, p99 and max of latencies [ms]; None for each when there are none."""
    if len(latencies_ns) == 0:
        return {'p50': None, 'p99': None, 'max': None}
    a = np.asarray(latencies_ns, dtype=float) / 1e6
    return {'p50': float(np.percentile(a, 50)), 'p99': float(np.percentile(a, 99)), 'max': float(a.max())}


def percentiles_of(values: Sequence[float]) -> dict:
    a = np.asarray(values, dtype=float)
    return {'p50': float(np.percentile(a, 50)), 'p99': float(np.percentile(a, 99))}


class Sender:
    """UDP datagrams at a fixed rate on an absolute schedule; each one's send time is
    time.monotonic_ns() right before sendto."""

    def __init__(self, port: int, host: str = '127.0.0.1'):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.address = (host, port)
        self.sent_ns: list[int] = []   # index = sample number

    def send(self, datagrams: Sequence[bytes], rate_hz: float, first: int = 0) -> None:
        """Send datagrams[k] as sample first + k, every 1/rate_hz seconds (blocking)."""
        period_ns = int(round(1e9 / rate_hz))
        sendto, address, now_ns, sleep = self.sock.sendto, self.address, time.monotonic_ns, time.sleep
        assert len(self.sent_ns) == first, 'samples must be sent in order'
        sent = self.sent_ns
        next_ns = now_ns()
        for data in datagrams:
            wait = next_ns - now_ns()
            if wait > 0:
                sleep(wait / 1e9)
            sent.append(now_ns())
            sendto(data, address)
            next_ns += period_ns
            if now_ns() - next_ns > 20 * period_ns:  # descheduled for long: keep the rate from now on
                next_ns = now_ns()

    def close(self) -> None:
        self.sock.close()


@dataclass
class Write:
    t_ns: int
    start: int
    values: tuple[int, ...]


class WriteLog:
    """Reads the file mock_plc's write_log_file parameter writes (see nodes/mock_plc.py)."""

    def __init__(self, path: Path):
        self.path = Path(path)

    def _lines(self) -> list[str]:
        try:
            return self.path.read_text().splitlines()
        except FileNotFoundError:
            return []

    def drained_ns(self) -> int:
        """The latest drain mark: every write before it is in the file."""
        for line in reversed(self._lines()):
            if line.startswith('# drained '):
                return int(line.split()[2])
        return 0

    def wait_drained(self, t_ns: int, timeout_s: float = 10.0) -> None:
        wait_until(lambda: self.drained_ns() >= t_ns, timeout_s, interval=0.02, what='the mock PLC write log')

    def writes(self, since_ns: int = 0) -> list[Write]:
        out = []
        for line in self._lines():
            if not line or line.startswith('#'):
                continue
            fields = line.split()
            t = int(fields[0])
            if t >= since_ns:
                out.append(Write(t, int(fields[1]), tuple(int(v) for v in fields[2:])))
        out.sort(key=lambda w: w.t_ns)
        return out


def landings(sent_ns: Sequence[int], writes: Sequence[Write], register: int,
             level_of: Callable[[int], int | None], levels: int) -> dict[int, int]:
    """Sample number -> the time its value first landed in `register` [ns].

    A landed count names a level; the sample is the latest one of that level sent before the
    write. A sample's value written again later (a re-send) is not a new landing.
    """
    landed: dict[int, int] = {}
    for w in writes:
        offset = register - w.start
        if not 0 <= offset < len(w.values):
            continue
        j = level_of(w.values[offset])
        if j is None:
            continue
        k = bisect.bisect_right(sent_ns, w.t_ns) - 1   # the last sample sent before the write
        if k < 0:
            continue
        i = k - ((k - j) % levels)
        if i >= 0 and i not in landed:
            landed[i] = w.t_ns
    return landed
