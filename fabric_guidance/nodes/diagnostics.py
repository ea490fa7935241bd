"""The nodes' /diagnostics: one DiagnosticStatus per job, published as a DiagnosticArray."""
from __future__ import annotations

from typing import Sequence

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node


def status(node: Node, name: str, level: bytes, message: str, values: dict) -> DiagnosticStatus:
    """One DiagnosticStatus named '<node>: <name>' with its key/values as strings."""
    return DiagnosticStatus(level=level, name=f'{node.get_name()}: {name}', message=message,
                            hardware_id=node.get_fully_qualified_name(),
                            values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])


def publish_diagnostics(node: Node, publisher, statuses: Sequence[DiagnosticStatus]) -> None:
    msg = DiagnosticArray()
    msg.header.stamp = node.get_clock().now().to_msg()
    msg.status = list(statuses)
    publisher.publish(msg)
