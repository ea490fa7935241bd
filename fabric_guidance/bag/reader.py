"""Read a session bag (rosbag2 directory or its .mcap file) with rosbags."""
from __future__ import annotations

from pathlib import Path
from typing import Iterable, Iterator

from mcap.reader import make_reader
from rosbags.rosbag2 import Reader

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
        # The mcap library reads the summary and only the chunks holding the wanted topics; rosbags'
        # MCAP storage parses every channel's QoS YAML on open, most of a short bag's read time.
        for file in files:
            with open(file, 'rb') as stream:
                reader = make_reader(stream)
                summary = reader.get_summary()
                available = {c.topic for c in summary.channels.values()} if summary else None
                chosen = None if wanted is None else sorted(wanted if available is None else wanted & available)
                if chosen == []:
                    continue
                for schema, channel, message in reader.iter_messages(topics=chosen):
                    yield channel.topic, schema.name if schema else '', message.log_time, bytes(message.data)
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
