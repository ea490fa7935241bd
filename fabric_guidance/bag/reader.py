"""Read a session bag (rosbag2 directory or its .mcap file): through the MCAP summary's index,
or, for a recording cut off before it was closed (no summary section, no or a stale
metadata.yaml), its intact part from the start of the file (recovery.py)."""
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
from .recovery import NothingRecovered, Recovered, scan
from .writer import typestore


def bag_dir(path: str | Path) -> Path:
    """The bag directory of a bag folder or of its .mcap file: the folder with metadata.yaml, or
    without one (a recorder killed before it closed the bag writes none) with .mcap files."""
    path = Path(path).expanduser()
    if path.is_file() and path.suffix == '.mcap':
        path = path.parent
    if not (path / 'metadata.yaml').is_file() and not (path.is_dir() and any(path.glob('*.mcap'))):
        raise FileNotFoundError(f'{path} is not a rosbag2 bag (neither metadata.yaml nor an .mcap file)')
    return path


#: The package's recorder writes chunks of about 1 MiB (rosbags' writer).
MAX_CHUNK_BYTES = 64 * 1024 * 1024


class BagReadError(ValueError):
    """A bag, or part of one, that cannot be read: one line naming the file and the reason."""


def _metadata(directory: Path) -> tuple[dict | None, str]:
    """metadata.yaml's rosbag2_bagfile_information, or None and what is wrong with the file."""
    meta_file = directory / 'metadata.yaml'
    if not meta_file.is_file():
        return None, 'no metadata.yaml'
    try:
        meta = load_yaml(meta_file, 'bag metadata')
    except InputFileError as exc:
        return None, f'metadata.yaml unreadable ({excerpt(str(exc))})'
    info = meta.get('rosbag2_bagfile_information') if isinstance(meta, dict) else None
    return (info, '') if isinstance(info, dict) else (None, 'metadata.yaml without rosbag2_bagfile_information')


def _mcap_files(directory: Path, info: dict | None) -> list[Path]:
    """The bag's MCAP files: those metadata.yaml names (each must exist), else every *.mcap."""
    meta_file = directory / 'metadata.yaml'
    names = info.get('relative_file_paths') if info is not None else None
    if not isinstance(names, list) or not names or not all(isinstance(n, str) and n for n in names):
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


def _scan_open(file: Path, f, wanted: set[str] | None) -> Recovered:
    """recovery.scan over the open file f; BagReadError when nothing is intact."""
    if os.fstat(f.fileno()).st_size == 0:
        raise BagReadError(f'{file}: empty (the recording was cut off before its first chunk); nothing to recover')
    with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as m:
        try:
            return scan(file, m, wanted, MAX_CHUNK_BYTES)
        except NothingRecovered as exc:
            raise BagReadError(str(exc)) from None


def _recover(file: Path, f, wanted: set[str] | None, recovered: list[Recovered], metadata: str):
    """The intact part of a file without a usable summary, in log-time order (recovery.py)."""
    found = _scan_open(file, f, wanted)
    found.metadata = metadata
    found.messages.sort(key=lambda item: item[0])          # stable: file order within a time
    recovered.append(found)
    for log_time, cid, message in found.messages:
        channel = found.channels[cid]
        schema = found.schemas.get(channel.schema_id)
        yield channel.topic, schema.name if schema else '', log_time, bytes(message.data)


def _mcap_messages(file: Path, wanted: set[str] | None, problems: list[str],
                   recovered: list[Recovered], metadata: str = ''):
    """(topic, type, log time, data) of one MCAP file in log-time order, chunk by chunk.

    A chunk that cannot be read (CRC, truncation, garbage) is reported in `problems` and skipped;
    so are message counts that fall short of the file's summary statistics. A file without a
    usable summary (a recording cut off) is read from its start up to its last intact record and
    appended to `recovered`; one with no intact chunk at all raises BagReadError."""
    with open(file, 'rb') as f:
        with _mapped(f) as stream:
            try:
                reader = make_reader(stream, validate_crcs=True)
                reader.get_header()
                summary = reader.get_summary()
            except Exception:  # the mcap library raises many kinds on a damaged file
                summary = None
            if summary is not None and not (not summary.chunk_indexes and summary.statistics
                                            and summary.statistics.message_count):
                yield from _indexed(file, stream, summary, wanted, problems)
                return
        yield from _recover(file, f, wanted, recovered, metadata)


