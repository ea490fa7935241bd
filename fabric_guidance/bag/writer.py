"""BagWriter: CDR-serialized messages into a rosbag2 bag (metadata.yaml version 9, MCAP
storage) with rosbags, each topic with its message definition (ros2msg schema, RIHS01 hash,
what Foxglove and `ros2 bag play` decode with) and its offered QoS profiles."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Iterable

from rosbags.interfaces import Qos
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from .topics import BAG_QOS, TOPICS, bag_topic

_TYPESTORE = None


def typestore():
    """The message definitions of ROS 2 Kilted (the release the package targets)."""
    global _TYPESTORE
    if _TYPESTORE is None:
        _TYPESTORE = get_typestore(Stores.ROS2_KILTED)
    return _TYPESTORE


class BagWriter:
    """Write one bag; connections are added on first use. Use as a context manager or close()."""

    def __init__(self, path: str | Path, custom_data: dict[str, str] | None = None):
        self.path = Path(path).expanduser()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._writer = Writer(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
        self._writer.open()
        for key, value in (custom_data or {}).items():
            self._writer.set_custom_data(key, value)
        self._connections: dict[str, object] = {}
        self.counts: dict[str, int] = {}

    def add_topic(self, topic: str, msgtype: str, qos: Iterable[Qos] = ()) -> None:
        if topic not in self._connections:
            self._connections[topic] = self._writer.add_connection(
                topic, msgtype, typestore=typestore(), offered_qos_profiles=list(qos))
            self.counts[topic] = 0

    def add_package_topic(self, name: str, namespace: str = '/') -> str:
        """A topic of topics.TOPICS with its type and QoS; returns its name in the bag."""
        msgtype, kind = TOPICS[name]
        topic = bag_topic(name, namespace)
        self.add_topic(topic, msgtype, [BAG_QOS[kind]])
        return topic

    def write(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        """One serialized (CDR) message received at timestamp_ns (ns since the epoch, or sim time)."""
        self._writer.write(self._connections[topic], int(timestamp_ns), data)
        self.counts[topic] += 1

    def flush(self, fsync: bool = True) -> bool:
        """Put what was written so far on disk as a complete chunk, so that a writer killed
        later (SIGKILL, power loss) leaves it readable (recovery.py); True when a chunk was
        written. rosbags' MCAP writer closes a chunk only at 1 MiB or on close: this closes the
        pending one early through its storage (rosbags 0.11's McapWriter: chunk, close_chunk,
        bio), and does nothing with a writer that has none of them."""
        storage = getattr(self._writer, 'storage', None) if self._writer is not None else None
        chunk = getattr(storage, 'chunk', None)
        if chunk is None or not hasattr(storage, 'close_chunk') or not hasattr(storage, 'bio'):
            return False
        if not chunk.msgs:           # nothing new (schemas and channels wait for their messages)
            return False
        storage.close_chunk()
        storage.bio.flush()
        if fsync:
            os.fsync(storage.bio.fileno())
        return True

    def set_custom_data(self, key: str, value: str) -> None:
        self._writer.set_custom_data(key, value)

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
