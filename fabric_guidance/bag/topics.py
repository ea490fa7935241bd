"""The topics a session bag holds, their message types and the QoS their publishers offer
(written into the bag's metadata as offered_qos_profiles, as rosbag2 does, so that
`ros2 bag play` republishes each topic with its own QoS: transient local for the latched ones).
No rclpy here: the profiles are rosbags' Qos values; nodes/bag_recorder.py maps the kinds to
the rclpy profiles of nodes/common.py.
"""
from __future__ import annotations

from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

from .controller_io import CONTROLLER_INPUT, CONTROLLER_PARAMETERS

#: RMW_DURATION_INFINITE as rosbag2 (Jazzy and later) writes it.
INFINITE = QosTime(9223372036, 854775807)

# QoS kinds (nodes/common.py): sensor = SENSOR_QOS (best effort, keep last 5), command =
# COMMAND_QOS (reliable, 10), latched = LATCHED_QOS (reliable, transient local, 1), event =
# EVENT_QOS (reliable, 50), default = depth 10 reliable volatile (/diagnostics).
SENSOR, COMMAND, LATCHED, EVENT, DEFAULT = 'sensor', 'command', 'latched', 'event', 'default'


def _qos(reliability: QosReliability, durability: QosDurability, depth: int) -> Qos:
    return Qos(QosHistory.KEEP_LAST, depth, reliability, durability, INFINITE, INFINITE,
               QosLiveliness.AUTOMATIC, INFINITE, False)


BAG_QOS = {
    SENSOR: _qos(QosReliability.BEST_EFFORT, QosDurability.VOLATILE, 5),
    COMMAND: _qos(QosReliability.RELIABLE, QosDurability.VOLATILE, 10),
    LATCHED: _qos(QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL, 1),
    EVENT: _qos(QosReliability.RELIABLE, QosDurability.VOLATILE, 50),
    DEFAULT: _qos(QosReliability.RELIABLE, QosDurability.VOLATILE, 10),
}

#: topic (relative names as the nodes use them) -> (ROS type, QoS kind)
TOPICS: dict[str, tuple[str, str]] = {
    'gaze': ('geometry_msgs/msg/PoseStamped', SENSOR),
    'head_pose': ('geometry_msgs/msg/PoseStamped', SENSOR),
    'target': ('geometry_msgs/msg/PointStamped', LATCHED),
    'active_target': ('std_msgs/msg/String', LATCHED),
    'target_found': ('std_msgs/msg/String', EVENT),
    'pressure_command': ('std_msgs/msg/Float64MultiArray', COMMAND),
    'measured_pressure': ('std_msgs/msg/Float64MultiArray', COMMAND),
    'speech': ('std_msgs/msg/String', EVENT),
    'calibration_status': ('std_msgs/msg/String', EVENT),
    '/diagnostics': ('diagnostic_msgs/msg/DiagnosticArray', DEFAULT),
    CONTROLLER_INPUT: ('std_msgs/msg/Float64MultiArray', COMMAND),
    CONTROLLER_PARAMETERS: ('std_msgs/msg/String', LATCHED),
}

#: What `fabric-guidance replay BAG` republishes (the controller's inputs), besides /clock.
REPLAYED_INPUTS = ('gaze', 'head_pose', 'target', 'active_target')
CLOCK = '/clock'


def bag_topic(name: str, namespace: str = '/') -> str:
    """The absolute name a relative topic has in a bag (rosbag2 stores absolute names)."""
    if name.startswith('/'):
        return name
    ns = namespace.rstrip('/')
    return f'{ns}/{name}'
