"""What bag_recorder says on /diagnostics, for the scripts that wait on it: discovery is
pairwise, so a recorder and a controller both on the graph does not mean the recorder hears the
controller yet; the messages it has written per topic do. No rclpy import (plain message fields)."""
from __future__ import annotations

from typing import Mapping

#: The status is '<node name>: recording' (bag_recorder unless renamed).
STATUS_SUFFIX = ': recording'


def count_key(topic: str) -> str:
    """The key of a topic's message count in the status (relative topic name)."""
    return f'messages {topic}'


def recorded_counts(diagnostic_array) -> dict[str, int] | None:
    """Messages written per topic, from a DiagnosticArray holding the recorder's status; None
    when it holds none."""
    for st in diagnostic_array.status:
        if st.name.endswith(STATUS_SUFFIX):
            prefix = count_key('')
            return {kv.key[len(prefix):]: int(kv.value) for kv in st.values if kv.key.startswith(prefix)}
    return None


def hears(counts: Mapping[str, int] | None, *topics: str) -> bool:
    """The recorder has written at least one message of every one of `topics`."""
    return counts is not None and all(counts.get(t, 0) > 0 for t in topics)
