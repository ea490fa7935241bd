"""Display messages, version 1: what the wearer sees, from headset_display to the headset.

docs/headset_wire_format.md is the specification (the C# receiver in hololens/ implements the
same). encode() builds one datagram from a kind and its fields, never longer than
MAX_DATAGRAM_BYTES: lists are capped by the spec's counts and strings cut to their limits
before encoding. decode() is the headset's trust boundary in Python (the simulated wearer
uses it): any bytes give a DisplayMessage or a WireFormatError, nothing else. DisplaySender
numbers what one sender sends (seq, event_id) and repeats events; DisplayView is the receiver.

Positions are Unity world coordinates (metres); to_unity() converts from REP 103.
"""
from __future__ import annotations

import bisect
from dataclasses import dataclass
import itertools
import json
from typing import Any, Sequence

from .clock_sync import MAX_DATAGRAM_BYTES
from .gaze_wire import WireFormatError, _integer, _json_type, _number, decode_object, message_kind

MAX_ID_CHARS = 32
MAX_TEXT_CHARS = 200
MAX_TARGETS = 8
MAX_DUMMIES_PER_PART = 25
MAX_DUMMY_PARTS = 8
UINT32 = 2 ** 32
ROLES = ('target', 'live')
EVENTS = ('found', 'next', 'done')
#: Decimals of a position in a datagram: 0.1 mm keeps 25 dummies within one datagram.
POSITION_DECIMALS = 4

#: The fields of each display kind, beyond version, kind, seq and stamp.
KINDS: dict[str, tuple[str, ...]] = {
    'targets': ('active', 'targets'),
    'dummies': ('set', 'part', 'parts', 'radius_m', 'positions'),
    'event': ('event_id', 'event', 'target'),
    'prompt': ('text', 'step', 'steps'),
    'phrase': ('text',),
}


@dataclass(frozen=True)
class DisplayMessage:
    kind: str
    seq: int
    stamp: float
    fields: dict


def to_unity(p_ros: Sequence[float]) -> list[float]:
    """A REP 103 point as Unity world (x, y, z) = (-y, z, x), rounded as on the wire."""
    x, y, z = (float(c) for c in p_ros)
    return _rounded((-y, z, x))


def from_unity(p_unity: Sequence[float]) -> list[float]:
    """The inverse of to_unity (REP 103 (x, y, z) = Unity (z, -x, y))."""
    a, b, c = (float(v) for v in p_unity)
    return [c, -a, b]


def encode(kind: str, seq: int, stamp: float, **fields: Any) -> bytes:
    """One display datagram; ValueError (naming the field) for values the spec does not allow.

    Lists longer than the spec allows are cut (targets to MAX_TARGETS, positions to
    MAX_DUMMIES_PER_PART), strings to their limits, so the result always decodes.
    """
    if kind not in KINDS:
        raise ValueError(f'unknown display kind {kind!r}; kinds: {sorted(KINDS)}')
    if set(fields) != set(KINDS[kind]):
        raise ValueError(f'{kind} needs the fields {KINDS[kind]}, got {sorted(fields)}')
    msg: dict[str, Any] = {'version': 1, 'kind': kind, 'seq': int(seq) % UINT32, 'stamp': float(stamp)}
    for name in KINDS[kind]:
        value = fields[name]
        if name in ('active', 'target', 'event'):
            value = str(value)[:MAX_ID_CHARS]
        elif name == 'text':
            value = _printable(str(value))[:MAX_TEXT_CHARS]
        elif name == 'targets':
            value = [{'id': str(t['id'])[:MAX_ID_CHARS], 'position': _rounded(t['position']),
                      'role': t.get('role', 'target')} for t in list(value)[:MAX_TARGETS]]
        elif name == 'positions':
            value = [_rounded(p) for p in list(value)[:MAX_DUMMIES_PER_PART]]
        elif name == 'radius_m':
            value = float(value)
        else:
            value = int(value)
        msg[name] = value
    data = json.dumps(msg, separators=(',', ':'), ensure_ascii=False, allow_nan=True).encode('utf-8')
    try:
        decode(data)
    except WireFormatError as exc:
        raise ValueError(f'display {kind}: {exc}') from None
    return data


def _printable(text: str) -> str:
    # Control characters would be escaped six bytes each and lone surrogates are not UTF-8:
    # either could push a 200-character text past the datagram limit or break the encoding.
    text = text.encode('utf-8', 'replace').decode('utf-8')
    return ''.join(c if c >= ' ' and c != '\x7f' else ' ' for c in text)


def _rounded(p: Sequence[float]) -> list[float]:
    return [round(float(c), POSITION_DECIMALS) + 0.0 for c in p]  # + 0.0: no '-0.0' on the wire


