"""pressure_controller's control inputs: `target` and `active_target` only from its own
namespace's target_selector (the parameter `target_publisher`), by the graph check plc_output
makes for its commands (command_source.py): while any other node publishes either topic (a bag
played onto the graph, a second node, a stray script) every message of it is refused and the
controller drops its target (it vents). The controller spins in rclpy's events executor, whose
callbacks get no MessageInfo here, so the sender of one message is not known: the topic must be
clean. Once it is, the active_target subscription is made afresh, so that target_selector's
latched value (missed meanwhile) arrives again.

A target position is also refused when it is older than TARGET_MAX_AGE_S by its stamp against
this node's ROS clock (the clock it was stamped on, as for gaze): target_selector republishes the
active target every 0.1 s, stamped, so an older one waited in a frozen process or a queue. A
position without a stamp is aged as fresh (the publisher check still applies).
"""
from __future__ import annotations

from geometry_msgs.msg import PointStamped
from std_msgs.msg import String

from ..interface import ACTIVE_TARGET, TARGET
from .command_source import CommandSource, Publisher, full_name
from .log_throttle import LogThrottle
from .qos import LATCHED_QOS

#: A target position older than this is refused [s] (target_selector republishes every 0.1 s).
TARGET_MAX_AGE_S = 1.0
TYPES = {TARGET: PointStamped, ACTIVE_TARGET: String}


class ControlInputs:
    """Mixin of PressureController: the target and active_target subscriptions, checked."""

    def subscribe_control_inputs(self) -> None:
        self.input_owner = full_name(self.v['target_publisher'], self.get_namespace())
        self.input_subs: dict = {}
        self.input_sources: dict[str, CommandSource] = {}
        self.refused_inputs = 0
        self.last_input_refusal = ''
        self.inputs_missed = False      # a refused active_target: subscribe afresh once the topics are clean
        self.input_log = LogThrottle(5.0)
        for topic in TYPES:
            self._subscribe_input(topic)
            resolved = self.input_subs[topic].topic_name
            self.input_sources[topic] = CommandSource(
                self.input_owner, lambda r=resolved: [Publisher(e.node_name, e.node_namespace, bytes(e.endpoint_gid))
                                                      for e in self.get_publishers_info_by_topic(r)])

    def _subscribe_input(self, topic: str) -> None:
        old = self.input_subs.get(topic)
        if old is not None:
            self.destroy_subscription(old)
        self.input_subs[topic] = self.create_subscription(
            TYPES[topic], topic, lambda msg, t=topic: self.on_control_input(t, msg), LATCHED_QOS)

    def input_refusal(self, topic: str, msg) -> tuple[str, bool]:
        """('', False) when the message may steer the controller, else why not and whether only
        for its age (the topic itself is clean)."""
        source = self.input_sources[topic]
        why = source.check(None)
        if why or topic != TARGET:
            return why, False
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        now_ns = self.get_clock().now().nanoseconds
        age_s = (now_ns - stamp_ns) * 1e-9 if stamp_ns > 0 and now_ns > 0 else 0.0
        if age_s > TARGET_MAX_AGE_S:
            return source.refuse('stale', f'stamped {age_s:.1f} s ago (older than {TARGET_MAX_AGE_S:g} s)'), True
        return '', False

    def on_control_input(self, topic: str, msg) -> None:
        why, stale = self.input_refusal(topic, msg)
        if not why:
            (self.on_active_target if topic == ACTIVE_TARGET else self.on_target)(msg)
            return
        self.refused_inputs += 1
        self.last_input_refusal = f'{topic} {why}'
        if self.input_log.due(topic):
            self.get_logger().warning(f'refusing {topic} {why}: only {self.input_owner} steers this controller')
        if stale:      # the next position, 0.1 s later, will do
            return
        # Inputs that cannot be trusted: no target (vent) until target_selector's is heard again.
        self.inputs_missed = True
        if self.target_name:
            self.target_name, self.target, self.awaiting_target = '', None, False
            self.vent_controller()

    def check_inputs_clean(self) -> None:
        """After a refusal: once only target_selector publishes, its latched active_target afresh."""
        if self.inputs_missed and not any(s.check(None) for s in self.input_sources.values()):
            self.inputs_missed = False
            self._subscribe_input(ACTIVE_TARGET)
