"""The headset link's Python side (docs/headset_wire_format.md): display messages, the clock
exchange messages and the clock estimator, without ROS."""
import json
import math
import random

from hypothesis import given, settings, strategies as st
import pytest

from fabric_guidance.core import display_wire as dw
from fabric_guidance.core.clock_sync import (MAX_CARRIED_S, MAX_DATAGRAM_BYTES, ClockEcho, ClockEstimator, answer_ping,
                                             capture_delay, encode_ping, parse_ping, parse_uplink)
from fabric_guidance.core.gaze_wire import Confirm, GazeSample, WireFormatError, encode_confirm, encode_datagram

IDS = st.text(min_size=0, max_size=80)
POINT = st.tuples(*[st.floats(-1e4, 1e4, allow_nan=False)] * 3)
TARGET = st.fixed_dictionaries({'id': IDS, 'position': POINT, 'role': st.sampled_from(dw.ROLES)})
FIELDS = {
    'targets': st.fixed_dictionaries({'active': IDS, 'targets': st.lists(TARGET, max_size=20)}),
    'dummies': st.integers(1, 8).flatmap(lambda parts: st.fixed_dictionaries({
        'set': st.integers(0, 2 ** 32 - 1), 'part': st.integers(0, parts - 1), 'parts': st.just(parts),
        'radius_m': st.floats(0.001, 10.0), 'positions': st.lists(POINT, max_size=40)})),
    'event': st.fixed_dictionaries({'event_id': st.integers(0, 2 ** 32 - 1), 'event': st.sampled_from(dw.EVENTS),
                                    'target': IDS}),
    'prompt': st.fixed_dictionaries({'text': st.text(max_size=300), 'step': st.integers(0, 2 ** 32 - 1),
                                     'steps': st.integers(0, 2 ** 32 - 1)}),
    'phrase': st.fixed_dictionaries({'text': st.text(max_size=300)}),
}


@settings(max_examples=300)
@given(st.sampled_from(sorted(dw.KINDS)).flatmap(lambda k: st.tuples(st.just(k), FIELDS[k])),
       st.integers(0, 2 ** 40), st.floats(0, 2e9))
def test_every_display_message_encodes_within_the_limit_and_decodes_to_what_was_meant(kind_fields, seq, stamp):
    kind, fields = kind_fields
    data = dw.encode(kind, seq, stamp, **fields)
    assert len(data) <= MAX_DATAGRAM_BYTES
    msg = dw.decode(data)
    assert (msg.kind, msg.seq, msg.stamp) == (kind, seq % 2 ** 32, stamp)
    for name, value in fields.items():
        got = msg.fields[name]
        if name in ('active', 'target'):
            assert got == value[:dw.MAX_ID_CHARS]
        elif name == 'targets':
            assert len(got) == min(len(value), dw.MAX_TARGETS)
            for g, v in zip(got, value):
                assert g['id'] == v['id'][:dw.MAX_ID_CHARS] and g['role'] == v['role']
                assert max(abs(a - b) for a, b in zip(g['position'], v['position'])) <= 0.5e-4 + 1e-9
        elif name == 'positions':
            assert len(got) == min(len(value), dw.MAX_DUMMIES_PER_PART)
        elif name == 'text':
            assert len(got) <= dw.MAX_TEXT_CHARS
        elif name != 'radius_m':
            assert got == value


@given(st.binary(max_size=1400))
def test_any_bytes_decode_to_a_message_or_a_reasoned_error(data):
    try:
        dw.decode(data)
    except WireFormatError as exc:
        assert exc.reason in ('oversize', 'encoding', 'json', 'non_finite', 'not_object', 'version', 'kind',
                              'missing_field', 'type', 'range')


def good(**changes):
    msg = {'version': 1, 'kind': 'dummies', 'seq': 3, 'stamp': 1.0, 'set': 2, 'part': 0, 'parts': 2,
           'radius_m': 0.05, 'positions': [[1, 2, 3]]}
    msg.update(changes)
    return json.dumps(msg).encode()


