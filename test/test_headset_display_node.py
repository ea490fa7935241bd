"""headset_display in this process, its datagrams received on a UDP socket of the test and read
as the headset reads them (display_wire.DisplayView, the twin of the C# DisplayState): event
copies against the seq rule when other messages go out between them; the speed task's dummies
seen from the eye. The test thread calls the node's callbacks and spins its timers itself, so
what is sent between two copies is the test's doing, not a race."""
import contextlib
import math
import socket
import time

import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from scipy import stats
from std_msgs.msg import String
from visualization_msgs.msg import Marker, MarkerArray

from fabric_guidance.core import display_wire as dw
from fabric_guidance.graph.process_graph import fresh_domain_id
from fabric_guidance.live_study.operator import target_position
from fabric_guidance.nodes.headset_display import EVENT_SENDS, HeadsetDisplay

pytestmark = pytest.mark.timing


class Rig:
    """The node, its executor and the socket its datagrams arrive on."""

    def __init__(self, node, executor, sock):
        self.node, self.executor, self.sock = node, executor, sock
        self.received: list[dw.DisplayMessage] = []
        self.view = dw.DisplayView()           # the headset, fed in the order received

    def drain(self) -> None:
        while True:
            try:
                self.received.append(dw.decode(self.sock.recv(2048)))
            except BlockingIOError:
                return
            self.view.apply(self.received[-1])

    def spin_until(self, predicate, timeout: float, what: str, each=lambda: None) -> None:
        """Run `each`, spin the node once and read what arrived, until predicate() or the deadline."""
        deadline = time.monotonic() + timeout
        while True:
            each()
            self.executor.spin_once(timeout_sec=0.005)
            self.drain()
            if predicate():
                return
            if time.monotonic() > deadline:
                raise AssertionError(f'timed out after {timeout:.1f} s waiting for {what}')


@contextlib.contextmanager
def display_node(**params):
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(('127.0.0.1', 0))
    sock.setblocking(False)
    context = Context()
    rclpy.init(context=context, domain_id=fresh_domain_id())
    values = {'headset_address': '127.0.0.1', 'display_port': sock.getsockname()[1], **params}
    node = executor = None
    try:
        node = HeadsetDisplay(context=context, parameter_overrides=[Parameter(k, value=v) for k, v in values.items()])
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        yield Rig(node, executor, sock)
    finally:
        if executor is not None:
            executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.shutdown(context=context)
        sock.close()


def shown(msgs, order=None) -> list[str]:
    """What a headset receiving `msgs` (in `order`, indices) newly shows, line by line."""
    view = dw.DisplayView()
    return [line for i in (range(len(msgs)) if order is None else order) for line in view.apply(msgs[i])]


# --- events: repeats and the seq rule ---------------------------------------------------------

def test_event_copies_sent_among_other_messages_are_never_stale_and_repair_a_lost_first_copy():
    with display_node(refresh_hz=50.0) as rig:
        rig.node.on_study(String(data='found t1'))
        prompts = iter(range(10 ** 6))
        # a new prompt before every spin: whatever the timers send, prompts go out between copies
        rig.spin_until(lambda: sum(m.kind == 'event' for m in rig.received) >= EVENT_SENDS, 10.0,
                       what=f'{EVENT_SENDS} copies of the event',
                       each=lambda: rig.node.on_study(String(data=f'prompt step {next(prompts)}')))
    msgs = rig.received
    copies = [i for i, m in enumerate(msgs) if m.kind == 'event']
    assert len(copies) == EVENT_SENDS and len({msgs[i].fields['event_id'] for i in copies}) == 1
    # the case in question: other messages sent after the first copy, before the others
    assert any(m.kind != 'event' for m in msgs[copies[0]:copies[-1]]), [m.kind for m in msgs]
    # (a) in the order sent, no copy is stale: each is ahead of everything sent before it
    view = dw.DisplayView()
    stale = []
    for i, m in enumerate(msgs):
        before = view.stale
        view.apply(m)
        if view.stale > before:
            stale.append((i, m.kind, m.seq))
    assert stale == [], f'stale: {stale}'
    assert shown(msgs).count('found t1') == 1
    # (b) the first copy lost: a later copy shows the event, once
    assert shown(msgs, [i for i in range(len(msgs)) if i != copies[0]]).count('found t1') == 1
    # (c) reordered by the network: any two neighbours swapped, or the first copy arriving last
    # (stale then): the event is shown once
    orders = [list(range(len(msgs)))]
    for i in range(len(msgs) - 1):
        order = list(range(len(msgs)))
        order[i], order[i + 1] = order[i + 1], order[i]
        orders.append(order)
    orders.append([i for i in range(len(msgs)) if i != copies[0]] + [copies[0]])
    for order in orders:
        assert shown(msgs, order).count('found t1') == 1, order


# --- the speed task's dummies, seen from the eye ---------------------------------------------

#: The paper's speed task (config/params/study-speed.yaml, guidance.yaml).
PAPER = dict(dummies=50, dummy_seed=7, dummy_radius_m=0.05, dummy_azimuth_deg=60.0, dummy_elevation_deg=30.0)


def markers(*targets) -> MarkerArray:
    """target_markers as target_selector publishes them: (name, REP 103 position) each."""
    array = MarkerArray()
    for i, (name, p) in enumerate(targets):
        m = Marker(ns='targets', id=i, action=Marker.ADD, text=name)
        m.pose.position.x, m.pose.position.y, m.pose.position.z = (float(c) for c in p)
        array.markers.append(m)
    return array


def seen_from(eye, rig) -> tuple[np.ndarray, np.ndarray]:
    """The active target and the dummies the headset shows, REP 103, relative to the eye."""
    target = next(t for t in rig.view.targets if t['id'] == rig.view.active)
    return (np.array(dw.from_unity(target['position'])) - eye,
            np.array([dw.from_unity(p) for p in rig.view.dummies]) - eye)


