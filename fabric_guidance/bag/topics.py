"""The topics a session bag holds, their message types and the QoS their publishers offer
(written into the bag's metadata as offered_qos_profiles, as rosbag2 does, so that
`ros2 bag play` republishes each topic with its own QoS: transient local for the latched ones).
Names, types and QoS kinds come from fabric_guidance/interface.py; no rclpy here: the profiles
are rosbags' Qos values.
"""
from __future__ import annotations

from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

from .. import interface
from ..interface import (ACTIVE_TARGET, CLOCK, COMMAND, DEFAULT, EVENT, GAZE, HEAD_POSE, LATCHED, QOS_KINDS, SENSOR,
                         TARGET)

__all__ = ['BAG_QOS', 'CLOCK', 'COMMAND', 'DEFAULT', 'EVENT', 'LATCHED', 'REPLAYED_INPUTS', 'SENSOR', 'TOPICS',
           'bag_topic']

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


def bag_topic(name: str, namespace: str = '/') -> str:
    """The absolute name a relative topic has in a bag (rosbag2 stores absolute names)."""
    if name.startswith('/'):
        return name
    ns = namespace.rstrip('/')
    return f'{ns}/{name}'
