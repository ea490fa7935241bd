"""Read a session bag (rosbag2 directory or its .mcap file) with rosbags."""
from __future__ import annotations

from collections import Counter
import contextlib
import io
import mmap
import os
import heapq
import itertools
from pathlib import Path
from typing import Iterable, Iterator

from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk, ChunkIndex, Message
from mcap.stream_reader import breakup_chunk
from rosbags.rosbag2 import Reader

from ..core.safe_input import InputFileError, excerpt, load_yaml
from .writer import typestore


def bag_dir(path: str | Path) -> Path:
    """The bag directory (the folder with metadata.yaml) of a bag folder or of its .mcap file."""
    path = Path(path).expanduser()
    if path.is_file() and path.suffix == '.mcap':
        path = path.parent
    if not (path / 'metadata.yaml').is_file():
        raise FileNotFoundError(f'{path} is not a rosbag2 bag (no metadata.yaml)')
    return path


#: The package's recorder writes chunks of about 1 MiB (rosbags' writer).
MAX_CHUNK_BYTES = 64 * 1024 * 1024


class BagReadError(ValueError):
    """A bag, or part of one, that cannot be read: one line naming the file and the reason."""


def _mcap_files(directory: Path) -> list[Path]:
    """The bag's MCAP files: those metadata.yaml names (each must exist), else every *.mcap."""
    meta_file = directory / 'metadata.yaml'
    try:
        meta = load_yaml(meta_file, 'bag metadata')
    except InputFileError as exc:
        raise BagReadError(str(exc)) from None
    info = meta.get('rosbag2_bagfile_information') if isinstance(meta, dict) else None
    names = info.get('relative_file_paths') if isinstance(info, dict) else None
    if not isinstance(names, list) or not all(isinstance(n, str) and n for n in names):
        return sorted(directory.glob('*.mcap'))
    files = []
    for name in names:
        file = directory / name
        if Path(name).is_absolute() or '..' in Path(name).parts:
            raise BagReadError(f'{meta_file}: field "relative_file_paths" names {excerpt(name)} '
                               'outside the bag')
        if not file.is_file():
            raise BagReadError(f'{meta_file}: field "relative_file_paths" names {name}, '
                               'which does not exist')
        files.append(file)
    return [f for f in files if f.suffix == '.mcap']


def _one_line(exc: BaseException) -> str:
    text = f'{type(exc).__name__}: {exc}' if str(exc) else type(exc).__name__
    return ' '.join(text.split())[:120]


@contextlib.contextmanager
def _mapped(f):
    """The file as a read-only memory map: a damaged record length asks read() for gigabytes,
    which a file object allocates before it finds the end of the file; a map returns what
    there is."""
    if os.fstat(f.fileno()).st_size == 0:
        yield io.BytesIO(b'')
        return
    with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as m:
        yield _MapStream(m)


class _MapStream:
    """A seekable binary stream over a memory map (what the mcap reader needs)."""

    def __init__(self, m: mmap.mmap):
        self._m = m

    def readinto(self, buffer) -> int:
        data = self._m.read(len(buffer))
        buffer[:len(data)] = data
        return len(data)

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def read(self, size: int = -1) -> bytes:
        return self._m.read(None if size is None or size < 0 else size)

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        self._m.seek(offset, whence)
        return self._m.tell()

    def tell(self) -> int:
        return self._m.tell()


