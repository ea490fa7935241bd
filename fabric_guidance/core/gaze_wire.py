"""Wire format (version 1) of the HoloLens gaze stream: one JSON object per UDP datagram.

The HoloLens app sends Unity-frame values (left-handed: x right, y up, z forward);
parse_datagram validates a datagram and returns a GazeSample in REP 103 (x forward, y left,
z up). encode_datagram is the sender side, for the simulated wearer and the tests.
SequenceTracker turns the seq field into new / stale / gap / restart and loss counters.
docs/gaze_wire_format.md is the specification for the Unity developer.

parse_datagram is the trust boundary for whatever arrives on the UDP port: for any bytes it
returns a GazeSample or raises WireFormatError, nothing else. It works on plain floats and
builds the numpy arrays once at the end, because it must keep up with far more than 90 Hz.
"""
from __future__ import annotations

from dataclasses import dataclass
import enum
import json
import math
import operator
from typing import Any, Sequence

import numpy as np

from .geometry import MIN_NORM, GeometryError

WIRE_VERSION = 1
DEFAULT_MAX_SIZE = 1024
SEQ_MODULUS = 2 ** 32
#: Positions farther than this from the Unity world origin (metres, per component) are
#: tracking faults, not places a wearer can be; the bound also keeps later arithmetic finite.
MAX_ABS_POSITION = 1.0e4

#: The fields of version 1, in the order parse_datagram checks them.
FIELDS: tuple[str, ...] = ('version', 'seq', 'stamp', 'gaze_origin', 'gaze_direction',
                           'head_position', 'head_orientation', 'eye_tracking_valid')

#: The values WireFormatError.reason can take.
REASONS: tuple[str, ...] = ('oversize', 'encoding', 'json', 'not_object', 'version', 'kind',
                            'missing_field', 'type', 'non_finite', 'zero_vector', 'range')
#: The uplink `kind` of a gaze sample, and what a datagram without `kind` is.
GAZE_KIND = 'gaze'
#: The uplink `kind` of the wearer's confirm press (docs/headset_wire_format.md).
CONFIRM_KIND = 'confirm'


class WireFormatError(ValueError):
    """A datagram that is not a valid version-1 gaze sample.

    reason is one of REASONS (for counters and diagnostics); str(error) names the field.
    """

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


@dataclass(frozen=True, eq=False)
class GazeSample:
    """One validated gaze sample in REP 103 (metres; the arrays are read-only).

    gaze_direction is a unit vector; head_orientation is a unit quaternion (x, y, z, w) with
    w >= 0. Only parse_datagram checks this; direct construction does not. eq=False because
    numpy arrays have no single truth value; compare fields instead.
    """

    seq: int
    stamp: float
    gaze_origin: np.ndarray
    gaze_direction: np.ndarray
    head_position: np.ndarray
    head_orientation: np.ndarray
    eye_tracking_valid: bool


class _NonFiniteLiteral(Exception):
    """Raised by the strict decoder on NaN / Infinity / -Infinity (not JSON, but Python's
    json accepts them by default)."""


def _reject_constant(name: str) -> Any:
    raise _NonFiniteLiteral(name)


class _HugeInt(float):
    """A JSON integer too long for CPython's int() digit limit (and for a double: any integer
    of more than 309 digits is): kept as the float it rounds to (inf), so it is judged like any
    other number that overflows a double ('non_finite', or 'range' for seq and version) and an
    unknown field holding one is ignored like any other, instead of failing the whole datagram."""


#: Integers with more characters than this become _HugeInt (far below CPython's digit limit,
#: 640 at its lowest setting; 400 digits already overflow a double).
_INT_CHARS = 400


def _parse_int(text: str):
    return int(text) if len(text) <= _INT_CHARS else _HugeInt(text)


# Built once: json.loads with keyword arguments would build a new decoder per call.
_STRICT_DECODER = json.JSONDecoder(parse_constant=_reject_constant, parse_int=_parse_int)
_LENIENT_DECODER = json.JSONDecoder(parse_int=_parse_int)
_isfinite = math.isfinite


