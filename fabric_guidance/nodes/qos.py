"""The rclpy QoS profiles of fabric_guidance/interface.py's kinds, built once for the nodes
(interface.py itself imports no rclpy)."""
from __future__ import annotations

from ..interface import COMMAND, EVENT, LATCHED, SENSOR, qos_profile

SENSOR_QOS = qos_profile(SENSOR)
COMMAND_QOS = qos_profile(COMMAND)
LATCHED_QOS = qos_profile(LATCHED)
EVENT_QOS = qos_profile(EVENT)
