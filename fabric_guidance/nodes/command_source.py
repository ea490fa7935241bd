"""Whose pressure_command plc_output writes, and how old it is (docs/safety.md, "Where a command
comes from").

Only the controller of the running graph moves a register. plc_output accepts a command only
from a publisher of the node named `command_publisher` (pressure_controller) in its own
namespace, as the ROS graph names it: `ros2 bag play` (node rosbag2_player), the package's
replay (bag_player) or any second publisher is refused. With an rclpy whose MessageInfo carries
`publisher_gid` (Kilted and later), each message's sending publisher is compared with the
controller's publishers in the graph; without it (Jazzy's rclpy), every command is refused while
any other node publishes on the topic: the suit vents rather than follow a command of unknown
origin.

A command is as old as its `source_timestamp`: the publisher's system clock when it published,
so a command that waited in a frozen process (SIGSTOP, a paused VM) or in DDS is aged from when
it was sent, not from when plc_output woke. A message without one (a middleware that gives 0)
is refused.

No rclpy here: the graph is a callable the node passes in, so the decisions are unit-tested.
"""
from __future__ import annotations

from dataclasses import dataclass
import time
from typing import Callable, Iterable, Mapping

#: The graph is asked again at most this often for an unknown publisher [s] (steady clock): a
#: flood from a second publisher costs one lookup per period, a restarted controller is heard
#: within one period of its discovery.
REFRESH_S = 0.2


@dataclass(frozen=True)
class Publisher:
    """A publisher of the topic as the graph names it (rclpy's TopicEndpointInfo, reduced)."""
    node_name: str
    node_namespace: str
    gid: bytes

    @property
    def node(self) -> str:
        ns = self.node_namespace.rstrip('/')
        return f'{ns}/{self.node_name}'


def full_name(name: str, namespace: str) -> str:
    """The fully qualified node name of `name` (relative to `namespace`, or already absolute)."""
    if name.startswith('/'):
        return name
    return f'{namespace.rstrip("/")}/{name}'


class CommandSource:
    """Accept a message only from the publishers of one node; say why otherwise."""

    def __init__(self, node: str, publishers: Callable[[], Iterable[Publisher]],
                 refresh_s: float = REFRESH_S, clock: Callable[[], float] = time.monotonic):
        self.node = node                 # fully qualified, e.g. /pressure_controller
        self._publishers = publishers
        self.refresh_s = refresh_s
        self._clock = clock
        self._known: dict[bytes, str] = {}   # gid -> node, from the latest lookup
        self._looked_s = -float('inf')
        self.refused = 0
        self.refused_by: dict[str, int] = {}  # node (or the reason's subject) -> refused count
        self.last_refusal = ''

    def _lookup(self) -> None:
        self._known = {p.gid: p.node for p in self._publishers()}
        self._looked_s = self._clock()

    def _due(self) -> bool:
        return self._clock() - self._looked_s >= self.refresh_s

    def check(self, info: Mapping | None) -> str:
        """'' when the message's publisher is the controller's, else the reason it is refused."""
        gid_info = info.get('publisher_gid') if info else None
        if gid_info is not None:
            gid = bytes(gid_info['data'])
            if self._known.get(gid) != self.node and self._due():
                self._lookup()
            who = self._known.get(gid)
            if who == self.node:
                return ''
            why = f'from {who}' if who else 'from a publisher the graph does not name (yet)'
            return self.refuse(who or 'unnamed', why)
        # No publisher_gid (rclpy before Kilted): the graph must show the controller alone.
        if self._due():
            self._lookup()
        others = sorted({n for n in self._known.values() if n != self.node})
        if others:
            why = (f'while other nodes publish it: {", ".join(others)} (this rclpy names no sender, '
                   'so no command is written while they publish)')
            return self.refuse(','.join(others), why)
        if not self._known:
            return self.refuse('unnamed', 'from a publisher the graph does not name (yet)')
        return ''

    def refuse(self, who: str, why: str) -> str:
        self.refused += 1
        self.refused_by[who] = self.refused_by.get(who, 0) + 1
        self.last_refusal = why
        return why


def sent_age_s(info: Mapping | None, now_ns: int | None = None) -> float | None:
    """How long ago the publisher sent the message [s] (its source_timestamp against this
    host's system clock), or None when the middleware gave no source time. Negative when it was
    stamped "in the future" (a clock stepped back): its age is then unknown, and the caller must
    not take it for fresh."""
    source_ns = info.get('source_timestamp', 0) if info else 0
    if not source_ns or source_ns <= 0:
        return None
    now_ns = time.time_ns() if now_ns is None else now_ns
    return (now_ns - source_ns) * 1e-9