@pytest.mark.parametrize('data, reason', [
    (good(version=2), 'version'),
    (good(kind='dance'), 'kind'),
    (good(kind='clock_ping'), 'kind'),
    (good(part=2), 'range'),
    (good(parts=9, part=0), 'range'),
    (good(positions=[[1, 2]]), 'type'),
    (good(positions=[[1, 2, 1e5]]), 'range'),
    (good(radius_m=0), 'range'),
    (good(seq=-1), 'range'),
    (good(set='2'), 'type'),
    (b'{"version":1,"kind":"phrase","seq":1,"stamp":1}', 'missing_field'),
    (b'{"version":1,"kind":"phrase","seq":1,"stamp":1,"text":NaN}', 'non_finite'),
    (b' ' * 1201, 'oversize'),
])
def test_a_bad_display_message_is_rejected_with_its_reason(data, reason):
    with pytest.raises(WireFormatError) as err:
        dw.decode(data)
    assert err.value.reason == reason, str(err.value)


def test_unity_positions_are_the_inverse_of_the_bridges_conversion():
    # Unity (x, y, z) -> REP 103 (z, -x, y) in gaze_wire; 1.5 m ahead, 0.5 m left, 0.2 m up:
    assert dw.to_unity([1.5, 0.5, 0.2]) == [-0.5, 0.2, 1.5]
    assert dw.from_unity(dw.to_unity([1.5, 0.5, 0.2])) == [1.5, 0.5, 0.2]


def test_ping_echo_round_trip_copies_t1_and_carries_the_headset_times():
    ping = encode_ping(7, 12.25)
    assert parse_ping(ping) == (7, 12.25)
    echo = parse_uplink(answer_ping(ping, 1000.5, 1000.5001), 1024)
    assert echo == ClockEcho(7, 12.25, 1000.5, 1000.5001)
    assert answer_ping(b'{"version":1,"kind":"clock_echo"}', 1.0, 1.0) is None
    assert answer_ping(b'junk', 1.0, 1.0) is None


def test_uplink_tells_gaze_from_echo_and_rejects_other_kinds():
    gaze = encode_datagram(1, 5.0, [0, 1.6, 0], [0, 0, 1], [0, 1.6, 0], [0, 0, 0, 1], True)
    assert isinstance(parse_uplink(gaze, 1024), GazeSample)
    tagged = json.loads(gaze)
    tagged['kind'] = 'gaze'
    assert isinstance(parse_uplink(json.dumps(tagged).encode(), 1024), GazeSample)
    tagged['kind'] = 'targets'
    with pytest.raises(WireFormatError) as err:
        parse_uplink(json.dumps(tagged).encode(), 1024)
    assert err.value.reason == 'kind'
    with pytest.raises(WireFormatError) as err:
        parse_uplink(b'{"version":1,"kind":"clock_echo","ping_seq":1,"t1":1,"t2":2}', 1024)
    assert err.value.reason == 'missing_field'


def exchange(rng, t1, offset, drift, up, down, jitter):
    """One exchange over paths of delay up / down (+ uniform jitter); the headset clock is
    bridge * (1 + drift) + offset."""
    d1, d2 = up + rng.uniform(0, jitter), down + rng.uniform(0, jitter)
    t2 = (t1 + d1) * (1 + drift) + offset
    t3 = t2 + 0.0002
    t4 = (t3 - offset) / (1 + drift) + d2
    return ClockEcho(0, t1, t2, t3), t4


@settings(max_examples=60, deadline=None)
@given(offset=st.floats(-1e5, 1e5), drift_ppm=st.floats(-200, 200), up=st.floats(0, 0.05),
       down=st.floats(0, 0.05), jitter=st.floats(0, 0.03), seed=st.integers(0, 2 ** 16))
def test_the_estimate_stays_within_the_bound_it_reports(offset, drift_ppm, up, down, jitter, seed):
    rng, est, drift = random.Random(seed), ClockEstimator(window_s=30.0), drift_ppm * 1e-6
    for i in range(250):
        echo, t4 = exchange(rng, 10.0 + 0.2 * i, offset, drift, up, down, jitter)
        assert est.add(echo, t4) is None
        e = est.estimate()
        if i < 2:
            assert e is None
            continue
        truth = t4 * drift + offset   # headset minus bridge at t4
        error, bound = abs(e.offset_at(t4) - truth), e.bound_at(t4)
        assert error <= bound + 1e-6, (i, error, bound)   # 1 us: where in the exchange the offset is read
    # Asymmetric paths shift the offset by half the difference, as the spec says, and no more.
    assert abs(e.offset_at(t4) - truth) <= abs(up - down) / 2 + jitter + 1e-4
    assert e.bound_at(t4) <= (up + down) / 2 + jitter + 3e-3


