"""The rclpy QoS profiles of fabric_guidance/interface.py's kinds, built once for the nodes
(interface.py itself imports no rclpy)."""
from __future__ import annotations

from ..interface import COMMAND, EVENT, LATCHED, SENSOR, qos_profile

SENSOR_QOS = qos_profile(SENSOR)
COMMAND_QOS = qos_profile(COMMAND)
LATCHED_QOS = qos_profile(LATCHED)
EVENT_QOS = qos_profile(EVENT)

#: A latched topic read for every value in turn, not only the latest (active_target where each
#: change matters: the wearer's return to the front, a monitor's count of targets): the reader
#: keeps the last 10, so a process not scheduled for a moment still sees X, '' and Y in order
#: (with depth 1 the newest overwrites an unread one). Matches the latched publishers: depth is
#: not part of QoS compatibility.
LATCHED_ALL_QOS = qos_profile(LATCHED)
LATCHED_ALL_QOS.depth = 10

#: A reader that must not lose what it could have buffered (a recorder; a bench counting unseen
#: control steps): the publishers' reliability and durability with a deep history, so that a
#: stall of its own process (writing, load, the GIL) costs no message. With depth 10, a 1 s stall
#: of a reader of a 100 Hz topic lost 6 of 400 samples here; with 1000, none. Depth is not part
#: of QoS compatibility.
DEEP_DEPTH = 1000


def deep(profile):
    """`profile` with a history of DEEP_DEPTH."""
    from rclpy.qos import HistoryPolicy, QoSProfile
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=DEEP_DEPTH, reliability=profile.reliability,
                      durability=profile.durability)