def decode_object(data: bytes, max_size: int = DEFAULT_MAX_SIZE) -> dict:
    """The first checks every headset datagram passes, in either direction: size, UTF-8,
    strict JSON (no NaN / Infinity literals) and a top-level object. Raises WireFormatError
    (oversize, encoding, json, non_finite, not_object) and nothing else for any bytes."""
    if type(data) is not bytes:
        if not isinstance(data, (bytes, bytearray, memoryview)):
            raise TypeError(f'a datagram must be bytes, got {type(data).__name__}')
        data = bytes(data)  # a memoryview's len() counts items, not bytes
    # Size first: nothing larger is decoded at all.
    if len(data) > max_size:
        raise WireFormatError('oversize', f'datagram of {len(data)} bytes exceeds {max_size}')
    try:
        text = data.decode('utf-8')
    except UnicodeDecodeError as exc:
        raise WireFormatError('encoding', f'datagram is not UTF-8: {exc.reason} at byte {exc.start}') from None
    try:
        msg = _STRICT_DECODER.decode(text)
    except _NonFiniteLiteral as exc:
        raise _non_finite_literal_error(text, str(exc)) from None
    except RecursionError:
        raise WireFormatError('json', 'datagram JSON is nested too deeply') from None
    except ValueError as exc:  # JSONDecodeError, and int() refusing a huge digit string
        raise WireFormatError('json', f'datagram is not JSON: {exc}') from None
    if type(msg) is not dict:
        raise WireFormatError('not_object', f'datagram is a JSON {type(msg).__name__}, not an object')
    return msg


def message_kind(msg: dict, default: str | None = None) -> str:
    """Check `version` (must be 1) and return `kind` (docs/headset_wire_format.md); a message
    without `kind` is `default`, or missing_field when there is no default."""
    version = _integer(msg, 'version', ('version', f'version of {_INT_CHARS}+ digits is not supported'))
    if version != WIRE_VERSION:
        raise WireFormatError('version', f'version {version} is not supported (expected {WIRE_VERSION})')
    if 'kind' not in msg:
        if default is None:
            raise WireFormatError('missing_field', "field 'kind' is missing")
        return default
    kind = msg['kind']
    if type(kind) is not str:
        raise WireFormatError('type', f'kind must be a string, got {_json_type(kind)}')
    return kind


def parse_datagram(data: bytes, max_size: int = DEFAULT_MAX_SIZE) -> GazeSample:
    """Validate one datagram and convert it to a REP 103 GazeSample.

    Raises WireFormatError (and nothing else) for any bytes that are not a valid version-1
    sample; the first failing check, in the order of docs/gaze_wire_format.md, decides the
    reason. Unknown extra fields are ignored.
    """
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise TypeError(f'parse_datagram needs bytes, got {type(data).__name__}')
    return sample_from_object(decode_object(data, max_size))