def decode(data: bytes) -> DisplayMessage:
    """Validate one downlink display datagram (not clock_ping: clock_sync.parse_ping)."""
    msg = decode_object(data, MAX_DATAGRAM_BYTES)
    kind = message_kind(msg)
    if kind not in KINDS:
        raise WireFormatError('kind', f'kind {kind[:40]!r} is not a display message')
    seq = _uint32(msg, 'seq')
    stamp = _number(_get(msg, 'stamp'), 'stamp')
    fields = {name: _CHECKS[name](_get(msg, name), name) for name in KINDS[kind]}
    if kind == 'dummies' and not (fields['part'] < fields['parts'] <= MAX_DUMMY_PARTS):
        raise WireFormatError('range', f"dummies part {fields['part']} of {fields['parts']}: needs "
                              f'0 <= part < parts <= {MAX_DUMMY_PARTS}')
    return DisplayMessage(kind, seq, stamp, fields)


# --- field checks ----------------------------------------------------------------------

def _get(msg: dict, name: str) -> Any:
    if name not in msg:
        raise WireFormatError('missing_field', f'field {name!r} is missing')
    return msg[name]


def _uint32(msg: dict, name: str) -> int:
    value = _integer(msg, name, ('range', f'{name} is too long'))
    if not 0 <= value < UINT32:
        raise WireFormatError('range', f'{name} {value} is outside 0..2**32-1')
    return value


def _string(limit: int):
    def check(value: Any, name: str) -> str:
        if type(value) is not str:
            raise WireFormatError('type', f'{name} must be a string, got {_json_type(value)}')
        if len(value) > limit:
            raise WireFormatError('range', f'{name} has {len(value)} characters, more than {limit}')
        return value
    return check


def _count(value: Any, name: str) -> int:
    if type(value) is not int:
        raise WireFormatError('type', f'{name} must be an integer, got {_json_type(value)}')
    if not 0 <= value < UINT32:
        raise WireFormatError('range', f'{name} {value} is outside 0..2**32-1')
    return value


def _radius(value: Any, name: str) -> float:
    r = _number(value, name)
    if not 0.0 < r <= 10.0:
        raise WireFormatError('range', f'{name} {r} is outside (0, 10] m')
    return r


def _point(value: Any, name: str) -> tuple[float, float, float]:
    if type(value) is not list or len(value) != 3:
        raise WireFormatError('type', f'{name} must be an array of 3 numbers, got {_json_type(value)}')
    p = tuple(_number(c, name, i) for i, c in enumerate(value))
    if not all(abs(c) <= 1.0e4 for c in p):
        raise WireFormatError('range', f'{name} {list(p)} is more than 10000 m from the origin')
    return p


def _array(value: Any, name: str, limit: int) -> list:
    if type(value) is not list:
        raise WireFormatError('type', f'{name} must be an array, got {_json_type(value)}')
    if len(value) > limit:
        raise WireFormatError('range', f'{name} has {len(value)} items, more than {limit}')
    return value


def _targets(value: Any, name: str) -> tuple:
    out = []
    for i, item in enumerate(_array(value, name, MAX_TARGETS)):
        where = f'{name}[{i}]'
        if type(item) is not dict:
            raise WireFormatError('type', f'{where} must be an object, got {_json_type(item)}')
        ident = _string(MAX_ID_CHARS)(_get(item, 'id'), f'{where}.id')
        position = _point(_get(item, 'position'), f'{where}.position')
        role = _string(MAX_ID_CHARS)(_get(item, 'role'), f'{where}.role')
        if role not in ROLES:
            raise WireFormatError('range', f'{where}.role {role!r} is not one of {ROLES}')
        out.append({'id': ident, 'position': position, 'role': role})
    return tuple(out)


def _positions(value: Any, name: str) -> tuple:
    return tuple(_point(p, f'{name}[{i}]') for i, p in enumerate(_array(value, name, MAX_DUMMIES_PER_PART)))


def _event(value: Any, name: str) -> str:
    event = _string(MAX_ID_CHARS)(value, name)
    if event not in EVENTS:
        raise WireFormatError('range', f'{name} {event!r} is not one of {EVENTS}')
    return event


_CHECKS = {
    'active': _string(MAX_ID_CHARS), 'target': _string(MAX_ID_CHARS), 'text': _string(MAX_TEXT_CHARS),
    'targets': _targets, 'positions': _positions, 'radius_m': _radius, 'event': _event,
    'set': _count, 'part': _count, 'parts': _count, 'event_id': _count, 'step': _count, 'steps': _count,
}

assert all(name in _CHECKS for names in KINDS.values() for name in names)