def test_a_capture_is_not_believed_on_an_estimate_carried_too_long_without_echoes():
    """Three exchanges (a settling estimate), then the headset stops answering pings: the drift
    they fit is 2 % off, which 20 s on would stamp a sample captured 10 ms before its receipt
    0.4 s old (the controller ages gaze from its stamp and vents at 0.3 s). The bridge stamps it on
    receipt instead, and believes the capture again once echoes come back."""
    est, offset = ClockEstimator(), 1000.0

    def echo(k, t1, up, down):
        t2 = t1 + up + offset
        est.add(ClockEcho(k, t1, t2, t2 + 0.0002), t1 + up + 0.0002 + down)
    for k, (up, down) in enumerate(((0.016, 0.024), (0.020, 0.020), (0.024, 0.016))):
        echo(k, 0.2 * k, up, down)
    e = est.estimate()
    delay, why = capture_delay(e, 0.89 + offset, 0.9, 1.0)        # half a second on: believed
    assert why == '' and delay == pytest.approx(0.01, abs=0.03)
    assert e.carried_at(0.9) <= MAX_CARRIED_S
    capture, received = 20.39 + offset, 20.4
    assert received - e.to_bridge(capture, received) > 0.3           # the stamp it gave before
    assert capture_delay(e, capture, received, 1.0) == (None, 'carried')
    echo(3, 20.2, 0.02, 0.02)
    delay, why = capture_delay(est.estimate(), capture, received, 1.0)
    assert why == '' and delay == pytest.approx(0.01, abs=0.03)
    # A capture after its own receipt, beyond the bound: the headset's clock jumped ahead.
    assert capture_delay(est.estimate(), received + 1.0 + offset, received, 1.0) == (None, 'future')


def test_a_restarted_headset_clock_starts_the_estimate_again():
    rng, est = random.Random(3), ClockEstimator()
    for i in range(20):
        est.add(*exchange(rng, 0.2 * i, 1000.0, 0.0, 0.01, 0.01, 0.002))
    assert abs(est.estimate().offset_at(4.0) - 1000.0) < 0.01
    # The app restarts: its clock starts again near 0.
    assert est.add(*exchange(rng, 4.2, -4.0, 0.0, 0.01, 0.01, 0.002)) == 'restart'
    assert est.restarts == 1 and est.estimate() is None
    for i in range(22, 30):
        est.add(*exchange(rng, 0.2 * i, -4.0, 0.0, 0.01, 0.01, 0.002))
    assert abs(est.estimate().offset_at(6.0) + 4.0) < 0.01


@pytest.mark.parametrize('t1, t2, t3, t4, why', [
    (1.0, 5.0, 4.0, 2.0, 'invalid'),          # the headset answered before it received
    (2.0, 5.0, 5.0, 1.0, 'invalid'),          # arrived before it was sent
    (1.0, 5.0, 5.0, math.nan, 'invalid'),
    (1.0, 5.0, 5.0, 3.0, 'rtt'),              # a 2 s round trip: beyond max_rtt_s
])
def test_impossible_exchanges_are_rejected_and_counted(t1, t2, t3, t4, why):
    est = ClockEstimator(max_rtt_s=0.5)
    assert est.add(ClockEcho(1, t1, t2, t3), t4) == why
    assert est.rejected[why] == 1 and est.exchanges == 0


def test_memory_stays_bounded_whatever_the_ping_rate():
    est = ClockEstimator(window_s=1e6)
    for i in range(10000):
        est.add(ClockEcho(i, i * 1e-3, 5.0 + i * 1e-3, 5.0 + i * 1e-3), i * 1e-3 + 1e-4)
    assert est.exchanges <= 4096


# --- the confirm press (uplink) -----------------------------------------------------------------

@given(st.integers(0, 2 ** 32 - 1), st.floats(-1e12, 1e12, allow_nan=False))
def test_a_confirm_press_round_trips(press_id, stamp):
    press = parse_uplink(encode_confirm(press_id, stamp), 1024)
    assert press == Confirm(press_id, stamp)


@pytest.mark.parametrize('body, reason, field', [
    ('"press_id":1', 'missing_field', 'stamp'),
    ('"stamp":1', 'missing_field', 'press_id'),
    ('"press_id":1.0,"stamp":1', 'type', 'press_id'),
    ('"press_id":true,"stamp":1', 'type', 'press_id'),
    ('"press_id":-1,"stamp":1', 'range', 'press_id'),
    ('"press_id":4294967296,"stamp":1', 'range', 'press_id'),
    ('"press_id":' + '9' * 500 + ',"stamp":1', 'range', 'press_id'),
    ('"press_id":1,"stamp":"3.5"', 'type', 'stamp'),
    ('"press_id":1,"stamp":null', 'type', 'stamp'),
    ('"press_id":1,"stamp":1e400', 'non_finite', 'stamp'),
    ('"press_id":1,"stamp":NaN', 'non_finite', 'stamp'),
])
def test_a_bad_confirm_is_rejected_naming_its_field(body, reason, field):
    with pytest.raises(WireFormatError) as err:
        parse_uplink(('{"version":1,"kind":"confirm",' + body + '}').encode(), 1024)
    assert err.value.reason == reason and field in str(err.value)


