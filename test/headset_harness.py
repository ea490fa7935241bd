"""The compiled C# headset (hololens/, HeadsetHarness.exe) for graph tests, and a UDP delay
proxy to put between it and the PC's nodes."""
from __future__ import annotations

import heapq
import json
import math
import os
from pathlib import Path
import random
import selectors
import shutil
import socket
import struct
import subprocess
import threading
import time

import pytest

from fabric_guidance.bench.build_lock import locked_run
from rosgraph import ROOT

HOLOLENS = ROOT / 'hololens'
EXE = HOLOLENS / 'build~' / 'HeadsetHarness.exe'
#: How long the harness may take to bind and say so (mono's start-up on a loaded machine).
START_DEADLINE_S = 20.0


def build_harness() -> Path:
    """Build hololens/ with mcs (make skips what is up to date); skip without mono."""
    missing = [tool for tool in ('mcs', 'mono', 'make') if shutil.which(tool) is None]
    if missing:
        pytest.skip(f'{", ".join(missing)} not installed (Debian mono-mcs, mono-runtime: make system-deps)')
    done = locked_run(['make', '--no-print-directory', '-C', str(HOLOLENS), 'all'], EXE.parent, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    return EXE


class Harness:
    """HeadsetHarness.exe running: listening on `port`, sending gaze to `uplink`."""

    def __init__(self, log_path: Path, *args: str, env: dict | None = None):
        self.log_path = Path(log_path)
        self.proc = subprocess.Popen(['mono', str(EXE), '--log', str(self.log_path), *args],
                                     stdin=subprocess.PIPE if 'stdin' in args else subprocess.DEVNULL,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     env=dict(os.environ, **(env or {})))
        sel = selectors.DefaultSelector()
        sel.register(self.proc.stdout, selectors.EVENT_READ)
        ready = sel.select(START_DEADLINE_S)
        sel.close()
        line = self.proc.stdout.readline() if ready else ''
        if not line.startswith('listening '):
            self.proc.kill()
            raise AssertionError(f'the harness did not start: {line!r} {self.proc.stderr.read()}')
        self.port = int(line.split(':')[-1])

    def command(self, line: str) -> None:
        """A command on its standard input (started with --commands stdin), e.g. 'confirm'."""
        self.proc.stdin.write(line + '\n')
        self.proc.stdin.flush()

    def wait(self, timeout: float = 60.0) -> dict:
        """Its exit, and the counts of its last line (`harness: sent N, skipped N, ...`)."""
        out, err = self.proc.communicate(timeout=timeout)
        assert self.proc.returncode == 0, err
        last = out.strip().splitlines()[-1]
        assert last.startswith('harness: '), out
        return {k: int(v) for k, v in (part.split() for part in last[len('harness: '):].split(', '))}

    def log(self) -> list[dict]:
        return [json.loads(line) for line in self.log_path.read_text().splitlines() if line.strip()]

    def messages(self, kind: str | None = None) -> list[dict]:
        return [e['msg'] for e in self.log() if 'msg' in e and (kind is None or e['msg']['kind'] == kind)]

    def stop(self) -> None:
        """SIGTERM, and wait: its log is complete afterwards."""
        self.proc.terminate()
        self.proc.communicate(timeout=10)

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.communicate()


def pose_line(gaze_yaw_left_deg: float, gaze_pitch_up_deg: float, head_quat_unity, origin=(0.1, 1.6, 0.2),
              valid: bool = True) -> str:
    """One pose of the harness's --poses file, in Unity's frame (x right, y up, z forward)."""
    yaw, pitch = math.radians(gaze_yaw_left_deg), math.radians(gaze_pitch_up_deg)
    direction = [-math.sin(yaw) * math.cos(pitch), math.sin(pitch), math.cos(yaw) * math.cos(pitch)]
    return json.dumps({'gaze_origin': list(origin), 'gaze_direction': direction, 'head_position': list(origin),
                       'head_orientation': list(head_quat_unity), 'valid': valid})


def unity_euler_quat(x_deg: float = 0.0, y_deg: float = 0.0) -> tuple:
    """Unity's Quaternion.Euler(x, 0, 0) or (0, y, 0): a pitch (x > 0 looks down) or a yaw
    (y > 0 turns right)."""
    if x_deg:
        h = math.radians(x_deg) / 2
        return (math.sin(h), 0.0, 0.0, math.cos(h))
    h = math.radians(y_deg) / 2
    return (0.0, math.sin(h), 0.0, math.cos(h))


#: Linux's SO_TIMESTAMPNS (= SCM_TIMESTAMPNS; the socket module does not name it): the kernel
#: stamps each datagram with CLOCK_REALTIME on arrival, a struct timespec of two longs.
SO_TIMESTAMPNS = 35
_TIMESPEC = struct.Struct('@ll')


def _kernel_timestamps(sock: socket.socket) -> bool:
    """Ask the kernel to stamp each datagram on arrival; False where it cannot."""
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        return True
    except OSError:
        return False


def _receive(sock: socket.socket, stamped: bool) -> tuple[bytes, float]:
    """(datagram, time.time() of its arrival): the kernel's stamp where there is one, so that a
    thread of this process that runs late on a loaded machine does not date it late."""
    if stamped:
        data, ancillary, _, _ = sock.recvmsg(2048, socket.CMSG_SPACE(_TIMESPEC.size))
        for level, kind, payload in ancillary:
            if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(payload) >= _TIMESPEC.size:
                sec, nsec = _TIMESPEC.unpack_from(payload)
                return data, sec + nsec * 1e-9
        return data, time.time()
    data, _ = sock.recvfrom(2048)
    return data, time.time()


class DelayProxy:
    """Forwards UDP both ways between a headset and the PC with a delay per direction (plus a
    seeded uniform jitter), and notes when each uplink datagram reached it: the truth of its
    capture time, before the injected delay. Loopback only; the queue is bounded."""

    MAX_QUEUED = 20000

    def __init__(self, up_s: float, down_s: float, jitter_s: float = 0.0, seed: int = 1):
        self.bridge: tuple | None = None         # gaze_bridge's address, and
        self.headset: tuple | None = None        # the harness's listen address: set once known
        self.up_s, self.down_s, self.jitter_s = up_s, down_s, jitter_s
        self.rng = random.Random(seed)
        self.uplink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)     # the harness sends here
        self.uplink.bind(('127.0.0.1', 0))
        self.downlink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)   # the bridge pings here
        self.downlink.bind(('127.0.0.1', 0))
        self.up_port, self.down_port = self.uplink.getsockname()[1], self.downlink.getsockname()[1]
        self.arrivals: dict[int, float] = {}     # gaze seq -> time.time() when it reached the proxy
        self.confirms: list[tuple[int, float]] = []   # (press_id, time.time()) of each confirm datagram
        self._queue: list = []
        self._lock = threading.Condition()
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._read, args=(self.uplink, True), daemon=True),
                         threading.Thread(target=self._read, args=(self.downlink, False), daemon=True),
                         threading.Thread(target=self._write, daemon=True)]
        for t in self._threads:
            t.start()

    def _read(self, sock: socket.socket, up: bool) -> None:
        sock.settimeout(0.1)
        stamped = _kernel_timestamps(sock)
        while not self._stop.is_set():
            try:
                data, now = _receive(sock, stamped)
            except socket.timeout:
                continue
            except OSError:
                return
            if up and b'"seq"' in data and b'clock_echo' not in data:
                self.arrivals[json.loads(data)['seq']] = now
            elif up and b'"confirm"' in data:
                self.confirms.append((json.loads(data)['press_id'], now))
            with self._lock:
                delay = (self.up_s if up else self.down_s) + self.rng.uniform(0.0, self.jitter_s)
                dest = self.bridge if up else self.headset
                if len(self._queue) < self.MAX_QUEUED and dest is not None:
                    # Out of the uplink socket to the bridge; out of the downlink socket to the headset,
                    # due `delay` after the datagram's arrival, however late this thread ran.
                    due = time.monotonic() - (time.time() - now) + delay
                    heapq.heappush(self._queue, (due, id(data), data,
                                                 self.downlink if up else self.uplink, dest))
                    self._lock.notify()

    def _write(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                if not self._queue:
                    self._lock.wait(0.05)
                    continue
                due = self._queue[0][0] - time.monotonic()
                if due > 0:
                    self._lock.wait(min(due, 0.05))
                    continue
                _, _, data, sock, dest = heapq.heappop(self._queue)
            try:
                sock.sendto(data, dest)
            except OSError:
                pass

    def close(self) -> None:
        self._stop.set()
        with self._lock:
            self._lock.notify_all()
        for t in self._threads:
            t.join(1.0)
        self.uplink.close()
        self.downlink.close()
