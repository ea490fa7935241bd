"""The package's graph and the floor's, as separate processes on a DDS domain of their own,
each ending in a mock PLC that logs when every write landed; a sender drives them with the
sweep and the two ends' clocks give the latency of each sample.
"""
from __future__ import annotations

import os
from pathlib import Path
import socket
import subprocess
import sys
import time
from typing import Callable

from ..core import Calibration
from ..plc import RegisterMap
from ..graph.process_graph import CONFIG, ROOT, Graph, Probe, free_port, wait_until
from . import floor
from .latency import Sender, WriteLog, landings, percentiles_ms
from .gaze_sweep import Sweep
from .stages import StageCounters

FILES = ('params/guidance.yaml', 'params/sim.yaml')
SIM_CALIBRATION = CONFIG / 'calibrations' / 'sim-wearer.yaml'
#: Package nodes whose memory is reported.
NODES = ('gaze_bridge', 'pressure_controller', 'plc_output', 'mock_plc')
#: A sample that has not landed this long after the last one was sent is not applied.
SETTLE_S = 0.25


def make_sweep() -> Sweep:
    return Sweep(Calibration.load(SIM_CALIBRATION), RegisterMap.load(CONFIG / 'hardware/plc_register_map.yaml'))


def _status(pid: int, key: str) -> int | None:
    """The first number of /proc/PID/status's line `key:` (None where there is no /proc)."""
    try:
        for line in Path(f'/proc/{pid}/status').read_text().splitlines():
            if line.startswith(key + ':'):
                return int(line.split()[1])
    except OSError:
        pass
    return None


def rss_mb(pid: int) -> float | None:
    """Resident memory of a process [MB], from /proc (None where there is no /proc)."""
    kb = _status(pid, 'VmRSS')
    return None if kb is None else kb / 1024.0


def threads(pid: int) -> int | None:
    """Threads of a process, from /proc."""
    return _status(pid, 'Threads')


def fds(pid: int) -> int | None:
    """Open file descriptors of a process (/proc/PID/fd)."""
    try:
        return len(os.listdir(f'/proc/{pid}/fd'))
    except OSError:
        return None


def _stat(pid: int) -> list[str] | None:
    """The fields of /proc/PID/stat after the command name (which may hold spaces and ')'):
    [0] the state letter, [11] and [12] user and system time in ticks (None: no such process)."""
    try:
        return Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    except OSError:
        return None


def state(pid: int) -> str | None:
    """A process's state letter (R running, S sleeping, T stopped, Z zombie), from /proc."""
    fields = _stat(pid)
    return None if fields is None else fields[0]


