"""What survives of an MCAP file whose writer never closed it (SIGKILL, power loss, a full disk).

Such a file has its header and the chunks written before the cut, but no summary section (no
chunk index, no statistics) and its rosbag2 folder usually no metadata.yaml: rosbags writes
both only when the bag is closed. The indexed reading (reader.py) needs the summary, so this
reads the data section from the start, record by record, and keeps a record only when all of
its bytes are there and it parses completely; a chunk counts only when every record inside it
does and what the writer wrote after it is there too: its message index records (each
message's time and place in the chunk, matched one by one), or a next record. rosbags writes
no chunk CRC, and a file system may leave zeros where a crash cut the data off: a chunk whose
end is zeros parses, its index after it does not. Reading stops at the first record that is
cut off or unreadable: what follows it cannot be located without the summary. What was kept
and what was lost is told by Recovered.describe().

The records are read with the mcap library's record classes, over the bounds checked here (its
StreamReader would hand a short read of a cut record to the parser). No rosbags, no rclpy.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
import io
from pathlib import Path

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Message, MessageIndex, Schema
from mcap.stream_reader import get_chunk_data_stream

MAGIC = b'\x89MCAP0\r\n'
_RECORD_HEAD = 9              # opcode (1 byte) and length (8 bytes, little endian)


@dataclass
class Recovered:
    """The intact part of a cut-off MCAP file."""
    file: Path
    size: int                                  # bytes in the file
    intact_end: int = 0                        # the byte after the last intact record
    stop: str = ''                             # why reading stopped ('' : the data section ended)
    chunks: int = 0                            # intact chunks
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    counts: Counter = field(default_factory=Counter)   # messages recovered per topic (all topics)
    first_ns: int | None = None
    last_ns: int | None = None
    #: (log time, channel id, message) of the wanted topics, in file order
    messages: list[tuple[int, int, Message]] = field(default_factory=list)
    metadata: str = ''                         # what became of metadata.yaml (set by the reader)

    @property
    def lost_bytes(self) -> int:
        return self.size - self.intact_end

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    @property
    def span_s(self) -> float:
        return 0.0 if self.first_ns is None else (self.last_ns - self.first_ns) * 1e-9

    def describe(self) -> str:
        """One line: recovered what, lost what."""
        topics = ', '.join(f'{t} {n}' for t, n in sorted(self.counts.items()))
        missing = 'no summary section' + (f', {self.metadata}' if self.metadata else '')
        lost = (f'lost the {self.lost_bytes} bytes after byte {self.intact_end} of {self.size} ({self.stop})'
                if self.stop else f'the data section is whole; the {self.lost_bytes} bytes after it '
                '(the summary) are unusable')
        return (f'{self.file}: recovered a cut-off recording ({missing}): {self.total} messages '
                f'over {self.span_s:.2f} s in {self.chunks} intact chunk{"s" * (self.chunks != 1)} '
                f'({topics or "no topic"}); {lost}')


class NothingRecovered(ValueError):
    """Not one intact chunk (or message) in the file: the reason, one line."""


def _u64(buf, at: int) -> int:
    return int.from_bytes(buf[at:at + 8], 'little')


def _records(buf, start: int, end: int):
    """(position, opcode, body) of the records in buf[start:end]; ValueError on a cut record."""
    pos = start
    while pos < end:
        if pos + _RECORD_HEAD > end:
            raise ValueError(f'{end - pos} bytes of a record header')
        length = _u64(buf, pos + 1)
        stop = pos + _RECORD_HEAD + length
        if stop > end:
            raise ValueError(f'a record of {length} bytes with {end - pos - _RECORD_HEAD} left')
        yield pos, buf[pos], buf[pos + _RECORD_HEAD:stop]
        pos = stop


def _stream(body) -> ReadDataStream:
    return ReadDataStream(io.BytesIO(body))


def _parse(opcode: int, body):
    """The record, parsed; ValueError when its fields do not fill its bytes exactly."""
    s = _stream(body)
    if opcode == Opcode.SCHEMA:
        record = Schema.read(s)
    elif opcode == Opcode.CHANNEL:
        record = Channel.read(s)
    elif opcode == Opcode.MESSAGE:
        if len(body) < 22:
            raise ValueError(f'a message record of {len(body)} bytes')
        record = Message.read(s, len(body))
    elif opcode == Opcode.CHUNK:
        record = Chunk.read(s)
    elif opcode == Opcode.MESSAGE_INDEX:
        record = MessageIndex.read(s)
    else:
        return None
    if s.count != len(body):
        raise ValueError(f'{type(record).__name__} fields fill {s.count} of its {len(body)} bytes')
    return record


class _Scan:
    def __init__(self, result: Recovered, wanted: set[str] | None, max_chunk_bytes: int):
        self.r = result
        self.wanted = wanted
        self.max_chunk_bytes = max_chunk_bytes

    def inner(self, chunk: Chunk) -> tuple[list, dict[int, list[tuple[int, int]]]]:
        """The records of a chunk, all parsed, and per channel the (log time, offset) of its
        messages as the chunk's message index records must list them; or ValueError."""
        if chunk.uncompressed_size > self.max_chunk_bytes:    # a damaged size: do not allocate it
            raise ValueError(f'a chunk of {chunk.uncompressed_size} bytes uncompressed')
        stream, n = get_chunk_data_stream(chunk, validate_crc=True)
        data = stream.read(n) if n else b''
        if len(data) != chunk.uncompressed_size:
            raise ValueError(f'a chunk of {len(data)} bytes, its header says {chunk.uncompressed_size}')
        records, index = [], {}
        for at, op, body in _records(data, 0, len(data)):
            if op not in (Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE) and op < 0x80:
                raise ValueError(f'no record a chunk holds at its byte {at} (opcode 0x{op:02x})')
            records.append(_parse(op, body))
            if op == Opcode.MESSAGE:
                index.setdefault(records[-1].channel_id, []).append((records[-1].log_time, at))
        return records, index

    def commit(self, records: list) -> int:
        """Take the records of one intact unit (a chunk, or one record); the messages taken."""
        schemas, channels = dict(self.r.schemas), dict(self.r.channels)
        messages = []
        for record in records:
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                if record.schema_id and record.schema_id not in schemas:
                    raise ValueError(f'channel {record.topic} names schema {record.schema_id}, not written before it')
                channels[record.id] = record
            elif isinstance(record, Message):
                if record.channel_id not in channels:
                    raise ValueError(f'a message on channel {record.channel_id}, not written before it')
                messages.append(record)
        # all checked: only now does the unit count
        self.r.schemas, self.r.channels = schemas, channels
        for m in messages:
            topic = channels[m.channel_id].topic
            self.r.counts[topic] += 1
            self.r.first_ns = m.log_time if self.r.first_ns is None else min(self.r.first_ns, m.log_time)
            self.r.last_ns = m.log_time if self.r.last_ns is None else max(self.r.last_ns, m.log_time)
            if self.wanted is None or topic in self.wanted:
                self.r.messages.append((m.log_time, m.channel_id, m))
        return len(messages)