def test_a_confirm_of_another_version_or_kind_is_not_a_confirm():
    with pytest.raises(WireFormatError) as err:
        parse_uplink(b'{"version":2,"kind":"confirm","press_id":1,"stamp":1}', 1024)
    assert err.value.reason == 'version'
    with pytest.raises(WireFormatError) as err:
        parse_uplink(b'{"version":1,"kind":"Confirm","press_id":1,"stamp":1}', 1024)
    assert err.value.reason == 'kind'
    # Unknown fields are ignored, as in every uplink message.
    assert parse_uplink(b'{"version":1,"kind":"confirm","press_id":7,"stamp":2,"hand":"left"}', 1024) == Confirm(7, 2.0)


# --- the sender: seq in send order, events repeated ---------------------------------------

SCHEDULE = st.lists(st.tuples(st.sampled_from(['event', 'prompt', 'wait']), st.floats(0.0, 0.05)), max_size=40)


def send_schedule(steps):
    """A DisplaySender driven by (what, seconds before it) steps: events and prompts at those
    times, due copies sent before each step and all at the end; the datagrams in send order."""
    sender, now, sent, events = dw.DisplaySender(sends=3, repeat_s=0.02), 0.0, [], 0
    for what, dt in steps:
        now += dt
        sent += sender.due(now, now)
        if what == 'event':
            events += 1
            sent.append(sender.event('found', f'e{events}', now, now))
        elif what == 'prompt':
            sent.append(sender.encode('prompt', now, text=f'p{len(sent)}', step=0, steps=0))
    sent += sender.due(now + 1.0, now + 1.0)
    assert sender.pending() == 0
    return [dw.decode(d) for d in sent], events


@given(SCHEDULE, st.data())
def test_every_event_copy_is_ahead_of_what_was_sent_before_it_so_a_lost_copy_is_repaired(steps, data):
    msgs, events = send_schedule(steps)
    # seq +1 per datagram in send order, copies included; three copies of each event, one id
    assert [m.seq for m in msgs] == list(range(len(msgs)))
    copies = [m for m in msgs if m.kind == 'event']
    assert len(copies) == 3 * events
    assert all(sum(1 for c in copies if c.fields['event_id'] == i) == 3 for i in range(1, events + 1))
    # in order, none lost: nothing stale, each event shown once
    view = dw.DisplayView()
    shown = [line for m in msgs for line in view.apply(m) if line.startswith('found')]
    assert view.stale == 0 and shown == [f'found e{i}' for i in range(1, events + 1)]
    # whatever is lost: each event with a copy through is shown exactly once, in order
    lost = data.draw(st.sets(st.integers(0, max(0, len(msgs) - 1))), label='lost')
    view = dw.DisplayView()
    shown = [line for i, m in enumerate(msgs) if i not in lost for line in view.apply(m) if line.startswith('found')]
    through = [f"found {c.fields['target']}" for i, c in enumerate(msgs) if i not in lost and c.kind == 'event']
    assert view.stale == 0 and shown == list(dict.fromkeys(through))


def test_event_copies_go_in_the_order_due_and_at_most_capacity_wait():
    def targets(datagrams):
        return [dw.decode(d).fields['target'] for d in datagrams]
    sender = dw.DisplaySender(sends=3, repeat_s=0.02)
    sender.event('next', 'a', 0.0, 0.0)        # copies due at 0.02, 0.04
    sender.event('found', 'b', 0.01, 0.01)     # at 0.03, 0.05
    assert targets(sender.due(0.019, 0.0)) == [] and targets(sender.due(1.0, 1.0)) == ['a', 'b', 'a', 'b']
    sender = dw.DisplaySender(sends=3, repeat_s=0.02, capacity=3)
    sender.event('next', 'a', 0.0, 0.0)
    sender.event('found', 'b', 0.01, 0.01)     # four waiting: the one due first is dropped
    assert sender.pending() == 3 and targets(sender.due(1.0, 1.0)) == ['b', 'a', 'b']
