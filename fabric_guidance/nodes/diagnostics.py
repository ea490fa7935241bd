"""The nodes' /diagnostics: one DiagnosticStatus per job, published as a DiagnosticArray."""
from __future__ import annotations

from typing import Sequence

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node


#: hardware_id of a status that concerns no device (diagnostic_updater's convention).
NO_HARDWARE = 'none'


def status(node: Node, name: str, level: bytes, message: str, values: dict,
           hardware_id: str = NO_HARDWARE) -> DiagnosticStatus:
    """One DiagnosticStatus named '<node's full name>: <name>' (without the leading '/': the
    node's name alone in the root namespace, `suit_a/plc_output: ...` in a namespace, so that two
    suits' statuses stay apart on the one /diagnostics) with its key/values as strings.
    hardware_id names the device the status is about (the PLC at address:port, the HoloLens at
    its address), as diagnostic aggregators group by it; NO_HARDWARE for software alone."""
    return DiagnosticStatus(level=level, name=f'{node.get_fully_qualified_name().lstrip("/")}: {name}',
                            message=message, hardware_id=hardware_id,
                            values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])


def publish_diagnostics(node: Node, publisher, statuses: Sequence[DiagnosticStatus]) -> None:
    msg = DiagnosticArray()
    msg.header.stamp = node.get_clock().now().to_msg()
    msg.status = list(statuses)
    publisher.publish(msg)