class DisplaySender:
    """One sender's display datagrams: seq +1 per datagram in the order they are sent, events
    sent `sends` times `repeat_s` apart with one event_id (UDP may lose one).

    A repeated event keeps its fields, not its bytes: each copy is encoded when it is due, with
    the seq of that moment. Copies numbered when queued would carry seqs below those of the
    messages sent between them, and a receiver drops a datagram not ahead of the last one it
    applied (DisplayView, the headset): every copy after the first would be stale and a lost
    first copy never repaired. At most `capacity` copies wait (the oldest is dropped beyond).
    """

    def __init__(self, sends: int = 3, repeat_s: float = 0.02, capacity: int = 64):
        self.sends, self.repeat_s, self.capacity = int(sends), float(repeat_s), int(capacity)
        self.seq = 0
        self.event_id = 0
        self._order = itertools.count()      # ties of one due time in the order queued
        self._repeats: list[tuple[float, int, dict]] = []   # (due, order, event fields), by due

    def encode(self, kind: str, stamp: float, **fields: Any) -> bytes:
        """The next datagram of this sender: encode() with the next seq."""
        data = encode(kind, self.seq, stamp, **fields)
        self.seq = (self.seq + 1) % UINT32
        return data

    def event(self, event: str, target: str, now: float, stamp: float) -> bytes:
        """A new event's first copy (send it now); the others are due from `now` on (due())."""
        self.event_id = (self.event_id + 1) % UINT32
        fields = {'event_id': self.event_id, 'event': event, 'target': target}
        for i in range(1, self.sends):
            bisect.insort(self._repeats, (now + i * self.repeat_s, next(self._order), fields))
        del self._repeats[:max(0, len(self._repeats) - self.capacity)]
        return self.encode('event', stamp, **fields)

    def due(self, now: float, stamp: float) -> list[bytes]:
        """The event copies due by `now`, each encoded now with its own seq, in the order due."""
        out = []
        while self._repeats and self._repeats[0][0] <= now:
            out.append(self.encode('event', stamp, **self._repeats.pop(0)[2]))
        return out

    def pending(self) -> int:
        return len(self._repeats)


class DisplayView:
    """What the headset shows, built from display messages as the C# DisplayState builds it:
    stale seqs dropped, each event_id shown once, a dummy set shown once all its parts arrived.
    apply() returns what the wearer newly sees, as short lines ('next front_left', 'found
    front_left', 'dummies 50', 'prompt Face front and rest (0/4)', 'phrase ...', 'targets 4').
    Memory is bounded (EVENT_MEMORY event ids, one set being assembled)."""

    EVENT_MEMORY = 64
    RESTART_THRESHOLD = 1000

    def __init__(self):
        self.active = ''
        self.targets: tuple = ()
        self.dummies: tuple = ()
        self.dummy_set = 0
        self.prompt = ('', 0, 0)
        self.phrase = ''
        self.applied = self.stale = 0
        self._last_seq: int | None = None
        self._parts: dict[int, tuple] = {}
        self._assembling = (0, 0)
        self._events: dict[int, None] = {}   # insertion-ordered: the oldest id is forgotten first

    def apply(self, msg: DisplayMessage) -> list[str]:
        if self._last_seq is not None:
            ahead = (msg.seq - self._last_seq) % UINT32
            if ahead == 0 or (ahead >= UINT32 // 2 and UINT32 - ahead <= self.RESTART_THRESHOLD):
                self.stale += 1
                return []
        self._last_seq = msg.seq
        self.applied += 1
        f, seen = msg.fields, []
        if msg.kind == 'targets':
            if (f['active'], len(f['targets'])) != (self.active, len(self.targets)):
                seen.append(f"targets {len(f['targets'])}, active {f['active'] or '-'}")
            self.active, self.targets = f['active'], f['targets']
        elif msg.kind == 'event':
            if f['event_id'] not in self._events:
                self._events[f['event_id']] = None
                if len(self._events) > self.EVENT_MEMORY:
                    del self._events[next(iter(self._events))]
                seen.append(f"{f['event']} {f['target']}".rstrip())
        elif msg.kind == 'dummies':
            seen += self._dummies(f)
        elif msg.kind == 'prompt':
            prompt = (f['text'], f['step'], f['steps'])
            if prompt != self.prompt and f['text']:
                seen.append(f"prompt {f['text']} ({f['step']}/{f['steps']})")
            self.prompt = prompt
        elif msg.kind == 'phrase':
            if f['text'] != self.phrase and f['text']:
                seen.append(f"phrase {f['text']}")
            self.phrase = f['text']
        return seen

    def _dummies(self, f: dict) -> list[str]:
        if f['set'] == 0:
            self.dummy_set, self.dummies, self._parts = 0, (), {}
            return []
        if f['set'] == self.dummy_set:
            return []
        if (f['set'], f['parts']) != self._assembling:
            self._parts, self._assembling = {}, (f['set'], f['parts'])
        self._parts[f['part']] = f['positions']
        if len(self._parts) < f['parts']:
            return []
        self.dummies = tuple(p for i in range(f['parts']) for p in self._parts[i])
        self.dummy_set, self._parts = f['set'], {}
        return [f'dummies {len(self.dummies)}']