def sample_from_object(msg: dict) -> GazeSample:
    """The GazeSample of a decoded uplink object (decode_object): version, kind, then the fields."""
    kind = message_kind(msg, GAZE_KIND)
    if kind != GAZE_KIND:
        raise WireFormatError('kind', f'kind {kind[:40]!r} is not a gaze sample')

    seq = _integer(msg, 'seq', ('range', f'seq of {_INT_CHARS}+ digits is outside 0..{SEQ_MODULUS - 1}'))
    if not 0 <= seq < SEQ_MODULUS:
        raise WireFormatError('range', f'seq {seq} is outside 0..{SEQ_MODULUS - 1}')

    stamp = _number(_field(msg, 'stamp'), 'stamp')

    ox, oy, oz = _vector(msg, 'gaze_origin', 3)
    _check_position(ox, oy, oz, 'gaze_origin')
    dx, dy, dz = _unit(_vector(msg, 'gaze_direction', 3), 'gaze_direction')
    hx, hy, hz = _vector(msg, 'head_position', 3)
    _check_position(hx, hy, hz, 'head_position')
    qx, qy, qz, qw = _unit(_vector(msg, 'head_orientation', 4), 'head_orientation')
    qnorm = 1.0

    valid = _field(msg, 'eye_tracking_valid')
    if type(valid) is not bool:
        raise WireFormatError('type', f'eye_tracking_valid must be true or false, got {_json_type(valid)}')

    # Unity (x, y, z) is (z, -x, y) in REP 103 (geometry.unity_to_ros_point). For the
    # quaternion the rotation axis is a pseudo-vector: the handedness flip negates it, so
    # (x, y, z, w) becomes (-z, x, -y, w); equal to geometry.unity_to_ros_quaternion (tested)
    # without its matrix round trip, which alone would cost ~40 us per datagram.
    if qw < 0.0:
        qnorm = -qnorm  # one sign per orientation, as in geometry
    return GazeSample(
        seq=seq,
        stamp=stamp,
        gaze_origin=_frozen_array((oz, -ox, oy)),
        gaze_direction=_frozen_array((dz, -dx, dy)),
        head_position=_frozen_array((hz, -hx, hy)),
        head_orientation=_frozen_array((-qz / qnorm, qx / qnorm, -qy / qnorm, qw / qnorm)),
        eye_tracking_valid=valid,
    )


@dataclass(frozen=True)
class Confirm:
    """One confirm press: press_id (uint32, +1 per press, the same in its repeats) and stamp, the
    headset clock when it was pressed (the clock of the gaze stamp) [s]."""

    press_id: int
    stamp: float


def confirm_from_object(msg: dict) -> Confirm:
    """The Confirm of a decoded uplink object whose kind is confirm (version already checked)."""
    press_id = _integer(msg, 'press_id', ('range', f'press_id of {_INT_CHARS}+ digits is outside 0..{SEQ_MODULUS - 1}'))
    if not 0 <= press_id < SEQ_MODULUS:
        raise WireFormatError('range', f'press_id {press_id} is outside 0..{SEQ_MODULUS - 1}')
    return Confirm(press_id, _number(_field(msg, 'stamp'), 'stamp'))


def encode_confirm(press_id: int, stamp: float) -> bytes:
    """The confirm datagram of one press (what the headset sends); checked like a received one."""
    msg = {'version': WIRE_VERSION, 'kind': CONFIRM_KIND, 'press_id': operator.index(press_id), 'stamp': float(stamp)}
    data = json.dumps(msg, separators=(',', ':'), allow_nan=True).encode('utf-8')
    confirm_from_object(decode_object(data))
    return data


def encode_datagram(seq: int, stamp: float, gaze_origin: Sequence[float],
                    gaze_direction: Sequence[float], head_position: Sequence[float],
                    head_orientation: Sequence[float], eye_tracking_valid: bool) -> bytes:
    """One version-1 datagram from Unity-frame values: what a (simulated) HoloLens sends.

    Vectors are (x, y, z) and the quaternion (x, y, z, w), all in Unity's frame; numpy
    arrays are fine. The result is checked with parse_datagram, so anything the receiver
    would reject raises WireFormatError here instead of being sent.
    """
    msg = {
        'version': WIRE_VERSION,
        'seq': operator.index(seq),
        'stamp': float(stamp),
        'gaze_origin': [float(c) for c in gaze_origin],
        'gaze_direction': [float(c) for c in gaze_direction],
        'head_position': [float(c) for c in head_position],
        'head_orientation': [float(c) for c in head_orientation],
        'eye_tracking_valid': bool(eye_tracking_valid),
    }
    # allow_nan so that a NaN reaches parse_datagram and is reported with its field name.
    data = json.dumps(msg, separators=(',', ':'), allow_nan=True).encode('utf-8')
    parse_datagram(data)
    return data


def ros_to_unity_point(p: Sequence[float]) -> np.ndarray:
    """A point or direction from REP 103 to Unity's frame: the inverse of unity_to_ros_point."""
    a, b, c = _finite(p, 3, 'point')
    return np.array([-b, c, a])