def _indexed(file: Path, stream, summary, wanted: set[str] | None, problems: list[str]):
    """The messages of a file with its summary, through the chunk index."""
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
                 problems: list[str] | None = None,
                 recovered: list[Recovered] | None = None) -> Iterator[tuple[str, str, int, bytes]]:
    """(topic, type, timestamp ns, CDR bytes) in bag (time) order, for some topics or all.

    Damage (an unreadable chunk, fewer messages than the summary counts) is appended to
    `problems` and reading goes on; without a `problems` list it raises BagReadError at the end.
    A file cut off before its summary gives its intact part, told in `recovered` (one
    Recovered per such file: Recovered.describe() says what was recovered and what was lost).
    A file that cannot be opened at all, or has no intact chunk, raises BagReadError at once."""
    wanted = None if topics is None else set(topics)
    found: list[str] = [] if problems is None else problems
    cut: list[Recovered] = [] if recovered is None else recovered
    directory = bag_dir(path)
    info, metadata = _metadata(directory)
    files = _mcap_files(directory, info)
    if files:
        # The mcap library reads the summary and only the chunks holding the wanted topics; rosbags'
        # MCAP storage parses every channel's QoS YAML on open, most of a short bag's read time.
        for file in files:
            before = len(cut)
            yield from _mcap_messages(file, wanted, found, cut, metadata)
            if len(cut) > before and not metadata:
                cut[-1].metadata = _stale(info, cut[-1])
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


def _stale(info: dict, found: Recovered) -> str:
    """What a metadata.yaml beside a cut-off file says that the file does not (a recorder that
    writes it at the start, or one left from an earlier close)."""
    count = info.get('message_count')
    if isinstance(count, int) and not isinstance(count, bool) and count != found.total:
        return f'a stale metadata.yaml (it counts {count} messages)'
    return ''


def messages(path: str | Path, topics: Iterable[str] | None = None):
    """(topic, timestamp ns, decoded message) in bag order (rosbags' own message classes)."""
    store = typestore()
    for topic, msgtype, timestamp, data in raw_messages(path, topics):
        yield topic, timestamp, store.deserialize_cdr(data, msgtype)


def topic_types(path: str | Path) -> dict[str, str]:
    with Reader(bag_dir(path)) as reader:
        return {c.topic: c.msgtype for c in reader.connections}


def _has_summary(file: Path) -> bool:
    with open(file, 'rb') as f, _mapped(f) as stream:
        try:
            summary = make_reader(stream, validate_crcs=True).get_summary()
        except Exception:  # the mcap library raises many kinds on a damaged file
            return False
        return summary is not None and bool(summary.chunk_indexes or not summary.statistics
                                            or not summary.statistics.message_count)


def scan_bag(path: str | Path) -> tuple[Path, list[Recovered], str]:
    """Every MCAP file of a bag read from its start (recovery.scan), all topics: the bag's
    directory, one Recovered per file, and what is missing ('' for a bag closed properly:
    every file has its summary and metadata.yaml is there). BagReadError when a file has
    nothing intact."""
    directory = bag_dir(path)
    info, metadata = _metadata(directory)
    files = _mcap_files(directory, info)
    if not files:
        raise BagReadError(f'{directory}: no .mcap file to recover from')
    found, cut = [], []
    for file in files:
        if not _has_summary(file):
            cut.append(file.name)
        with open(file, 'rb') as f:
            r = _scan_open(file, f, None)
        r.metadata = metadata or (_stale(info, r) if file.name in cut else '')
        found.append(r)
    missing = [f'no summary section in {", ".join(cut)}'] if cut else []
    missing += [metadata] if metadata else []
    return directory, found, '; '.join(missing)