def cpu_s(pid: int) -> float | None:
    """CPU time (user + system) a process has used [s], from /proc."""
    fields = _stat(pid)
    return None if fields is None else (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def combine(blocks: list[dict], rate_hz: float) -> dict:
    """Figures over blocks of one chain at one rate: p50, p99, max [ms] of the applied samples,
    sent, applied, and the CPU per sample sent of each process [us]."""
    latencies = [x for b in blocks for x in b['latencies_ns']]
    out = percentiles_ms(latencies)
    out.update(sent=sum(b['sent'] for b in blocks), applied=len(latencies), rate_hz=rate_hz)
    samples = sum(b['samples'] for b in blocks)
    out['cpu_us_per_sample'] = {k: round(1e6 * sum(b['cpu_s'].get(k, 0.0) for b in blocks) / samples, 1)
                                for k in blocks[0]['cpu_s']}
    return out


class Rig:
    """A running chain: its sender, its mock PLC's write log, and how a sample is encoded."""

    def __init__(self, graph: Graph, sweep: Sweep, gaze_port: int, log: WriteLog,
                 encode: Callable[[int, float], bytes], say: Callable[[str], None],
                 explain: Callable[[], str] | None = None):
        self.graph, self.sweep, self.log, self.encode, self.say = graph, sweep, log, encode, say
        self.sender = Sender(gaze_port)
        self.explain = explain   # what the chain's nodes last said, for an error

    def _why(self) -> str:
        return f'; the nodes said: {self.explain()}' if self.explain else ''

    def _send(self, n: int, rate_hz: float) -> range:
        first = len(self.sender.sent_ns)
        samples = range(first, first + n)
        self.sender.send([self.encode(i, rate_hz) for i in samples], rate_hz, first)
        return samples

    def _landed(self, since_ns: int) -> dict[int, int]:
        sw = self.sweep
        return landings(self.sender.sent_ns, self.log.writes(since_ns), sw.register, sw.level_of, sw.levels)

    def prime(self, timeout_s: float = 60.0) -> None:
        """Send at 30 Hz until a sample lands: every process is up and discovered."""
        deadline = time.monotonic() + timeout_s
        while True:
            samples = self._send(6, 30.0)
            start_ns = self.sender.sent_ns[samples[0]]
            # Until the prime's own deadline: on a loaded machine the mock PLC may take longer
            # than the drain's usual 10 s to start writing its log at all.
            self.log.wait_drained(time.monotonic_ns() + int(0.1e9), max(10.0, deadline - time.monotonic()))
            if any(i in samples for i in self._landed(start_ns)):
                return
            self._check_alive()
            if time.monotonic() > deadline:
                raise RuntimeError(f'no sample reached the mock PLC within {timeout_s:.0f} s{self._why()} '
                                   f'(logs in {self.graph.log_dir})')

    def _check_alive(self) -> None:
        for name, proc in self.graph.processes.items():
            if proc.poll() is not None:
                raise RuntimeError(f'{name} exited with {proc.returncode}; its log: {self.graph.log_dir}')

    def block(self, rate_hz: float, n: int, warmup_s: float) -> dict:
        """n samples at rate_hz after warmup_s of the same stream: their latencies [ns] (the
        applied ones), how many were sent, and the CPU each process spent per sample sent."""
        warm = int(round(warmup_s * rate_hz))
        cpu0 = {name: cpu_s(p.pid) for name, p in self.graph.processes.items()}
        t0 = time.monotonic()
        samples = self._send(warm + n, rate_hz)
        cpu1 = {name: cpu_s(p.pid) for name, p in self.graph.processes.items()}
        start_ns = self.sender.sent_ns[samples[0]]
        self.log.wait_drained(time.monotonic_ns() + int(SETTLE_S * 1e9))
        self._check_alive()
        landed, sent = self._landed(start_ns), self.sender.sent_ns
        return {'latencies_ns': [landed[i] - sent[i] for i in samples[warm:] if i in landed], 'sent': n,
                'cpu_s': {k: cpu1[k] - cpu0[k] for k in cpu0 if cpu0[k] is not None and cpu1[k] is not None},
                'samples': len(samples), 'landed_all': sum(1 for i in samples if i in landed),
                'window': (t0, time.monotonic())}

    def measure(self, rate_hz: float, n: int, warmup_s: float) -> dict:
        """One block's figures (see combine)."""
        return combine([self.block(rate_hz, n, warmup_s)], rate_hz)

    def close(self) -> None:
        self.sender.close()


class PackageGraph:
    """gaze_bridge, pressure_controller, plc_output and mock_plc with the package's parameter
    files; the bench publishes the target (as target_selector would) and sends the gaze."""

    def __init__(self, work: Path, say: Callable[[str], None], overrides: dict | None = None):
        self.work, self.say = Path(work), say
        self.sweep = make_sweep()
        self.graph = Graph(self.work / 'package_logs')
        self.plc_port, self.gaze_port = free_port(), free_port(socket.SOCK_DGRAM)
        self.log = WriteLog(self.work / 'package_writes.log')
        o = overrides or {}
        g = self.graph
        g.start('mock_plc', FILES, port=self.plc_port, write_log_file=str(self.log.path), **o.get('mock_plc', {}))
        g.start('plc_output', FILES, plc_port=self.plc_port, **o.get('plc_output', {}))
        g.start('gaze_bridge', FILES, port=self.gaze_port, **o.get('gaze_bridge', {}))
        # The sweep circles the target at one error and never comes closer: a person doing that
        # is vented by the no-progress watch after stall_timeout_s, whatever gaps come between
        # (it took every sample after the first 10 s). The bench measures the chain, so the
        # watch is off, as in `study --simulated`; the rest of the parameters are the package's.
        g.start('pressure_controller', FILES, calibration_file=str(SIM_CALIBRATION), condition=2,
                follow_moving_target=True, calibration_dir=str(self.work / 'calibrations'),
                target_publisher='bench_target',   # this bench's probe plays target_selector
                **{'stall_timeout_s': 0.0, **o.get('pressure_controller', {})})
        self.probe = Probe(g.domain_id, 'bench_target')
        self.stages = StageCounters(self.probe)
        self._publish_target()
        self.rig = Rig(g, self.sweep, self.gaze_port, self.log, self.sweep.datagram, say,
                       explain=self.stages.latest_messages)

    def _publish_target(self) -> None:
        from geometry_msgs.msg import PointStamped
        from std_msgs.msg import String
        from .. import interface
        from ..nodes import qos
        node = self.probe.node
        name_pub = node.create_publisher(String, interface.ACTIVE_TARGET, qos.LATCHED_QOS)
        point_pub = node.create_publisher(PointStamped, interface.TARGET, qos.LATCHED_QOS)
        name_pub.publish(String(data='bench'))
        msg = PointStamped()
        msg.header.frame_id = interface.IMMERSIVE_FRAME
        msg.point.x, msg.point.y, msg.point.z = self.sweep.target
        # Republished as target_selector does: the controller takes a position only after the name.
        node.create_timer(0.1, lambda: point_pub.publish(msg))

    def rss_mb(self) -> dict:
        return {name: rss_mb(self.graph.processes[name].pid) for name in NODES}

    def record(self, seconds: float, rate_hz: float) -> Path:
        """Record `seconds` of the sweep with bag_recorder; the bag (replay() reruns it)."""
        bag = self.work / 'session'
        self.graph.start('bag_recorder', FILES, output=str(bag),
                         topics=['controller_input', 'controller_parameters', 'pressure_command'])
        wait_until(lambda: 'recording' in self.graph.log('bag_recorder'), 30.0, what='bag_recorder to start')
        # Record only once the recorder hears the controller (discovery is pairwise; the
        # controller builds controller_input only for a matched subscriber): wait until it has
        # written what the controller publishes while no gaze comes (vented steps: the replay's
        # state is known from the first one).
        from diagnostic_msgs.msg import DiagnosticArray
        from ..bag.recorder_status import hears, recorded_counts
        from ..interface import DIAGNOSTICS
        counts = {}
        self.probe.subscribe(DiagnosticArray, DIAGNOSTICS, 10,
                             lambda msg: counts.update(recorded_counts(msg) or {}))
        wait_until(lambda: hears(counts, 'controller_input', 'controller_parameters', 'pressure_command'), 30.0,
                   what='bag_recorder to hear the controller')
        self.rig.prime()
        self.rig.measure(rate_hz, int(seconds * rate_hz), 0.0)
        self.graph.stop('bag_recorder')
        return bag

    def close(self) -> None:
        self.rig.close()
        self.probe.close()
        self.graph.stop_all()


class FloorGraph:
    """The bare chain of bench/floor.py (udp, relay, modbus) into the same mock PLC."""

    def __init__(self, work: Path, say: Callable[[str], None]):
        self.work, self.say = Path(work), say
        self.sweep = make_sweep()
        self.graph = Graph(self.work / 'floor_logs')
        self.plc_port, self.gaze_port = free_port(), free_port(socket.SOCK_DGRAM)
        self.log = WriteLog(self.work / 'floor_writes.log')
        g = self.graph
        g.start('mock_plc', FILES, port=self.plc_port, write_log_file=str(self.log.path))
        self._start('floor_modbus', 'modbus', '--plc-port', str(self.plc_port))
        self._start('floor_relay', 'relay')
        self._start('floor_udp', 'udp', '--port', str(self.gaze_port))
        self.rig = Rig(g, self.sweep, self.gaze_port, self.log,
                       lambda i, _rate: floor.encode(i, self.sweep.count(i)), say)

    def _start(self, name: str, *args: str) -> None:
        g = self.graph
        log = open(g.log_dir / f'{name}.log', 'w')
        g.processes[name] = subprocess.Popen([sys.executable, '-m', 'fabric_guidance.bench.floor', *args],
                                             stdout=log, stderr=subprocess.STDOUT, env=g.env, cwd=ROOT)

    def close(self) -> None:
        self.rig.close()
        self.graph.stop_all()


def replay(bag: Path) -> dict:
    """Rerun a recorded session offline in a fresh process, as `fabric-guidance replay --offline`
    runs (in the bench's own process, after the graphs, it measured 4x slower): the replay's
    speed-up over real time and whether it reproduced every command."""
    import json
    run = subprocess.run([sys.executable, '-m', 'fabric_guidance.bench.graphs', str(bag)], capture_output=True,
                         text=True, timeout=300, cwd=ROOT)
    if run.returncode != 0:
        return {'speedup': None, 'reason': ((run.stderr or run.stdout).strip().splitlines() or ['failed'])[-1],
                'exact': False, 'steps': 0, 'compared': 0, 'session_s': 0.0}
    return json.loads(run.stdout)


def _replay_here(bag: Path) -> dict:
    from ..bag import offline
    try:
        rec = offline.load(bag)
    except ValueError as exc:
        return {'speedup': None, 'reason': str(exc), 'exact': False, 'steps': 0, 'compared': 0,
                'session_s': 0.0}
    result = offline.replay(rec)
    return {'speedup': result.speedup, 'exact': result.exact, 'steps': result.steps,
            'compared': result.compared, 'session_s': result.bag_duration_s}


if __name__ == '__main__':
    import json
    print(json.dumps(_replay_here(Path(sys.argv[1]))))
