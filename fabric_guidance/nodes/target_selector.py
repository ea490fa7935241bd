"""target_selector: which target the wearer should look at, and when it counts as found.

Targets are named points in the immersive frame: fixed ones from the parameters
target_names / target_positions, and live ones (live_targets) that follow a
geometry_msgs/PoseStamped on live_targets/<name>, mapped from the micromanipulator's frame
as position * live_scale + live_offset.

The task runs through `sequence` (empty: target_names in order). The active target changes
by the `active_target` parameter (any known name, '' for none), the services next_target and
reset_sequence (std_srvs/Trigger) and, with auto_advance, when the wearer finds it: the gaze
stays within acceptance_deg of the target for dwell_s (core.task.AcceptanceTracker). After the
last target of the sequence no target is active (''). With autostart false no target is active
at start-up; with return_to_front the next target waits until the gaze is back at the front.
The parameter always shows the active target. A study session places its target by setting
target_positions at run time (same count) with active_target, and turns found_by_dwell off: the
wearer's key press, judged by the session, finds it then.

Published: target (geometry_msgs/PointStamped, latched; on every activation target, then
active_target, then target again, so that whoever sees the new name gets a position after
it; 10 Hz while a target is active), active_target (std_msgs/String, latched), target_found
(std_msgs/String), target_markers (visualization_msgs/MarkerArray), /diagnostics.
Subscribed: gaze (geometry_msgs/PoseStamped, x axis along the gaze ray), live_targets/<name>.
"""
from __future__ import annotations

import math
import sys

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PointStamped, PoseStamped
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import String
from std_srvs.srv import Trigger
from visualization_msgs.msg import Marker, MarkerArray

from fabric_guidance.core.geometry import GeometryError, ray_direction, target_direction
from fabric_guidance.core.task import AcceptanceTracker
from fabric_guidance.interface import LIVE_TARGETS, NEXT_TARGET, RESET_SEQUENCE, TARGET_MARKERS
from fabric_guidance.interface import (ACTIVE_TARGET, DIAGNOSTICS, GAZE, IMMERSIVE_FRAME, TARGET,
                                       TARGET_FOUND)
from fabric_guidance.nodes.diagnostics import publish_diagnostics, status
from fabric_guidance.nodes.log_throttle import LogThrottle
from fabric_guidance.nodes.parameters import declare
from fabric_guidance.nodes.qos import EVENT_QOS, LATCHED_QOS, SENSOR_QOS
from fabric_guidance.nodes.spin import run

#: The active target's position is republished this often (live targets move) [Hz].
REPUBLISH_HZ = 10.0
#: Diagnostics every this many republish ticks (1 s).
DIAGNOSTICS_TICKS = 10
#: Marker spheres: 0.1 m diameter, the active one red, the others magenta (the paper's scene).
MARKER_DIAMETER_M = 0.1
#: The wearer's front, where the speed protocol's wearer returns between targets: +x (REP 103).
FRONT = (1.0, 0.0, 0.0)
MARKER_NS_FIXED, MARKER_NS_LIVE = 'targets', 'live_targets'
ACTIVE_RGBA = (1.0, 0.0, 0.0, 1.0)
INACTIVE_RGBA = (1.0, 0.0, 1.0, 1.0)

#: The paper's four targets (config/params/guidance.yaml), the defaults when no parameter file is given.
DEFAULT_NAMES = ['front_left', 'up_right', 'down_left', 'down_right']
DEFAULT_POSITIONS = [1.5321, 1.2856, 1.2000, 1.5827, -1.1499, 1.6158,
                     1.7033, 0.7943, 0.5160, 1.2660, -1.5088, 0.8527]