def _mcap_messages(file: Path, wanted: set[str] | None, problems: list[str]):
    """(topic, type, log time, data) of one MCAP file in log-time order, chunk by chunk.

    A chunk that cannot be read (CRC, truncation, garbage) is reported in `problems` and skipped;
    so are message counts that fall short of the file's summary statistics. A file without a
    summary or whose header is unreadable raises BagReadError."""
    with open(file, 'rb') as f, _mapped(f) as stream:
        try:
            reader = make_reader(stream, validate_crcs=True)
            reader.get_header()
            summary = reader.get_summary()
        except Exception as exc:  # the mcap library raises many kinds on a damaged file
            raise BagReadError(f'{file}: not a readable MCAP file ({_one_line(exc)})') from None
        if summary is None or (not summary.chunk_indexes and summary.statistics
                               and summary.statistics.message_count):
            raise BagReadError(f'{file}: no summary section (the recording was cut off?); '
                               'it cannot be checked, so it is not replayed')
        channels = {cid: c for cid, c in summary.channels.items()
                    if wanted is None or c.topic in wanted}
        expected = Counter()
        if summary.statistics is not None:
            for cid, n in summary.statistics.channel_message_counts.items():
                if cid in channels:
                    expected[channels[cid].topic] += n
        read = Counter()
        heap, order = [], itertools.count()
        for ci in summary.chunk_indexes:
            offsets = ci.message_index_offsets
            if not offsets or any(cid in channels for cid in offsets):
                heapq.heappush(heap, (ci.message_start_time, next(order), ci))
        while heap:
            _, _, item = heapq.heappop(heap)
            if not isinstance(item, ChunkIndex):
                channel, message = item
                schema = summary.schemas.get(channel.schema_id)
                read[channel.topic] += 1
                yield (channel.topic, schema.name if schema else '', message.log_time,
                       bytes(message.data))
                continue
            try:
                stream.seek(item.chunk_start_offset + 1 + 8)
                chunk = Chunk.read(ReadDataStream(stream))
                if chunk.uncompressed_size > MAX_CHUNK_BYTES:  # a damaged size: do not allocate it
                    raise BagReadError(f'uncompressed size {chunk.uncompressed_size} bytes')
                records = breakup_chunk(chunk, validate_crc=True)
            except Exception as exc:
                problems.append(f'{file}: chunk at byte {item.chunk_start_offset} unreadable '
                                f'({_one_line(exc)})')
                continue
            for record in records:
                if isinstance(record, Message) and record.channel_id in channels:
                    item = (channels[record.channel_id], record)
                    heapq.heappush(heap, (record.log_time, next(order), item))
        short = {t: (read[t], n) for t, n in expected.items() if read[t] < n}
        if short:
            counts = ', '.join(f'{r} of {n} {t}' for t, (r, n) in sorted(short.items()))
            problems.append(f'{file}: read {counts} messages the summary counts')


def raw_messages(path: str | Path, topics: Iterable[str] | None = None,
                 problems: list[str] | None = None) -> Iterator[tuple[str, str, int, bytes]]:
    """(topic, type, timestamp ns, CDR bytes) in bag (time) order, for some topics or all.

    Damage (an unreadable chunk, fewer messages than the summary counts) is appended to
    `problems` and reading goes on; without a `problems` list it raises BagReadError at the end.
    A file that cannot be opened at all raises BagReadError at once."""
    wanted = None if topics is None else set(topics)
    found: list[str] = [] if problems is None else problems
    directory = bag_dir(path)
    files = _mcap_files(directory)
    if files:
        # The mcap library reads the summary and only the chunks holding the wanted topics; rosbags'
        # MCAP storage parses every channel's QoS YAML on open, most of a short bag's read time.
        for file in files:
            yield from _mcap_messages(file, wanted, found)
        if problems is None and found:
            raise BagReadError('; '.join(found))
        return
    try:
        with Reader(directory) as reader:
            conns = [c for c in reader.connections if wanted is None or c.topic in wanted]
            if not conns:
                return
            for conn, timestamp, data in reader.messages(connections=conns):
                yield conn.topic, conn.msgtype, timestamp, bytes(data)
    except Exception as exc:  # rosbags raises its own kinds on a damaged bag
        raise BagReadError(f'{directory}: not a readable bag ({_one_line(exc)})') from None


def messages(path: str | Path, topics: Iterable[str] | None = None):
    """(topic, timestamp ns, decoded message) in bag order (rosbags' own message classes)."""
    store = typestore()
    for topic, msgtype, timestamp, data in raw_messages(path, topics):
        yield topic, timestamp, store.deserialize_cdr(data, msgtype)


def topic_types(path: str | Path) -> dict[str, str]:
    with Reader(bag_dir(path)) as reader:
        return {c.topic: c.msgtype for c in reader.connections}
