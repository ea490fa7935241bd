"""`make demo` / `fabric-guidance demo`: the whole simulated graph as separate processes (what
launch/sim.launch.py starts), a short guided session through the targets of
config/guidance.yaml, and a report of what happened, read off the graph's own topics and the
mock PLC's registers.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math
from pathlib import Path
import socket
import sys
import tempfile
import threading
import time

import numpy as np
import yaml

from .core import ChannelMap, condition as condition_of, ray_direction, target_direction
from .core.geometry import DIRECTIONS
from .core.task import angular_error_deg
from .paths import config_path
from .plc import PlcClient, RegisterMap
from .process_graph import Graph, Probe, free_port, wait_until

SIM_CALIBRATION = 'config/calibrations/sim-wearer.yaml'
#: Nodes in start order: the PLC side first so plc_output finds its PLC.
NODES = ('mock_plc', 'plc_output', 'gaze_bridge', 'target_selector', 'pressure_controller', 'wearer_sim')


@dataclass
class TargetRecord:
    name: str
    activated: float                       # time.monotonic()
    found: float | None = None
    final_error_deg: float | None = None
    peak_kpa: np.ndarray = field(default_factory=lambda: np.zeros(len(DIRECTIONS)))


class SessionWatch:
    """What the demo reads off the graph: targets activated and found, gaze, commands."""

    def __init__(self, probe: Probe, channel_map: ChannelMap, layout: str, sequence: list[str], say):
        from geometry_msgs.msg import PointStamped, PoseStamped
        from std_msgs.msg import Float64MultiArray, String

        from .nodes import common
        self.cmap, self.layout, self.say = channel_map, layout, say
        self.sequence = sequence
        self.lock = threading.Lock()
        self.records: list[TargetRecord] = []
        self.gaze = self.origin = self.target = None
        self.finished = threading.Event()
        self.start = time.monotonic()
        self.max_command = 0.0
        self.speech: list[str] = []
        probe.subscribe(PoseStamped, common.GAZE, common.SENSOR_QOS, self.on_gaze)
        probe.subscribe(PointStamped, common.TARGET, common.LATCHED_QOS, self.on_target)
        probe.subscribe(String, common.ACTIVE_TARGET, common.LATCHED_QOS, self.on_active)
        probe.subscribe(String, common.TARGET_FOUND, common.EVENT_QOS, self.on_found)
        probe.subscribe(Float64MultiArray, common.PRESSURE_COMMAND, common.COMMAND_QOS, self.on_command)
        probe.subscribe(Float64MultiArray, common.MEASURED_PRESSURE, common.COMMAND_QOS)
        probe.subscribe(String, common.SPEECH, common.EVENT_QOS, lambda m: self.speech.append(m.data))

    def t(self) -> float:
        return time.monotonic() - self.start

    def on_gaze(self, msg) -> None:
        q, p = msg.pose.orientation, msg.pose.position
        with self.lock:
            self.gaze, self.origin = ray_direction([q.x, q.y, q.z, q.w]), np.array([p.x, p.y, p.z])

    def on_target(self, msg) -> None:
        with self.lock:
            self.target = np.array([msg.point.x, msg.point.y, msg.point.z])

    def on_active(self, msg) -> None:
        with self.lock:
            if msg.data and (not self.records or self.records[-1].name != msg.data):
                self.records.append(TargetRecord(msg.data, time.monotonic()))
                self.say(f'[{self.t():5.1f} s] target {msg.data} active')

    def on_found(self, msg) -> None:
        with self.lock:
            rec = next((r for r in reversed(self.records) if r.name == msg.data), None)
            if rec is None or rec.found is not None:
                return
            rec.found = time.monotonic()
            if self.gaze is not None and self.target is not None:
                rec.final_error_deg = angular_error_deg(self.gaze, target_direction(self.origin, self.target))
            self.say(f'[{self.t():5.1f} s] target {msg.data} found after {rec.found - rec.activated:.2f} s')
            if [r.name for r in self.records if r.found is not None] == self.sequence:
                self.finished.set()

    def on_command(self, msg) -> None:
        data = np.asarray(msg.data, dtype=float)
        if data.shape != (len(self.cmap.channels),):
            return
        with self.lock:
            self.max_command = max(self.max_command, float(data.max(initial=0.0)))
            if self.records and self.records[-1].found is None:
                rec = self.records[-1]
                rec.peak_kpa = np.maximum(rec.peak_kpa, self.cmap.to_directions(data, self.layout))


def run_demo(condition: int = 1, timeout_s: float = 45.0, out_dir: Path | None = None, stream=sys.stdout) -> int:
    def say(line: str = '') -> None:
        print(line, file=stream, flush=True)

    cond = condition_of(condition)
    layout = cond.layout or 'suit'
    cmap = ChannelMap.load(config_path('channel_map.yaml'))
    regmap = RegisterMap.load(config_path('plc_register_map.yaml'), expected_channels=cmap.channels)
    log_dir = Path(out_dir) if out_dir else Path(tempfile.mkdtemp(prefix='fabric-guidance-demo-'))
    plc_port, gaze_port = free_port(), free_port(socket.SOCK_DGRAM)
    graph = Graph(log_dir)
    say(f'fabric_guidance demo: condition {cond.number} ({cond.name}), the simulated graph as {len(NODES)} '
        f'processes on ROS_DOMAIN_ID {graph.domain_id} (localhost only); logs in {log_dir}')
    files = ('guidance.yaml', 'sim.yaml')
    overrides = {
        'mock_plc': dict(port=plc_port),
        'plc_output': dict(plc_port=plc_port),
        'gaze_bridge': dict(port=gaze_port),
        'target_selector': dict(autostart=False),
        'pressure_controller': dict(condition=cond.number, calibration_file=SIM_CALIBRATION,
                                    calibration_dir=str(log_dir / 'calibrations')),
        'wearer_sim': dict(bridge_port=gaze_port, layout=layout),
    }
    probe = None
    code = 1
    try:
        for node in NODES:
            graph.start(node, files, **overrides[node])
        probe = Probe(graph.domain_id, 'demo_watch')
        watch = SessionWatch(probe, cmap, layout, task_sequence(), say)
        deadline = time.monotonic() + timeout_s
        # Start the task, as an operator would, once the whole graph (the watch included) is up:
        # every target's time is then guidance time, not process start-up.
        from std_srvs.srv import Trigger

        from .nodes import common
        wait_until(lambda: all(probe.messages.get(t) for t in (
            common.PRESSURE_COMMAND, common.GAZE, common.MEASURED_PRESSURE, common.ACTIVE_TARGET)),
            timeout_s, what='the graph to come up')
        probe.call(Trigger, 'next_target', Trigger.Request())
        while not watch.finished.is_set() and time.monotonic() < deadline:
            dead = [n for n, p in graph.processes.items() if p.poll() is not None]
            if dead:
                say(f'node(s) {dead} exited early; see their logs in {log_dir}')
                break
            watch.finished.wait(0.1)
        complete = watch.finished.is_set()
        if not complete:
            say(f'the session did not finish within {timeout_s:.0f} s')
        # Shut the lab side down first; the registers must read vented while the mock still runs.
        for node in ('wearer_sim', 'pressure_controller', 'target_selector', 'gaze_bridge', 'plc_output'):
            graph.stop(node)
        with PlcClient(regmap, '127.0.0.1', plc_port, timeout_s=1.0) as client:
            after = client.read_commands_kpa()
        graph.stop('mock_plc')
        code = report(watch, cond, after, say) if complete else 1
    finally:
        if probe is not None:
            probe.close()
        graph.stop_all()
    return code


def task_sequence() -> list[str]:
    """The target order target_selector will run, from the same parameter file."""
    params = yaml.safe_load(config_path('guidance.yaml').read_text())['target_selector']['ros__parameters']
    return [n for n in params.get('sequence') or [] if n] or list(params['target_names'])


def report(watch: SessionWatch, cond, registers_after: np.ndarray, say) -> int:
    say()
    say(f'{"target":<14} {"found":<5} {"time s":>6} {"error deg":>9}   peak kPa ' +
        ' '.join(f'{d:>5}' for d in DIRECTIONS))
    found = 0
    for r in watch.records:
        ok = r.found is not None
        found += ok
        elapsed = (r.found - r.activated) if ok else float('nan')
        err = r.final_error_deg if r.final_error_deg is not None else float('nan')
        say(f'{r.name:<14} {"yes" if ok else "no":<5} {elapsed:6.2f} {err:9.2f}            ' +
            ' '.join(f'{p:5.0f}' for p in r.peak_kpa))
    if watch.speech:
        say(f'speech (condition 4): {"; ".join(watch.speech)}')
    say()
    say(f'{found} of {len(watch.records)} targets found; highest command {watch.max_command:.1f} kPa '
        f'(limit 375 kPa); after shutdown the PLC registers read {registers_after.max():.1f} kPa at most.')
    vented = bool(np.all(registers_after == 0.0))
    if not vented:
        say('WARNING: the suit was not vented at shutdown')
    return 0 if found == len(watch.records) and found > 0 and vented and math.isfinite(watch.max_command) else 1