def ros_to_unity_quaternion(q_xyzw: Sequence[float]) -> np.ndarray:
    """An orientation (x, y, z, w) from REP 103 to Unity's frame: the inverse of
    unity_to_ros_quaternion. Normalised, returned with w >= 0."""
    x, y, z, w = _finite(q_xyzw, 4, 'quaternion')
    norm = math.hypot(x, y, z, w)
    if not norm > MIN_NORM:
        raise GeometryError('quaternion has zero length')
    if w < 0.0:
        norm = -norm
    # Inverse of (x, y, z, w) -> (-z, x, -y, w).
    return np.array([y, -z, -x, w]) / norm


class SeqStatus(str, enum.Enum):
    """What SequenceTracker.update made of a sequence number."""

    NEW = 'new'          # the first sample, or the next one: use it
    GAP = 'gap'          # newer, with samples missing in between (last_gap of them): use it
    STALE = 'stale'      # a duplicate or older than the newest sample: drop it
    RESTART = 'restart'  # far behind the newest: the sender restarted; use it, start over

    @property
    def accepted(self) -> bool:
        return self is not SeqStatus.STALE


class SequenceTracker:
    """Classifies the seq of each accepted datagram and counts received, lost and stale samples.

    seq is uint32 and wraps from 2**32-1 to 0. Distances are taken modulo 2**32: less than
    half the ring ahead is forward (a gap if more than 1), otherwise it is behind. Up to
    restart_threshold behind is a duplicate or a reordered sample (stale); farther behind is a
    sender restart, which resets the reference but keeps the counters.
    """

    def __init__(self, restart_threshold: int = 1000):
        if not 0 < restart_threshold < SEQ_MODULUS // 2:
            raise ValueError(f'restart_threshold must be in 1..{SEQ_MODULUS // 2 - 1}, got {restart_threshold}')
        self.restart_threshold = restart_threshold
        self.reset()

    def reset(self) -> None:
        """Forget the last sequence number and zero the counters."""
        self.last_seq: int | None = None
        self.received = 0    # samples accepted (not stale)
        self.lost = 0        # seq numbers skipped over by gaps
        self.stale = 0       # duplicates and reordered samples dropped
        self.restarts = 0
        self.last_gap = 0    # samples lost just before the latest accepted one

    @property
    def loss_rate(self) -> float:
        """lost / (received + lost); 0 when nothing has been seen."""
        total = self.received + self.lost
        return self.lost / total if total else 0.0

    def update(self, seq: int) -> SeqStatus:
        """Classify seq (from a datagram parse_datagram accepted) and update the counters."""
        if not 0 <= seq < SEQ_MODULUS:
            raise ValueError(f'seq {seq} is outside 0..{SEQ_MODULUS - 1}')
        last = self.last_seq
        if last is None:
            return self._accept(seq, SeqStatus.NEW, 0)
        ahead = (seq - last) % SEQ_MODULUS
        if ahead == 0:
            self.stale += 1
            return SeqStatus.STALE
        if ahead < SEQ_MODULUS // 2:
            if ahead == 1:
                return self._accept(seq, SeqStatus.NEW, 0)
            return self._accept(seq, SeqStatus.GAP, ahead - 1)
        if SEQ_MODULUS - ahead <= self.restart_threshold:
            self.stale += 1
            return SeqStatus.STALE
        self.restarts += 1
        return self._accept(seq, SeqStatus.RESTART, 0)

    def _accept(self, seq: int, status: SeqStatus, gap: int) -> SeqStatus:
        self.last_seq = seq
        self.received += 1
        self.lost += gap
        self.last_gap = gap
        return status


# --- helpers ---------------------------------------------------------------------------

def _field(msg: dict, name: str) -> Any:
    try:
        return msg[name]
    except KeyError:
        raise WireFormatError('missing_field', f'field {name!r} is missing') from None


def _json_type(value: Any) -> str:
    if value is None:
        return 'null'
    if type(value) is bool:
        return 'a boolean'
    if type(value) in (int, float):
        return f'the number {value!r}'
    names = {str: 'a string', list: 'an array', dict: 'an object', _HugeInt: 'a huge integer'}
    return names.get(type(value), type(value).__name__)


