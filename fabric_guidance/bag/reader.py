"""Read a session bag (rosbag2 directory or its .mcap file) with rosbags."""
from __future__ import annotations

from pathlib import Path
from typing import Iterable, Iterator

from rosbags.rosbag2 import Reader
from rosbags.rosbag2.storage_mcap import McapReader

from .writer import typestore


def bag_dir(path: str | Path) -> Path:
    """The bag directory (the folder with metadata.yaml) of a bag folder or of its .mcap file."""
    path = Path(path).expanduser()
    if path.is_file() and path.suffix == '.mcap':
        path = path.parent
    if not (path / 'metadata.yaml').is_file():
        raise FileNotFoundError(f'{path} is not a rosbag2 bag (no metadata.yaml)')
    return path


def raw_messages(path: str | Path, topics: Iterable[str] | None = None) -> Iterator[tuple[str, str, int, bytes]]:
    """(topic, type, timestamp ns, CDR bytes) in bag (time) order, for some topics or all."""
    wanted = None if topics is None else set(topics)
    files = sorted(bag_dir(path).glob('*.mcap'))
    if files:
        # rosbags' MCAP storage reader straight away: the topics and types are in the file, and
        # skipping metadata.yaml (parsed by a pure-Python YAML) saves most of a short bag's read time.
        for file in files:
            storage = McapReader(file)
            storage.open()
            try:
                conns = [c for c in storage.connections if wanted is None or c.topic in wanted]
                if conns:
                    for conn, timestamp, data in storage.messages(conns):
                        yield conn.topic, conn.msgtype, timestamp, bytes(data)
            finally:
                storage.close()
        return
    with Reader(bag_dir(path)) as reader:
        conns = [c for c in reader.connections if wanted is None or c.topic in wanted]
        if not conns:
            return
        for conn, timestamp, data in reader.messages(connections=conns):
            yield conn.topic, conn.msgtype, timestamp, bytes(data)


def messages(path: str | Path, topics: Iterable[str] | None = None):
    """(topic, timestamp ns, decoded message) in bag order (rosbags' own message classes)."""
    store = typestore()
    for topic, msgtype, timestamp, data in raw_messages(path, topics):
        yield topic, timestamp, store.deserialize_cdr(data, msgtype)


def topic_types(path: str | Path) -> dict[str, str]:
    with Reader(bag_dir(path)) as reader:
        return {c.topic: c.msgtype for c in reader.connections}
