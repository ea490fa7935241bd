"""Fuzzing a running gaze_bridge: more than 10,000 malformed datagrams mixed with valid ones.

Hypothesis draws the datagrams with a fixed seed (the same ones whenever this module runs
alone; the draw shifts a little after other hypothesis tests in the session, so the minimum
is asserted): random bytes,
truncated and oversized JSON, wrong versions, missing fields, wrong types, NaN and Infinity,
huge and negative numbers, zero-length vectors, and well-formed samples whose sequence number
goes back. They are sent over UDP to one gaze_bridge process, in batches. The expected fate of
every datagram comes from the core it is built on (gaze_wire.parse_datagram for the reason,
SequenceTracker for stale ones, fed in sending order): the bridge must stay up, publish
exactly the samples expected (each tagged by its gaze origin) and count every other datagram
under its reason on /diagnostics.
"""
import collections
import json
import math
import time

from hypothesis import HealthCheck, Phase, given, seed, settings
from hypothesis import strategies as st
import pytest

from fabric_guidance.core.gaze_wire import FIELDS, REASONS, SequenceTracker, WireFormatError, encode_datagram, \
    parse_datagram
from test_node_gaze_bridge import (DIRECTION_U, HEAD_Q_U, HEAD_U, MAX_BYTES, _running_bridge, dropped, udp_drops)

#: Hypothesis' seed: the same datagrams on every run.
SEED = 20250601
#: Malformed datagrams the run must have sent, at least.
MIN_MALFORMED = 10_000
BATCH = 100
BATCHES = 145
#: Send pacing: ~5000 datagrams/s, hostile but within what the kernel buffer absorbs.
PAUSE_EVERY, PAUSE_S = 100, 0.01
#: Gaze origin x (Unity) of the junk template: a junk datagram that happens to be valid
#: is published with this tag.
JUNK_TAG = 7.0

NUMERIC = ('seq', 'stamp', 'gaze_origin', 'gaze_direction', 'head_position', 'head_orientation')
HUGE = [1e308, -1e308, 1.7976931348623157e308, 1e300, -1e300, 2 ** 63, -2 ** 63, 2 ** 64, 10 ** 400, -1, -1.5,
        -0.0, 4294967296, 4294967295, 1e-320, 5e-324]


def _template(seq=123456):
    return json.loads(encode_datagram(seq, 1.0, (JUNK_TAG, 1.6, 0.1), DIRECTION_U, HEAD_U, HEAD_Q_U, True))


def _dump(msg) -> bytes:
    return json.dumps(msg, separators=(',', ':')).encode()


def _set(field, value) -> bytes:
    msg = _template()
    msg[field] = value
    return _dump(msg)


def _huge(field, value) -> bytes:
    """A huge or negative number as the field or as one component of it (literal JSON text,
    so 10**400 stays an integer and 1e400 would be inf)."""
    msg = _template()
    if isinstance(msg[field], list):
        msg[field][0] = value
    else:
        msg[field] = value
    return _dump(msg)


def _literal(field, literal) -> bytes:
    text = _dump(_template()).decode()
    return text.replace(f'"{field}":', f'"{field}":{literal},"_{field}":', 1).encode()


def _oversize(n) -> bytes:
    msg = _template()
    msg['pad'] = 'x' * (MAX_BYTES + n)
    return _dump(msg)


def _zero(field) -> bytes:
    return _set(field, [0.0] * len(_template()[field]))


def _missing(field) -> bytes:
    msg = _template()
    del msg[field]
    return _dump(msg)


TEMPLATE_BYTES = _dump(_template())
JSON_VALUES = st.one_of(st.none(), st.booleans(), st.text(max_size=5), st.integers(-10 ** 30, 10 ** 30),
                        st.floats(allow_nan=False, allow_infinity=False), st.lists(st.integers(), max_size=6),
                        st.dictionaries(st.text(max_size=3), st.integers(), max_size=2))

