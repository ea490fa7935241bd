"""The topics a session bag holds, their message types and the QoS their publishers offer
(written into the bag's metadata as offered_qos_profiles, as rosbag2 does, so that
`ros2 bag play` republishes each topic with its own QoS: transient local for the latched ones).
Names, types and QoS kinds come from fabric_guidance/interface.py; no rclpy here: the profiles
are rosbags' Qos values.
"""
from __future__ import annotations

from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

from .. import interface
from ..interface import (ACTIVE_TARGET, CLOCK, COMMAND, CONFIRM, DEFAULT, EVENT, GAZE, HEAD_POSE, LATCHED,
                         LIVE_TARGETS, PRESSURE_COMMAND, QOS_KINDS, SENSOR, TARGET)

__all__ = ['BAG_QOS', 'CLOCK', 'COMMAND', 'CONTROL_TOPICS', 'DEFAULT', 'EVENT', 'LATCHED', 'REPLAYED_INPUTS',
           'SENSOR', 'TOPICS', 'bag_topic', 'is_control_topic']

#: RMW_DURATION_INFINITE as rosbag2 (Jazzy and later) writes it.
INFINITE = QosTime(9223372036, 854775807)


def _qos(reliable: bool, latched: bool, depth: int) -> Qos:
    return Qos(QosHistory.KEEP_LAST, depth, QosReliability.RELIABLE if reliable else QosReliability.BEST_EFFORT,
               QosDurability.TRANSIENT_LOCAL if latched else QosDurability.VOLATILE, INFINITE, INFINITE,
               QosLiveliness.AUTOMATIC, INFINITE, False)


BAG_QOS = {kind: _qos(*QOS_KINDS[kind]) for kind in (SENSOR, COMMAND, LATCHED, EVENT, DEFAULT)}

#: topic (relative names as the nodes use them) -> (ROS type, QoS kind): what bag_recorder records.
TOPICS: dict[str, tuple[str, str]] = {t.name: (t.type, t.qos) for t in interface.TOPICS if t.recorded}

#: What `fabric-guidance replay BAG` republishes (the controller's inputs), besides /clock.
REPLAYED_INPUTS = (GAZE, HEAD_POSE, TARGET, ACTIVE_TARGET)
#: The topics whose messages move a suit through a live graph (the controller's inputs, the
#: command itself, a target's pose, a study's confirm): a replay never publishes them where a
#: live controller hears them (bag/player.py).
CONTROL_TOPICS = (GAZE, HEAD_POSE, TARGET, ACTIVE_TARGET, PRESSURE_COMMAND, CONFIRM, LIVE_TARGETS)


def is_control_topic(name: str) -> bool:
    """True for a topic of CONTROL_TOPICS in any namespace (live_targets/<name> included)."""
    parts = [p for p in name.split('/') if p]
    return bool(parts) and (parts[-1] in CONTROL_TOPICS or (len(parts) > 1 and parts[-2] == LIVE_TARGETS))


def bag_topic(name: str, namespace: str = '/') -> str:
    """The absolute name a relative topic has in a bag (rosbag2 stores absolute names)."""
    if name.startswith('/'):
        return name
    ns = namespace.rstrip('/')
    return f'{ns}/{name}'
