"""The PLC program's host build (firmware/host/plc_host.cpp) for the tests: built once per
session with firmware/Makefile, started as a process in place of mock_plc, its state file
(write records as plc/records.py has them, plus what reached the outputs) read back."""
from __future__ import annotations

import functools
import json
from pathlib import Path
import select
import shutil
import signal
import subprocess
import time

import pytest

from fabric_guidance.bench.build_lock import locked_run
from fabric_guidance.plc import RegisterMap

FIRMWARE = Path(__file__).resolve().parents[1] / 'firmware'
#: The program's compile-time scaling (firmware/fabric_plc/src/scaling.h, kCountsPerKpa).
PROGRAM_COUNTS_PER_KPA = 10


def need_tools(*tools: str) -> None:
    """Skip (one line, naming the Debian package) when a build tool is absent."""
    packages = {'g++': 'g++', 'make': 'make', 'avr-g++': 'gcc-avr', 'avr-size': 'binutils-avr',
                'mbpoll': 'mbpoll'}
    for tool in tools:
        if shutil.which(tool) is None:
            pytest.skip(f'{tool} not installed (Debian package {packages.get(tool, tool)})')


@functools.lru_cache(maxsize=None)
def _make(target: str) -> tuple[int, str]:
    out = locked_run(['make', '-C', str(FIRMWARE), target], FIRMWARE / 'build', timeout=600)
    return out.returncode, out.stdout + out.stderr


def make(target: str) -> str:
    """Run a firmware/Makefile target once per session; fail with its output."""
    need_tools('make', 'g++')
    code, output = _make(target)
    assert code == 0, f'make -C firmware {target} failed:\n{output}'
    return output


def host_binary() -> Path:
    make('build/plc_host')
    return FIRMWARE / 'build' / 'plc_host'


class PlcProgram:
    """One running host build. `args()` is its command line for a register map (all channels
    on one endpoint, as the default map), so a Graph can start it too."""

    def __init__(self, state_path: Path, register_map: RegisterMap, port: int = 0,
                 watchdog_s: float = 0.5, scan_s: float = 0.01):
        if register_map.counts_per_kpa != PROGRAM_COUNTS_PER_KPA:
            raise ValueError(f'the program is built for counts_per_kpa {PROGRAM_COUNTS_PER_KPA}, '
                             f'the map has {register_map.counts_per_kpa}')
        if register_map.sequence_register != len(register_map) or \
                register_map.heartbeat_register != len(register_map) + 1:
            raise ValueError('the program serves the contract layout: sequence register N, '
                             'heartbeat N + 1')
        self.map = register_map
        self.state_path = Path(state_path)
        self.port = port
        self.watchdog_s, self.scan_s = watchdog_s, scan_s
        self.proc: subprocess.Popen | None = None

    def args(self) -> list[str]:
        m = self.map
        return [str(host_binary()), '--port', str(self.port), '--unit-id', str(m.unit_id),
                '--channels', str(len(m)), '--p-max-counts', str(m.p_max_counts),
                '--watchdog-ms', str(round(self.watchdog_s * 1000)),
                '--scan-ms', str(round(self.scan_s * 1000)), '--state', str(self.state_path),
                '--names', ','.join(m.names)]

    def start(self, timeout_s: float = 10.0) -> 'PlcProgram':
        self.proc = subprocess.Popen(self.args(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True)
        self.port = wait_listening(self.proc, timeout_s)
        return self

    def state(self) -> dict:
        return json.loads(self.state_path.read_text())

    def stop(self, sig: int = signal.SIGINT, timeout_s: float = 10.0) -> int:
        if self.proc is None:
            return 0
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        code = self.proc.wait(timeout_s)
        self.proc.stdout.close()
        return code

    def __enter__(self) -> 'PlcProgram':
        return self.start()

    def __exit__(self, *_exc) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.stop()


def wait_listening(proc: subprocess.Popen, timeout_s: float) -> int:
    """The port from the program's 'listening on HOST:PORT' line, within timeout_s."""
    deadline = time.monotonic() + timeout_s
    seen = ''
    while time.monotonic() < deadline:
        ready, _, _ = select.select([proc.stdout], [], [], 0.1)
        if ready:
            line = proc.stdout.readline()
            seen += line
            if line.startswith('listening on '):
                return int(line.rsplit(':', 1)[1])
            if not line and proc.poll() is not None:
                break
    raise AssertionError(f'the PLC program did not start listening within {timeout_s} s: {seen!r}')
