"""What the soak run reads off the graph (gaze, control steps, commands, targets, diagnostics),
with nothing kept that grows with the run's length."""
from __future__ import annotations

from collections import Counter
import threading
import time

from ..graph.process_graph import Probe
from .soak_latency import LatencyMatcher

#: Statuses of the nodes' /diagnostics that are routine in a guided session (between targets).
ROUTINE = ('no active target',)


def realtime_offset_ns() -> int:
    """CLOCK_REALTIME minus CLOCK_MONOTONIC now: ROS stamps and DDS source times are realtime,
    the register log monotonic (taken at each use, so that a stepped system clock is followed)."""
    return time.time_ns() - time.monotonic_ns()


class SoakWatch:
    """What the run reads off the graph, with nothing kept that grows with the run's length."""

    def __init__(self, probe: Probe, matcher: LatencyMatcher):
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseStamped
        from std_msgs.msg import Float64MultiArray, String

        from .. import interface
        from ..bag.controller_io import DIRECTION, STEP
        from ..core import ray_direction
        from ..nodes import qos
        self.matcher = matcher
        self.lock = threading.Lock()
        self.active = None               # the latest active_target ('' = none); None before any
        self.active_since = time.monotonic()
        self.target: tuple[str, float] | None = None   # the latest target activated, and when
        self.found: list[float] = []     # time to each target found since the last take [s]
        self.status: dict[str, tuple[int, str, dict]] = {}   # diagnostics name -> level, message, values
        self.warnings: Counter = Counter()
        self.heard = Counter()
        self._ray, self._direction, self._step = ray_direction, DIRECTION, STEP
        node = probe.node
        node.create_subscription(PoseStamped, interface.GAZE, self.on_gaze, qos.SENSOR_QOS)
        # Deep readers: steps_unseen and the command pairing count what the graph lost, not what a
        # stall of this process would drop from a reader of depth 10 (qos.deep).
        node.create_subscription(Float64MultiArray, interface.CONTROLLER_INPUT, self.on_input,
                                 qos.deep(qos.COMMAND_QOS))
        node.create_subscription(Float64MultiArray, interface.PRESSURE_COMMAND, self.on_command,
                                 qos.deep(qos.COMMAND_QOS))
        node.create_subscription(String, interface.ACTIVE_TARGET, self.on_active, qos.LATCHED_ALL_QOS)
        node.create_subscription(String, interface.TARGET_FOUND, self.on_found, qos.EVENT_QOS)
        node.create_subscription(DiagnosticArray, interface.DIAGNOSTICS, self.on_diagnostics, 10)

    def on_gaze(self, msg) -> None:
        self.heard['gaze'] += 1
        o = msg.pose.orientation
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        # The controller's direction of this sample, computed as it computes it: bit for bit.
        key = tuple(self._ray([o.x, o.y, o.z, o.w]).tolist())
        self.matcher.gaze(key, stamp_ns - realtime_offset_ns())

    def on_input(self, msg, info) -> None:
        self.heard['controller_input'] += 1
        d = msg.data
        key = tuple(float(x) for x in d[self._direction])
        self.matcher.step(info['source_timestamp'] - realtime_offset_ns(), int(d[self._step]), key)

    def on_command(self, msg, info) -> None:
        self.heard['pressure_command'] += 1
        self.matcher.command(info['source_timestamp'] - realtime_offset_ns(), msg.data)

    def on_active(self, msg) -> None:
        with self.lock:
            if msg.data != self.active:
                self.active, self.active_since = msg.data, time.monotonic()
                if msg.data:
                    self.target = (msg.data, self.active_since)

    def on_found(self, msg) -> None:
        # The next active_target ('' while the wearer turns back to the front) may arrive first.
        with self.lock:
            if self.target is not None and msg.data == self.target[0]:
                self.found.append(time.monotonic() - self.target[1])
                self.target = None

    def on_diagnostics(self, msg) -> None:
        with self.lock:
            for st in msg.status:
                level = st.level if isinstance(st.level, int) else int.from_bytes(st.level, 'little')
                self.status[st.name] = (level, st.message, {kv.key: kv.value for kv in st.values})
                if level > 0 and not any(r in st.message for r in ROUTINE):
                    self.warnings[f'{st.name}: {st.message}'] += 1

    def value(self, name_prefix: str, key: str, default=None):
        with self.lock:
            for name, (_, _, values) in self.status.items():
                if name.startswith(name_prefix) and key in values:
                    return values[key]
        return default

    def take(self) -> tuple[list[float], Counter]:
        with self.lock:
            found, self.found = self.found, []
            warnings, self.warnings = self.warnings, Counter()
        return found, warnings