def _integer(msg: dict, name: str, huge: tuple[str, str]) -> int:
    """An integer field; `huge` is the (reason, message) for one too long to parse."""
    value = _field(msg, name)
    if type(value) is _HugeInt:
        raise WireFormatError(*huge)
    if type(value) is not int:
        raise WireFormatError('type', f'{name} must be an integer, got {_json_type(value)}')
    return value


def _number(value: Any, name: str, index: int | None = None) -> float:
    # type() rather than isinstance(): bool is an int subclass and is not a number here.
    if type(value) is float:
        if _isfinite(value):
            return value
        # 1e400 parses as inf
        raise WireFormatError('non_finite', f'{_name(name, index)} is not finite ({value!r})')
    if type(value) is _HugeInt:
        raise WireFormatError('non_finite', f'{_name(name, index)} is too large to be a float')
    if type(value) is int:
        try:
            return float(value)
        except OverflowError:
            raise WireFormatError('non_finite', f'{_name(name, index)} is too large to be a float') from None
    raise WireFormatError('type', f'{_name(name, index)} must be a number, got {_json_type(value)}')


def _unit(v: list[float], name: str) -> list[float]:
    """v / |v| for any finite v of length > MIN_NORM. Scaled by its largest component first:
    the length of [1e308] * 4 overflows a double (hypot gives inf, and v / inf is zero)."""
    m = max(abs(c) for c in v)
    if not m > 0.0:
        raise WireFormatError('zero_vector', f'{name} has zero length')
    scaled = [c / m for c in v]
    n = math.hypot(*scaled)          # in [1, sqrt(len(v))]
    if not m * n > MIN_NORM:
        raise WireFormatError('zero_vector', f'{name} has zero length ({m * n:g})')
    return [c / n for c in scaled]


def _name(name: str, index: int | None) -> str:
    return name if index is None else f'{name}[{index}]'


def _vector(msg: dict, name: str, n: int) -> list[float]:
    value = _field(msg, name)
    if type(value) is not list or len(value) != n:
        what = f'an array of {len(value)}' if type(value) is list else _json_type(value)
        raise WireFormatError('type', f'{name} must be an array of {n} numbers, got {what}')
    return [_number(c, name, i) for i, c in enumerate(value)]


def _check_position(x: float, y: float, z: float, name: str) -> None:
    if not (abs(x) <= MAX_ABS_POSITION and abs(y) <= MAX_ABS_POSITION and abs(z) <= MAX_ABS_POSITION):
        raise WireFormatError('range', f'{name} {[x, y, z]} is more than {MAX_ABS_POSITION:g} m from the origin')


def _frozen_array(values: tuple[float, ...]) -> np.ndarray:
    arr = np.array(values)
    arr.flags.writeable = False  # the sample is frozen; so are its arrays
    return arr


def _finite(v: Sequence[float], n: int, name: str) -> tuple[float, ...]:
    arr = np.asarray(v, dtype=float)
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise GeometryError(f'{name} must be {n} finite numbers, got {arr.tolist()}')
    return tuple(float(c) for c in arr)


def _non_finite_literal_error(text: str, literal: str) -> WireFormatError:
    """Name the top-level field that holds a NaN/Infinity literal (rare path: parse again
    leniently and search, iteratively so that deep nesting cannot overflow the stack)."""
    try:
        msg = _LENIENT_DECODER.decode(text)
    except (ValueError, RecursionError):
        msg = None
    where = 'the datagram'
    if type(msg) is dict:
        for key, value in msg.items():
            if _holds_non_finite(value):
                where = f'field {key!r}'
                break
    return WireFormatError('non_finite', f'{literal} in {where} is not valid JSON')


def _holds_non_finite(value: Any) -> bool:
    stack = [value]
    while stack:
        v = stack.pop()
        if type(v) is float and not _isfinite(v):
            return True
        if type(v) is list:
            stack.extend(v)
        elif type(v) is dict:
            stack.extend(v.values())
    return False