class TargetSelector(Node):

    def __init__(self):
        super().__init__('target_selector')
        self.frame_id = declare(self, 'frame_id', IMMERSIVE_FRAME, 'frame of the target positions',
                                read_only=True)
        names = declare(self, 'target_names', DEFAULT_NAMES, 'names of the fixed targets', read_only=True)
        positions = declare(self, 'target_positions', DEFAULT_POSITIONS,
                            'x, y, z of each fixed target in the immersive frame, in target_names order; '
                            'settable at run time with the same number of values (a study session places '
                            'its target)', 'm')
        sequence = declare(self, 'sequence', [''], 'task order by name; empty: target_names in order',
                           read_only=True)
        live = declare(self, 'live_targets', [''], 'names of live targets, each on live_targets/<name>',
                       read_only=True)
        self.live_scale = declare(self, 'live_scale', 1000.0, 'micro to macro scale of live targets', '-',
                                  1e-6, 1e6, read_only=True)
        live_offset = declare(self, 'live_offset', [0.0, 0.0, 1.2], 'added to live targets after scaling', 'm',
                              read_only=True)
        # The one transform this node knows is live_scale and live_offset, from live_frame_id; a
        # pose already in frame_id is taken as it is. Any other frame would be mis-placed without
        # a word: refused (tf2 cannot express the 1000x scale, and the stack's frame is fixed).
        self.live_frame_id = declare(self, 'live_frame_id', 'microscope',
                                     'frame of live targets that live_scale and live_offset map into frame_id; '
                                     'a live pose in any other frame than these two is refused', read_only=True)
        active = declare(self, 'active_target', '', "name of the target to guide to now ('' = none)")
        acceptance_deg = declare(self, 'acceptance_deg', 5.0, 'found when the gaze stays this close', 'deg',
                                 0.01, 180.0)
        dwell_s = declare(self, 'dwell_s', 0.3, 'how long the gaze must stay within acceptance_deg', 's',
                          0.0, 60.0)
        self.auto_advance = declare(self, 'auto_advance', True,
                                    'go on to the next target of the sequence when one is found')
        autostart = declare(self, 'autostart', True, 'activate the first target of the sequence at start-up; '
                            'false: no target until next_target (or active_target) starts the task',
                            read_only=True)
        self.found_by_dwell = declare(self, 'found_by_dwell', True,
                                      "a target is found when the gaze dwells on it; false: never here "
                                      "(a study session judges the wearer's key press instead)")
        self.return_to_front = declare(self, 'return_to_front', False,
                                       "the paper's speed protocol: after a target is found no target is "
                                       'active until the gaze is back at the front (+x), then the next one')

        # Start-up validation: a clear message naming the parameter, and no node.
        names = [] if names is None else list(names)
        positions = [] if positions is None else list(positions)
        if '' in names:
            raise ValueError("parameter 'target_names': names must not be empty strings")
        if len(set(names)) != len(names):
            raise ValueError(f"parameter 'target_names': duplicate names in {names}")
        if len(positions) != 3 * len(names):
            raise ValueError(f"parameter 'target_positions': needs 3 values (x, y, z) per name of "
                             f"'target_names', i.e. {3 * len(names)}, got {len(positions)}")
        if not all(math.isfinite(v) for v in positions):
            raise ValueError(f"parameter 'target_positions': values must be finite, got {positions}")
        live_names = [n for n in (live or []) if n != '']
        if len(set(live_names)) != len(live_names) or set(live_names) & set(names):
            raise ValueError(f"parameter 'live_targets': names must be unique and differ from "
                             f"'target_names', got {live_names}")
        for name in live_names:
            if not _valid_topic_token(name):
                raise ValueError(f"parameter 'live_targets': {name!r} is not a valid topic name part "
                                 '(letters, digits and _, not starting with a digit)')
        live_offset = [] if live_offset is None else list(live_offset)
        if len(live_offset) != 3 or not all(math.isfinite(v) for v in live_offset):
            raise ValueError(f"parameter 'live_offset': needs 3 finite values (x, y, z), got {live_offset}")
        self.live_offset = tuple(live_offset)
        # Positions by name (None: a live target not heard from yet); dicts keep the order.
        self.positions: dict[str, tuple[float, float, float] | None] = {
            name: tuple(positions[3 * i:3 * i + 3]) for i, name in enumerate(names)}
        self.live_names = frozenset(live_names)
        self.positions.update({name: None for name in live_names})
        if not self.positions:
            raise ValueError("parameters 'target_names' and 'live_targets': no target at all")
        self.sequence = [n for n in (sequence or []) if n != ''] or list(names)
        unknown = [n for n in self.sequence if n not in self.positions]
        if unknown:
            raise ValueError(f"parameter 'sequence': unknown targets {unknown}; known: {list(self.positions)}")
        if active and active not in self.positions:
            raise ValueError(f"parameter 'active_target': unknown target {active!r}; known: {list(self.positions)}")
        self.tracker = AcceptanceTracker(acceptance_deg, dwell_s)
        self.front_tracker = AcceptanceTracker(acceptance_deg, dwell_s)
        self.after_front: int | None = None   # sequence index to activate once the gaze is at the front
        # Dwell time on a steady clock (a system clock step must not find a target), simulated
        # time when the graph runs on it.
        sim_time = self.get_parameter('use_sim_time').value
        self.dwell_clock = self.get_clock() if sim_time else Clock(clock_type=ClockType.STEADY_TIME)

        # State (all callbacks run on one executor thread).
        self.active = ''
        self.cursor = -1           # index in sequence of the target last activated from it
        self.found_current = False  # the active target was found (no second event for it)
        self.counts = {'gaze': 0, 'invalid_gaze': 0, 'found': 0, 'invalid_live': 0, 'live_wrong_frame': 0,
                       'internal_error': 0}
        self._frame_log = LogThrottle(5.0)
        self._setting_parameter = False
        self._ticks = 0

        self.target_pub = self.create_publisher(PointStamped, TARGET, LATCHED_QOS)
        self.active_pub = self.create_publisher(String, ACTIVE_TARGET, LATCHED_QOS)
        self.found_pub = self.create_publisher(String, TARGET_FOUND, EVENT_QOS)
        self.marker_pub = self.create_publisher(MarkerArray, TARGET_MARKERS, LATCHED_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS, 10)
        self.create_subscription(PoseStamped, GAZE, self.on_gaze, SENSOR_QOS)
        for name in sorted(self.live_names):
            self.create_subscription(PoseStamped, f'{LIVE_TARGETS}/{name}',
                                     lambda msg, name=name: self.on_live_target(name, msg), SENSOR_QOS)
        self.create_service(Trigger, NEXT_TARGET, self.on_next_target)
        self.create_service(Trigger, RESET_SEQUENCE, self.on_reset_sequence)
        self.add_on_set_parameters_callback(self.validate_parameters)
        self.add_post_set_parameters_callback(self.apply_parameters)
        self.create_timer(1.0 / REPUBLISH_HZ, self.on_tick)

        if active:
            self.activate(active)
        elif autostart:
            self.activate_index(0)
        else:
            self.activate('')   # the operator starts the sequence with next_target
        self.get_logger().info(f'{len(names)} fixed and {len(live_names)} live targets, sequence {self.sequence}, '
                               f'active {self.active!r}')

    # --- activation -----------------------------------------------------------------------

    def activate_index(self, index: int) -> None:
        """Activate sequence[index]; past the end, no target."""
        self.cursor = min(index, len(self.sequence))
        self.activate(self.sequence[self.cursor] if self.cursor < len(self.sequence) else '')

    def activate(self, name: str) -> None:
        """Make `name` the active target ('' = none) and announce it: target, name, target."""
        # A target of the sequence chosen by name moves the cursor there (unless the cursor is on
        # it already: a sequence may repeat a name); '' or a target off the sequence leaves it.
        if name:
            self.after_front = None   # any target chosen ends a wait for the front
        if name in self.sequence and not (0 <= self.cursor < len(self.sequence) and self.sequence[self.cursor] == name):
            self.cursor = self.sequence.index(name)
        self.active = name
        self.found_current = False
        self.tracker.reset()
        self.publish_target()
        self.active_pub.publish(String(data=name))
        self.publish_target()
        self.publish_markers()
        if self.get_parameter('active_target').value != name:
            self._setting_parameter = True
            try:
                self.set_parameters([Parameter('active_target', value=name)])
            finally:
                self._setting_parameter = False
        self.get_logger().info(f'active target: {name!r}' if name else 'no active target')

    def publish_target(self) -> None:
        position = self.positions.get(self.active) if self.active else None
        if position is None:
            return
        msg = PointStamped()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = self.frame_id
        msg.point.x, msg.point.y, msg.point.z = position
        self.target_pub.publish(msg)

    def publish_markers(self) -> None:
        stamp = self.get_clock().now().to_msg()
        markers = MarkerArray()
        for i, (name, position) in enumerate(self.positions.items()):
            m = Marker()
            m.header.stamp = stamp
            m.header.frame_id = self.frame_id
            # The namespace tells fixed targets from live ones (RViz lists them apart; the
            # headset display draws live objects as such).
            m.ns = MARKER_NS_LIVE if name in self.live_names else MARKER_NS_FIXED
            m.id = i
            m.type = Marker.SPHERE
            if position is None:
                m.action = Marker.DELETE
            else:
                m.action = Marker.ADD
                m.pose.position.x, m.pose.position.y, m.pose.position.z = position
                m.pose.orientation.w = 1.0
                m.scale.x = m.scale.y = m.scale.z = MARKER_DIAMETER_M
                m.color.r, m.color.g, m.color.b, m.color.a = ACTIVE_RGBA if name == self.active else INACTIVE_RGBA
            m.text = name
            markers.markers.append(m)
        self.marker_pub.publish(markers)

    # --- callbacks ------------------------------------------------------------------------

    def on_gaze(self, msg: PoseStamped) -> None:
        self.counts['gaze'] += 1
        try:
            if self.after_front is not None:
                o = msg.pose.orientation
                now = self.dwell_clock.now().nanoseconds * 1e-9
                if self.front_tracker.update(ray_direction((o.x, o.y, o.z, o.w)), FRONT, now):
                    index, self.after_front = self.after_front, None
                    self.activate_index(index)
                return
            target = self.positions.get(self.active) if self.active else None
            if target is None or self.found_current or not self.found_by_dwell:
                return
            p, o = msg.pose.position, msg.pose.orientation
            origin = (p.x, p.y, p.z)
            gaze = ray_direction((o.x, o.y, o.z, o.w))
            to_target = target_direction(origin, target)
            now = self.dwell_clock.now().nanoseconds * 1e-9
            if not self.tracker.update(gaze, to_target, now):
                return
        except GeometryError as exc:
            self.counts['invalid_gaze'] += 1
            self.get_logger().warn(f'invalid gaze ignored: {exc}', throttle_duration_sec=5.0)
            return
        except Exception as exc:  # noqa: BLE001 - a bad sample must not end the node
            self.counts['internal_error'] += 1
            self.get_logger().error(f'gaze sample dropped by an internal error: {exc!r}', throttle_duration_sec=5.0)
            return
        name = self.active
        self.found_current = True
        self.counts['found'] += 1
        self.found_pub.publish(String(data=name))
        self.get_logger().info(f'target found: {name!r}')
        if self.auto_advance and self.return_to_front and self._next_index() < len(self.sequence):
            self.after_front = self._next_index()
            self.front_tracker.reset()
            self.activate('')
        elif self.auto_advance:
            self.activate_index(self._next_index())

    def on_live_target(self, name: str, msg: PoseStamped) -> None:
        p = msg.pose.position
        frame = msg.header.frame_id
        if frame == self.live_frame_id:
            scale, offset = self.live_scale, self.live_offset
            position = (p.x * scale + offset[0], p.y * scale + offset[1], p.z * scale + offset[2])
        elif frame == self.frame_id:
            position = (p.x, p.y, p.z)
        else:
            self.counts['live_wrong_frame'] += 1
            if self._frame_log.due(name):
                self.get_logger().warn(
                    f'live target {name!r}: pose in frame {frame!r} refused: no transform from it is known '
                    f"(parameter 'live_frame_id' {self.live_frame_id!r} is mapped by live_scale and live_offset, "
                    f"'frame_id' {self.frame_id!r} taken as is)")
            return
        if not all(math.isfinite(c) for c in position):
            self.counts['invalid_live'] += 1
            self.get_logger().warn(f'live target {name!r}: non-finite position ignored', throttle_duration_sec=5.0)
            return
        first = self.positions[name] is None
        self.positions[name] = position
        if name == self.active and first:
            self.publish_target()  # the first position of an active live target: do not wait for the tick
            self.publish_markers()

    def on_tick(self) -> None:
        self.publish_target()
        if self.live_names:
            self.publish_markers()
        self._ticks += 1
        if self._ticks % DIAGNOSTICS_TICKS == 0:
            self.publish_diagnostics()

    def on_next_target(self, request, response):
        if self.cursor >= len(self.sequence):
            response.success = False
            response.message = 'the sequence is done; call reset_sequence to start it again'
            return response
        self.activate_index(self._next_index())
        response.success = True
        response.message = f'active target: {self.active!r}' if self.active else 'sequence done: no active target'
        return response

    def on_reset_sequence(self, request, response):
        self.activate_index(0)
        response.success = True
        response.message = f'active target: {self.active!r}'
        return response

    def validate_parameters(self, params) -> SetParametersResult:
        acceptance_deg, dwell_s = self.tracker.acceptance_deg, self.tracker.dwell_s
        for param in params:
            if param.name == 'active_target':
                if param.value != '' and param.value not in self.positions:
                    return SetParametersResult(successful=False, reason=(
                        f'unknown target {param.value!r}; known: {list(self.positions)} or \'\' for none'))
            elif param.name == 'target_positions':
                values = list(param.value or [])
                fixed = [n for n in self.positions if n not in self.live_names]
                if len(values) != 3 * len(fixed) or not all(math.isfinite(v) for v in values):
                    return SetParametersResult(successful=False, reason=(
                        f'target_positions: needs {3 * len(fixed)} finite values (x, y, z of {fixed}), '
                        f'got {values}'))
            elif param.name == 'acceptance_deg':
                acceptance_deg = param.value
            elif param.name == 'dwell_s':
                dwell_s = param.value
        try:
            AcceptanceTracker(acceptance_deg, dwell_s)
        except ValueError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def apply_parameters(self, params) -> None:
        # New positions first: a session sets them and the target to activate in one call.
        params = sorted(params, key=lambda p: p.name != 'target_positions')
        for param in params:
            if param.name == 'target_positions':
                self.move_fixed(list(param.value))
            elif param.name == 'found_by_dwell':
                self.found_by_dwell = param.value
                self.tracker.reset()
            elif param.name == 'active_target' and not self._setting_parameter:
                self.activate(param.value)
            elif param.name in ('acceptance_deg', 'dwell_s'):
                self.tracker = AcceptanceTracker(self.get_parameter('acceptance_deg').value,
                                                 self.get_parameter('dwell_s').value)
                self.front_tracker = AcceptanceTracker(self.get_parameter('acceptance_deg').value,
                                                       self.get_parameter('dwell_s').value)
            elif param.name == 'auto_advance':
                self.auto_advance = param.value

    def move_fixed(self, values: list[float]) -> None:
        """The fixed targets at new positions (validated); the active one is announced again."""
        fixed = [n for n in self.positions if n not in self.live_names]
        for i, name in enumerate(fixed):
            self.positions[name] = tuple(values[3 * i:3 * i + 3])
        self.publish_markers()
        if self.active in fixed:
            self.tracker.reset()
            self.publish_target()

    # --- helpers --------------------------------------------------------------------------

    def _next_index(self) -> int:
        return self.cursor + 1

    def publish_diagnostics(self) -> None:
        waiting = bool(self.active) and self.positions.get(self.active) is None
        level = DiagnosticStatus.WARN if waiting else DiagnosticStatus.OK
        if waiting:
            message = f'live target {self.active!r} has no position yet'
        elif self.active:
            message = f'guiding to {self.active!r}'
        else:
            message = 'no active target'
        position = f'{self.cursor + 1} of {len(self.sequence)}' if 0 <= self.cursor < len(self.sequence) else '-'
        values = {'active_target': self.active, 'sequence_position': position, **self.counts}
        publish_diagnostics(self, self.diag_pub, [status(self, 'task', level, message, values)])

    def safe_shutdown(self) -> None:
        """On SIGINT/SIGTERM: announce no target, so that the controller stops guiding and vents
        instead of guiding on to a target nobody supervises."""
        self.active_pub.publish(String(data=''))
        # Reliable: wait (briefly) until the subscribers have it, the process ends right after.
        self.active_pub.wait_for_all_acked(Duration(seconds=1.0))
        self.get_logger().info('no active target on shutdown (the controller vents)')


def _valid_topic_token(name: str) -> bool:
    return name.replace('_', 'a').isalnum() and name.isascii() and not name[0].isdigit()


def main(args=None):
    return run(lambda: TargetSelector(), args)


if __name__ == '__main__':
    sys.exit(main())