def separation_deg(radius_m: float, distance_m: float) -> float:
    """The rule: two spheres at one distance from the eye are apart by twice the angle a radius subtends."""
    return math.degrees(2.0 * math.asin(radius_m / distance_m))


def angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ua, ub = a / np.linalg.norm(a, axis=-1, keepdims=True), b / np.linalg.norm(b, axis=-1, keepdims=True)
    chord = np.linalg.norm(ua[:, None] - ub[None], axis=2)
    return np.degrees(2.0 * np.arcsin(np.clip(chord / 2.0, 0.0, 1.0)))


def test_the_dummies_are_around_the_eye_at_the_targets_distance_within_the_field_and_apart():
    """60 targets where the study places them (2 m from the eye at 1.2 m, within the field),
    each a new set as the headset assembles it: every dummy, seen from the eye, within
    +-60 deg azimuth and +-30 deg elevation, at the target's distance (to the wire's 0.1 mm),
    apart from the others and from the target; over all sets as many above eye level as
    below, and sin(elevation) uniform (KS; the seeds are fixed, so the outcome is too)."""
    eye = np.array([0.0, 0.0, 1.2])        # eye_height_m's default, the study's eye height
    tolerance_deg = math.degrees(2e-4 / 2.0)   # the wire's rounding (1e-4 m per coordinate) at 2 m
    picks = np.random.default_rng(3)
    sin_el = []
    with display_node(**PAPER) as rig:
        for k in range(60):
            rig.node.on_markers(markers(('study', target_position(picks.uniform(-60, 60), picks.uniform(-30, 30),
                                                                  eye[2]))))
            rig.node.on_active(String(data='study'))
            rig.spin_until(lambda: rig.view.dummy_set == rig.node.dummy_set == k + 1 and rig.view.active == 'study',
                           10.0, what=f'dummy set {k + 1} at the headset')
            target, dummies = seen_from(eye, rig)
            distance = np.linalg.norm(target)
            assert len(dummies) == 50
            d = np.linalg.norm(dummies, axis=1)
            elevation = np.degrees(np.arcsin(dummies[:, 2] / d))
            azimuth = np.degrees(np.arctan2(dummies[:, 1], dummies[:, 0]))
            assert np.all(np.abs(elevation) <= 30.0 + tolerance_deg), (elevation.min(), elevation.max())
            assert np.all(np.abs(azimuth) <= 60.0 + tolerance_deg), (azimuth.min(), azimuth.max())
            assert np.all(np.abs(d - distance) <= 1e-4), np.abs(d - distance).max()
            apart = separation_deg(0.05, distance) - tolerance_deg
            assert (angles_deg(dummies, dummies) + 360.0 * np.eye(50)).min() >= apart
            assert angles_deg(dummies, target[None]).min() >= apart
            sin_el += list(dummies[:, 2] / d)
            rig.node.on_active(String(data=''))
    sin_el = np.array(sin_el)
    assert 0.45 <= np.mean(sin_el > 0.0) <= 0.55, np.mean(sin_el > 0.0)   # not lopsided
    assert stats.kstest(sin_el, 'uniform', args=(-0.5, 1.0)).pvalue > 0.01


def test_a_set_waits_for_the_targets_position_and_follows_a_marker_overtaken_by_the_activation():
    eye = np.array([0.0, 0.0, 1.5])
    a, b, c = (target_position(yaw, pitch, eye[2], 1.5) for yaw, pitch in ((20, 10), (-40, -20), (0, 25)))

    def around(where) -> bool:
        placed = np.array([dw.from_unity(p) for p in rig.node.dummy_positions]) - eye
        offset = np.array(where) - eye
        return (len(placed) == 50 and np.allclose(np.linalg.norm(placed, axis=1), np.linalg.norm(offset), atol=1e-4)
                and angles_deg(placed, offset[None]).min() >= separation_deg(0.05, 1.5) - 0.01)
    with display_node(eye_height_m=float(eye[2]), **PAPER) as rig:
        rig.node.on_active(String(data='study'))           # its position not known yet: no set
        assert rig.node.dummy_set == 0 and rig.node.dummy_positions == []
        rig.node.on_markers(markers(('study', a)))
        assert rig.node.dummy_set == 1 and around(a)
        rig.node.on_markers(markers(('study', a)))         # the same place again: the same set
        assert rig.node.dummy_set == 1
        # the next trial: the activation arrives before the marker that moved the target
        rig.node.on_active(String(data=''))
        rig.node.on_active(String(data='study'))
        assert rig.node.dummy_set == 2 and around(a)
        rig.node.on_markers(markers(('study', b)))
        assert rig.node.dummy_set == 3 and around(b)
        rig.node.on_markers(markers(('study', c)))         # only the first marker after an activation
        assert rig.node.dummy_set == 3


def test_a_field_too_small_gets_as_many_dummies_as_fit_and_a_warning_naming_the_parameters(capfd):
    with display_node(dummies=200, dummy_radius_m=0.2, dummy_azimuth_deg=10.0, dummy_elevation_deg=10.0) as rig:
        rig.node.on_markers(markers(('t', target_position(45.0, 0.0, 1.2))))   # outside the field
        rig.node.on_active(String(data='t'))   # (bounded candidates: test_dummies.py)
        assert 1 <= len(rig.node.dummy_positions) < 10, len(rig.node.dummy_positions)
    err = capfd.readouterr().err
    assert 'dummies fit apart' in err and all(name in err for name in (
        'dummies', 'dummy_radius_m', 'dummy_azimuth_deg', 'dummy_elevation_deg', 'eye_height_m')), err