def scan(file: str | Path, buf, wanted: set[str] | None = None,
         max_chunk_bytes: int = 64 * 1024 * 1024) -> Recovered:
    """Read the data section of the MCAP file in `buf` (bytes or a memory map) from its start.

    Raises NothingRecovered when the file is not MCAP or is cut before its first intact chunk."""
    file = Path(file)
    size = len(buf)
    result = Recovered(file, size)
    if size < len(MAGIC) or bytes(buf[:len(MAGIC)]) != MAGIC:
        raise NothingRecovered(f'{file}: not an MCAP file (it does not start with the MCAP magic bytes)')
    result.intact_end = pos = len(MAGIC)
    work = _Scan(result, wanted, max_chunk_bytes)
    header_seen = False
    pending = None        # the last chunk read: (records, its index still to come, its end, its start)

    def confirm() -> None:
        nonlocal pending
        if pending is not None:
            work.commit(pending[0])
            result.chunks += 1
            result.intact_end = pending[2]
            pending = None

    while True:
        if pos >= size:
            result.stop = 'the file ends there, cut between two records'
            break
        if pos + _RECORD_HEAD > size:
            result.stop = f'cut inside the head of the record at byte {pos}'
            break
        opcode, length = buf[pos], _u64(buf, pos + 1)
        end = pos + _RECORD_HEAD + length
        name = Opcode(opcode).name.lower() if opcode in Opcode._value2member_map_ else f'opcode 0x{opcode:02x}'
        if opcode not in Opcode._value2member_map_ and opcode < 0x80:
            # 0x00 and 0x10-0x7f are no record (0x80 and up are private records, skipped): what
            # follows is not what the writer wrote (a file system's zero-filled tail after a crash)
            result.stop = f'no MCAP record at byte {pos} (opcode 0x{opcode:02x})'
            break
        if end > size:
            result.stop = (f'the {name} record at byte {pos} is cut off: '
                           f'{size - pos - _RECORD_HEAD} of its {length} bytes')
            break
        if not header_seen and opcode != Opcode.HEADER:
            raise NothingRecovered(f'{file}: not a readable MCAP file (no header record after the magic bytes)')
        header_seen = True
        try:
            if opcode in (Opcode.DATA_END, Opcode.FOOTER):
                confirm()
                result.stop = ''           # the data section ended: only the summary is unreadable
                break
            record = _parse(opcode, buf[pos + _RECORD_HEAD:end])
            if isinstance(record, MessageIndex) and pending is not None:
                expected = pending[1].pop(record.channel_id, None)
                if expected is None or [tuple(r) for r in record.records] != expected:
                    raise ValueError(f'it does not index the messages of channel {record.channel_id} '
                                     'in the chunk before it')
                pending = (pending[0], pending[1], end, pending[3])
                if not pending[1]:
                    confirm()
            elif not isinstance(record, MessageIndex):
                confirm()                  # a record after the chunk: its bytes were all written
                if isinstance(record, Chunk):
                    records, index = work.inner(record)
                    pending = (records, index, end, pos)
                    if not index:          # no message to index: nothing more to wait for
                        confirm()
                elif record is not None:
                    work.commit([record])
                    result.intact_end = end
                else:
                    result.intact_end = end
            else:                          # an index of a chunk already confirmed
                result.intact_end = end
        except Exception as exc:  # the mcap parsers raise many kinds on bytes that are not a record
            text = ' '.join(f'{type(exc).__name__}: {exc}'.split())[:120]
            result.stop = f'the {name} record at byte {pos} is unreadable ({text})'
            break
        pos = end
    if pending is not None:   # its index never came: whether all of the chunk was written is unknown
        result.stop += f'; the chunk at byte {pending[3]} before it lacks its message index: not trusted'
    if not result.total:
        raise NothingRecovered(f'{file}: cut off before its first intact chunk ({result.stop or "no message"}); '
                               'nothing to recover')
    return result