MALFORMED = st.one_of(
    st.binary(max_size=MAX_BYTES + 200),                                              # random bytes
    st.integers(0, len(TEMPLATE_BYTES) - 1).map(lambda i: TEMPLATE_BYTES[:i]),        # truncated
    st.integers(1, 2000).map(_oversize),                                              # oversized
    st.integers(-5, 10 ** 6).filter(lambda v: v != 1).map(lambda v: _set('version', v)),  # wrong version
    st.sampled_from(FIELDS).map(_missing),                                            # missing field
    st.sampled_from(['clock_ping', 'targets', 'Gaze', '', None, 7]).map(lambda k: _set('kind', k)),  # other kinds
    st.tuples(st.sampled_from(FIELDS), JSON_VALUES).map(lambda fv: _set(*fv)),        # wrong type / value
    st.tuples(st.sampled_from(NUMERIC), st.sampled_from(['NaN', 'Infinity', '-Infinity', '1e400', '-1e400']))
      .map(lambda fl: _literal(*fl)),                                                 # NaN, inf
    st.tuples(st.sampled_from(NUMERIC), st.sampled_from(HUGE)).map(lambda fv: _huge(*fv)),  # huge, negative
    st.sampled_from(['gaze_direction', 'head_orientation']).map(_zero),               # zero-length vectors
    st.sampled_from([b'[]', b'1', b'"gaze"', b'null', b'true', b'{}', b'\xff\xfe{}',
                     '\udcff'.encode('utf-8', 'surrogatepass'), b'[' * 5000 + b']' * 5000]),
)
#: What each drawn item is: 'junk' (bytes above), 'valid' (the next seq) or 'back' (a seq k behind).
ITEMS = st.one_of(
    st.tuples(st.just('junk'), MALFORMED),
    st.tuples(st.just('junk'), MALFORMED),
    st.tuples(st.just('junk'), MALFORMED),
    st.tuples(st.just('junk'), MALFORMED),
    st.tuples(st.just('junk'), MALFORMED),
    st.tuples(st.just('junk'), MALFORMED),
    st.tuples(st.just('valid'), st.just(b'')),
    st.tuples(st.just('back'), st.integers(1, 1000)),
)


@pytest.fixture(scope='module')
def bridge(tmp_path_factory):
    # Every datagram is judged by the model as sent: none may be dropped for the time it waited
    # in a loaded machine's receive buffer (that bound is tested in test_node_gaze_bridge).
    yield from _running_bridge(tmp_path_factory.mktemp('fuzz_bridge'), max_queue_delay_s=0.0)


def test_the_bridge_survives_malformed_datagrams_and_publishes_only_valid_samples(bridge):
    before = bridge.settle()
    n_gaze = len(bridge.gaze)
    drops_before = udp_drops(bridge.port)
    model = SequenceTracker()
    model.update(bridge.seq - 1)   # where the bridge's own tracker is after start-up
    expected_tags = []        # tag of every sample the bridge must publish, in sending order
    reasons = collections.Counter()
    kinds = collections.Counter()
    sent = [0]
    start = time.monotonic()

    def expect(data: bytes):
        """The core's verdict on `data`, fed to the model in sending order."""
        try:
            sample = parse_datagram(data, MAX_BYTES)
        except WireFormatError as exc:
            reasons[exc.reason] += 1
            return
        if not model.update(sample.seq).accepted:
            reasons['stale'] += 1
        elif not sample.eye_tracking_valid:
            reasons['eye_tracking_invalid'] += 1
        else:
            expected_tags.append(-float(sample.gaze_origin[1]))   # REP 103 y = -Unity x

    def send(data: bytes):
        expect(data)
        bridge.send(data)
        sent[0] += 1
        if sent[0] % PAUSE_EVERY == 0:
            time.sleep(PAUSE_S)

    @seed(SEED)
    @settings(max_examples=BATCHES, database=None, phases=[Phase.generate], deadline=None,
              suppress_health_check=list(HealthCheck))
    @given(st.lists(ITEMS, min_size=BATCH, max_size=BATCH))
    def batch(items):
        for kind, item in items:
            kinds[kind] += 1
            if kind == 'junk':
                send(item)
            elif kind == 'valid':
                send(bridge.sample(tag=round(0.01 + 1e-4 * len(expected_tags), 6)))
            else:   # a well-formed sample whose seq goes back by `item`
                send(bridge.sample(tag=3.0, seq=max(bridge.seq - item, 0)))
    batch()
    send(bridge.sample(tag=5.0))   # and a last valid one: still alive and publishing
    send_s = time.monotonic() - start
    after = bridge.settle()

    assert bridge.proc.poll() is None, 'gaze_bridge died'
    assert udp_drops(bridge.port) == drops_before, 'the kernel dropped datagrams: the counts cannot match'
    malformed = sum(n for r, n in reasons.items() if r in REASONS)
    assert malformed >= MIN_MALFORMED, (malformed, reasons)
    delta = {r: n - dropped(before).get(r, 0) for r, n in dropped(after).items()}
    for reason, n in delta.items():
        assert n == reasons.get(reason, 0), (reason, delta, dict(reasons))
    published = [-m.pose.position.y for m in bridge.gaze[n_gaze:]]
    assert int(after['published']) - int(before['published']) == len(expected_tags)
    assert sorted(published) == pytest.approx(sorted(expected_tags), abs=1e-9)
    assert all(math.isfinite(c) for m in bridge.gaze[n_gaze:] for c in
               (m.pose.position.x, m.pose.position.y, m.pose.position.z, m.pose.orientation.w))
    assert int(after['dropped']) - int(before['dropped']) == sent[0] - len(expected_tags)
    assert len([r for r in REASONS if reasons[r]]) == len(REASONS), f'not every reason reached: {reasons}'
    assert reasons['stale'] > 0
    print(f'\n[fuzz] {sent[0]} datagrams in {send_s:.1f} s ({dict(kinds)}): {malformed} malformed, '
          f'{len(expected_tags)} published as expected; dropped by reason {dict(sorted(reasons.items()))}')
