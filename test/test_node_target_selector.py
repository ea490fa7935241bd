"""target_selector as a process: the task's targets, the gaze that finds them, services,
the active_target parameter and live targets.

The node runs with the package's parameter file on its own ROS domain; the test is the rest
of the graph (a probe that publishes gaze and live targets, listens to what the node
publishes, calls its services and sets its parameters). Every assertion is on what comes out
of the node; every wait polls against a deadline.
"""
import math
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PointStamped, PoseStamped
import numpy as np
import pytest
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.parameter import Parameter
from std_msgs.msg import String
from std_srvs.srv import Trigger
from visualization_msgs.msg import Marker, MarkerArray

from fabric_guidance.core.geometry import ray_orientation, target_direction
from fabric_guidance.interface import (ACTIVE_TARGET, DIAGNOSTICS, GAZE, IMMERSIVE_FRAME, TARGET,
                                       TARGET_FOUND)
from fabric_guidance.nodes.qos import EVENT_QOS, LATCHED_QOS, SENSOR_QOS
from fabric_guidance.paths import node_parameters
from rosgraph import Graph, Probe, wait_until

pytestmark = pytest.mark.graph  # starts a process graph with DDS

PARAMS = node_parameters('params/guidance.yaml', 'target_selector')
NAMES = PARAMS['target_names']
POSITIONS = {n: tuple(PARAMS['target_positions'][3 * i:3 * i + 3]) for i, n in enumerate(NAMES)}
DWELL_S = PARAMS['dwell_s']
ACCEPTANCE_DEG = PARAMS['acceptance_deg']
#: The wearer's eyes (the gaze origin), immersive frame.
EYE = (0.0, 0.0, 1.2)
GAZE_RATE_HZ = 60.0
STATUS = 'target_selector: task'

#: Node up and the probe matched with it (cold start on a loaded 2-core machine).
STARTUP_DEADLINE_S = 20.0
#: A published message or a service call through the node.
REPLY_DEADLINE_S = 5.0
#: Gaze on the target -> target_found: the dwell plus delivery and slack.
FOUND_DEADLINE_S = DWELL_S + 2.0


def gaze_pose(direction, origin=EYE) -> PoseStamped:
    msg = PoseStamped()
    msg.header.frame_id = IMMERSIVE_FRAME
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = origin
    q = ray_orientation(direction)
    msg.pose.orientation.x, msg.pose.orientation.y, msg.pose.orientation.z, msg.pose.orientation.w = q
    return msg


def towards(target, off_deg: float = 0.0, origin=EYE) -> np.ndarray:
    """The direction from origin to target, turned off_deg about the vertical axis."""
    d = target_direction(origin, target)
    a = math.radians(off_deg)
    return np.array([d[0] * math.cos(a) - d[1] * math.sin(a), d[0] * math.sin(a) + d[1] * math.cos(a), d[2]])


def point(msg: PointStamped) -> tuple:
    return (msg.point.x, msg.point.y, msg.point.z)


class Selector:
    """A target_selector process and the probe that plays the rest of the graph."""

    def __init__(self, log_dir, name='selector_probe', **overrides):
        self.graph = Graph(log_dir)
        self.proc = self.graph.start('target_selector', **overrides)
        self.probe = Probe(self.graph.domain_id, name=name)
        # One ordered record of target and active_target, to check what a consumer sees after a name.
        self.events: list[tuple[str, object]] = []
        self._events_lock = threading.Lock()
        self.targets = self.probe.subscribe(PointStamped, TARGET, LATCHED_QOS,
                                            callback=lambda m: self._record('target', point(m)))
        self.names = self.probe.subscribe(String, ACTIVE_TARGET, LATCHED_QOS,
                                          callback=lambda m: self._record('name', m.data))
        self.found = self.probe.subscribe(String, TARGET_FOUND, EVENT_QOS)
        self.markers = self.probe.subscribe(MarkerArray, 'target_markers', LATCHED_QOS)
        self.diagnostics = self.probe.subscribe(DiagnosticArray, DIAGNOSTICS, 100)
        self.gaze_pub = self.probe.node.create_publisher(PoseStamped, GAZE, SENSOR_QOS)
        self.live_pubs = {}

    def _record(self, kind, value):
        with self._events_lock:
            self.events.append((kind, value))

    def start(self):
        wait_until(lambda: self.names and self.targets and self.gaze_pub.get_subscription_count() > 0,
                   STARTUP_DEADLINE_S, what='target_selector up and matched')
        return self

    def close(self):
        self.probe.close()
        self.graph.stop_all()

    def active(self) -> str | None:
        msg = self.probe.latest(ACTIVE_TARGET)
        return None if msg is None else msg.data

    def target(self) -> tuple | None:
        msg = self.probe.latest(TARGET)
        return None if msg is None else point(msg)

    def wait_active(self, name: str, position=None) -> None:
        """Wait until `name` is active and, when it has a position, the target is there."""
        wait_until(lambda: self.active() == name, REPLY_DEADLINE_S, what=f'active target {name!r}')
        if position is not None:
            wait_until(lambda: self.target() is not None and np.allclose(self.target(), position, atol=1e-9),
                       REPLY_DEADLINE_S, what=f'target at {position}')

    def trigger(self, service: str) -> Trigger.Response:
        """Call the selector's private service `service` (next_target, reset_sequence)."""
        return self.probe.call(Trigger, f'~/{service}', Trigger.Request(), REPLY_DEADLINE_S)

    def set_active(self, name: str):
        request = SetParameters.Request(parameters=[Parameter('active_target', value=name).to_parameter_msg()])
        return self.probe.call(SetParameters, '/target_selector/set_parameters', request,
                               REPLY_DEADLINE_S).results[0]

    def get_param(self, name: str):
        response = self.probe.call(GetParameters, '/target_selector/get_parameters',
                                   GetParameters.Request(names=[name]), REPLY_DEADLINE_S)
        return response.values[0]

    def look(self, direction, until, deadline_s: float, origin=EYE) -> float:
        """Publish gaze along `direction` at GAZE_RATE_HZ until until() holds; returns the time it
        took. Fails at the deadline."""
        start = time.monotonic()
        msg = gaze_pose(direction, origin)
        i = 0
        while not until():
            if time.monotonic() - start > deadline_s:
                raise AssertionError(f'timed out after {deadline_s:.1f} s of gaze')
            msg.header.stamp = self.probe.node.get_clock().now().to_msg()
            self.gaze_pub.publish(msg)
            i += 1
            delay = start + i / GAZE_RATE_HZ - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        return time.monotonic() - start

    def counters(self) -> dict:
        for array in reversed(list(self.diagnostics)):
            for st in array.status:
                if st.name == STATUS:
                    return {kv.key: kv.value for kv in st.values}
        return {}


@pytest.fixture(scope='module')
def selector(tmp_path_factory):
    """One node for the tests that begin with reset_sequence (so they do not depend on order);
    it also has a live target, bead, which is not in the sequence."""
    s = Selector(tmp_path_factory.mktemp('target_selector'), live_targets=['bead'])
    try:
        yield s.start()
    finally:
        s.close()


@pytest.fixture
def fresh(selector):
    """The shared node back at the start of the sequence, with nothing found pending."""
    assert selector.trigger('reset_sequence').success
    selector.wait_active(NAMES[0], POSITIONS[NAMES[0]])
    return selector


# ---------------------------------------------------------------------- tests

def test_starts_on_the_first_target_latched_for_a_late_joiner(tmp_path):
    s = Selector(tmp_path)
    try:
        s.start()
        first = NAMES[0]
        s.wait_active(first, POSITIONS[first])
        # A probe that joins later still gets the name, the position and the markers.
        with Probe(s.graph.domain_id, name='late_probe') as late:
            late.subscribe(PointStamped, TARGET, LATCHED_QOS)
            late.subscribe(String, ACTIVE_TARGET, LATCHED_QOS)
            late.subscribe(MarkerArray, 'target_markers', LATCHED_QOS)
            wait_until(lambda: late.latest(TARGET) and late.latest(ACTIVE_TARGET) and late.latest('target_markers'),
                       REPLY_DEADLINE_S, what='latched messages at the late probe')
            msg = late.latest(TARGET)
            assert point(msg) == pytest.approx(POSITIONS[first], abs=1e-12)
            assert msg.header.frame_id == IMMERSIVE_FRAME
            assert late.latest(ACTIVE_TARGET).data == first
            markers = late.latest('target_markers').markers
        spheres = {m.text: m for m in markers}
        assert set(spheres) == set(NAMES)
        for name, m in spheres.items():
            assert m.type == Marker.SPHERE and m.action == Marker.ADD and m.header.frame_id == IMMERSIVE_FRAME
            assert (m.scale.x, m.scale.y, m.scale.z) == pytest.approx((0.1, 0.1, 0.1))
            assert (m.pose.position.x, m.pose.position.y, m.pose.position.z) == pytest.approx(POSITIONS[name])
            rgba = (m.color.r, m.color.g, m.color.b, m.color.a)
            assert rgba == ((1.0, 0.0, 0.0, 1.0) if name == first else (1.0, 0.0, 1.0, 1.0))
        assert len({m.id for m in markers}) == len(markers)
        # While a target is active, its position is republished (10 Hz).
        n = len(s.targets)
        wait_until(lambda: len(s.targets) >= n + 3, 1.0, what='the target republished')
    finally:
        s.close()


def test_a_gaze_that_dwells_on_the_target_finds_it_and_the_next_becomes_active(fresh):
    first, second = NAMES[0], NAMES[1]
    n_found = len(fresh.found)
    with fresh._events_lock:
        n_events = len(fresh.events)
    # Inside the acceptance cone, not dead on: 4 deg off with a 5 deg acceptance.
    took = fresh.look(towards(POSITIONS[first], off_deg=ACCEPTANCE_DEG - 1.0), lambda: len(fresh.found) > n_found,
                      FOUND_DEADLINE_S)
    print(f'\n[dwell] found after {took:.3f} s of gaze (dwell_s {DWELL_S})')
    assert took >= DWELL_S
    assert [m.data for m in fresh.found[n_found:]] == [first]
    fresh.wait_active(second, POSITIONS[second])
    # A consumer that sees the new name gets the new position after it (never the old one).

    def targets_after_the_name():
        with fresh._events_lock:
            events = fresh.events[n_events:]
        at = events.index(('name', second))
        return [value for kind, value in events[at + 1:] if kind == 'target']
    after = wait_until(targets_after_the_name, REPLY_DEADLINE_S, what=f'a target after the name {second!r}')
    assert np.allclose(after[0], POSITIONS[second])
    assert fresh.get_param('active_target').string_value == second


def test_a_gaze_more_than_the_acceptance_angle_away_never_finds(fresh):
    first = NAMES[0]
    n_found = len(fresh.found)
    # 1.5 s of gaze 6 deg beside the target (five dwell times) ...
    away = towards(POSITIONS[first], off_deg=ACCEPTANCE_DEG + 1.0)
    start = time.monotonic()
    fresh.look(away, lambda: time.monotonic() - start > 5 * DWELL_S, 5 * DWELL_S + 1.0)
    assert len(fresh.found) == n_found and fresh.active() == first
    # ... counted for nothing: on target, the dwell starts only now.
    took = fresh.look(towards(POSITIONS[first]), lambda: len(fresh.found) > n_found, FOUND_DEADLINE_S)
    assert took >= DWELL_S
    assert [m.data for m in fresh.found[n_found:]] == [first]


def test_next_target_and_reset_sequence(fresh):
    for name in NAMES[1:]:
        response = fresh.trigger('next_target')
        assert response.success and name in response.message
        fresh.wait_active(name, POSITIONS[name])
    # After the last one: no target.
    response = fresh.trigger('next_target')
    assert response.success
    fresh.wait_active('')
    assert fresh.get_param('active_target').string_value == ''
    response = fresh.trigger('next_target')
    assert not response.success and 'reset_sequence' in response.message
    assert fresh.trigger('reset_sequence').success
    fresh.wait_active(NAMES[0], POSITIONS[NAMES[0]])


def test_active_target_parameter_rejects_unknown_names_and_activates_known_ones(fresh):
    result = fresh.set_active('nowhere')
    assert not result.successful and 'nowhere' in result.reason and 'unknown' in result.reason
    assert fresh.get_param('active_target').string_value == NAMES[0]
    name = NAMES[2]
    assert fresh.set_active(name).successful
    fresh.wait_active(name, POSITIONS[name])
    # The sequence goes on from there.
    assert fresh.trigger('next_target').success
    fresh.wait_active(NAMES[3], POSITIONS[NAMES[3]])


def test_a_live_target_is_mapped_into_the_immersive_frame(fresh):
    live_pub = fresh.probe.node.create_publisher(PoseStamped, 'live_targets/bead', SENSOR_QOS)
    wait_until(lambda: live_pub.get_subscription_count() > 0, REPLY_DEADLINE_S, what='live_targets/bead matched')
    bead = PoseStamped()
    bead.header.frame_id = 'microscope'   # live_frame_id: mapped by live_scale and live_offset
    bead.pose.position.x, bead.pose.position.y, bead.pose.position.z = 0.001, 0.0005, 0.0
    bead.pose.orientation.w = 1.0
    assert fresh.set_active('bead').successful
    wait_until(lambda: fresh.active() == 'bead', REPLY_DEADLINE_S, what='bead active')

    def arrived():
        live_pub.publish(bead)
        return fresh.target() is not None and np.allclose(fresh.target(), (1.0, 0.5, 1.2), atol=1e-9)
    # x 1000 (live_scale), + (0, 0, 1.2) (live_offset)
    wait_until(arrived, REPLY_DEADLINE_S, interval=0.05, what='the bead at (1.0, 0.5, 1.2)')
    # It moves: the target follows.
    bead.pose.position.y = -0.0005
    wait_until(lambda: (live_pub.publish(bead), fresh.target())[1] is not None and
               np.allclose(fresh.target(), (1.0, -0.5, 1.2), atol=1e-9),
               REPLY_DEADLINE_S, interval=0.05, what='the bead at (1.0, -0.5, 1.2)')
    # The markers follow too (waited for: a markers message already in flight when the bead
    # moved still shows it where it was).
    wait_until(lambda: next((m for m in fresh.markers[-1].markers if m.text == 'bead' and m.action == Marker.ADD
                             and m.color.g == 0.0
                             and (m.pose.position.x, m.pose.position.y) == pytest.approx((1.0, -0.5))), None),
               REPLY_DEADLINE_S, what='a red bead marker at (1.0, -0.5)')
    fresh.probe.node.destroy_publisher(live_pub)


@pytest.fixture
def own_selector(tmp_path):
    """A node of the test's own (the shared one's probe lost its gaze match after this test's
    burst of refused poses in a full module run: kept apart so the tests stay independent)."""
    s = Selector(tmp_path, live_targets=['bead'])
    try:
        yield s.start()
    finally:
        s.close()


def test_a_live_target_in_an_unknown_frame_is_refused_with_one_line(own_selector):
    """A pose in a frame no transform is known from (not live_frame_id's microscope, not the
    immersive frame) would be mis-placed: refused, counted, one throttled line. A pose in the
    immersive frame is taken as it is."""
    fresh = own_selector
    live_pub = fresh.probe.node.create_publisher(PoseStamped, 'live_targets/bead', SENSOR_QOS)
    wait_until(lambda: live_pub.get_subscription_count() > 0, REPLY_DEADLINE_S, what='live_targets/bead matched')
    bead = PoseStamped()
    bead.pose.position.x, bead.pose.position.y, bead.pose.position.z = 2.0, 0.25, 1.0
    bead.pose.orientation.w = 1.0
    bead.header.frame_id = IMMERSIVE_FRAME
    assert fresh.set_active('bead').successful
    wait_until(lambda: (live_pub.publish(bead), fresh.target())[1] is not None and
               np.allclose(fresh.target(), (2.0, 0.25, 1.0), atol=1e-9),
               REPLY_DEADLINE_S, interval=0.05, what='the bead at (2.0, 0.25, 1.0), immersive as is')
    before = int(fresh.counters().get('live_wrong_frame', 0))
    bead.header.frame_id = 'camera_optical'
    bead.pose.position.x = 0.001
    for _ in range(20):
        live_pub.publish(bead)
        time.sleep(0.02)
    wait_until(lambda: int(fresh.counters().get('live_wrong_frame', 0)) > before, 3.0,
               what='poses in a wrong frame counted on /diagnostics')
    assert np.allclose(fresh.target(), (2.0, 0.25, 1.0), atol=1e-9), 'a pose in an unknown frame moved the target'
    log = fresh.graph.log('target_selector')
    assert log.count("live target 'bead': pose in frame 'camera_optical' refused") == 1, log[-2000:]


def test_invalid_gaze_is_ignored_and_counted(fresh):
    first = NAMES[0]
    n_found = len(fresh.found)
    bad = gaze_pose(towards(POSITIONS[first]))
    bad.pose.orientation.x = bad.pose.orientation.y = bad.pose.orientation.z = bad.pose.orientation.w = 0.0
    nan = gaze_pose(towards(POSITIONS[first]))
    nan.pose.position.x = math.nan
    before = int(fresh.counters().get('invalid_gaze', 0))
    for _ in range(10):
        fresh.gaze_pub.publish(bad)
        fresh.gaze_pub.publish(nan)
        time.sleep(1 / GAZE_RATE_HZ)   # the rate of a gaze stream
    wait_until(lambda: int(fresh.counters().get('invalid_gaze', 0)) > before, 3.0,
               what='invalid gaze counted on /diagnostics')
    assert fresh.proc.poll() is None
    # The node still finds the target.
    fresh.look(towards(POSITIONS[first]), lambda: len(fresh.found) > n_found, FOUND_DEADLINE_S)
    assert [m.data for m in fresh.found[n_found:]] == [first]


@pytest.mark.parametrize('overrides, needle', [
    ({'target_positions': [1.0, 2.0, 3.0]}, "'target_positions'"),
    ({'target_names': ['a', 'a'], 'target_positions': [1.0, 0.0, 1.0, 2.0, 0.0, 1.0]}, "'target_names'"),
    ({'sequence': ['front_left', 'nowhere']}, "'sequence'"),
    ({'active_target': 'nowhere'}, "'active_target'"),
])
def test_bad_targets_end_the_start_up_with_a_message(tmp_path, overrides, needle):
    graph = Graph(tmp_path)
    try:
        proc = graph.start('target_selector', **overrides)
        assert proc.wait(STARTUP_DEADLINE_S) == 1
        log = graph.log('target_selector')
        assert 'cannot start' in log and needle in log, log
    finally:
        graph.stop_all()


def test_without_autostart_waits_for_next_target_and_the_speed_protocol_returns_to_front(tmp_path):
    """autostart false: nothing active until next_target. return_to_front (the paper's speed
    protocol): after a find no target is active until the gaze is back at the front (+x)."""
    s = Selector(tmp_path, autostart=False, return_to_front=True)
    try:
        wait_until(lambda: s.names and s.gaze_pub.get_subscription_count() > 0, STARTUP_DEADLINE_S,
                   what='target_selector up and matched')
        assert s.active() == ''
        assert s.trigger('next_target').success
        first, second = NAMES[0], NAMES[1]
        s.wait_active(first, POSITIONS[first])
        s.look(towards(POSITIONS[first]), lambda: s.found, FOUND_DEADLINE_S)
        s.wait_active('')
        # Still looking at the found target: the next one does not come.
        held = time.monotonic()
        while time.monotonic() - held < 3 * DWELL_S:
            s.gaze_pub.publish(gaze_pose(towards(POSITIONS[first])))
            time.sleep(1 / GAZE_RATE_HZ)
        assert s.active() == ''
        # Back at the front for the dwell: the next target of the sequence.
        s.look((1.0, 0.0, 0.0), lambda: s.active() == second, FOUND_DEADLINE_S)
        s.wait_active(second, POSITIONS[second])
    finally:
        s.close()


def test_a_study_session_places_its_target_and_the_dwell_alone_finds_nothing(tmp_path):
    """target_positions set at run time with active_target in one call (the study session's
    target at an angle); with found_by_dwell false the gaze on it finds nothing (the session
    judges the key press); a wrong number of values is refused, naming the parameter."""
    from rcl_interfaces.srv import SetParametersAtomically
    s = Selector(tmp_path, target_names=['study'], target_positions=[2.0, 0.0, 1.2],
                 found_by_dwell=False).start()
    try:
        def set_atomically(**values):
            request = SetParametersAtomically.Request(
                parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in values.items()])
            return s.probe.call(SetParametersAtomically, '/target_selector/set_parameters_atomically', request,
                                REPLY_DEADLINE_S).result
        placed = (1.5, 1.0, 1.6)
        assert set_atomically(target_positions=list(placed), active_target='study').successful
        s.wait_active('study', placed)
        start = time.monotonic()
        s.look(towards(placed), lambda: time.monotonic() - start > 5 * DWELL_S, 5 * DWELL_S + 1.0)
        assert len(s.found) == 0
        bad = set_atomically(target_positions=[1.0, 2.0])
        assert not bad.successful and 'target_positions' in bad.reason
        assert s.target() == placed
        assert set_atomically(found_by_dwell=True).successful
        s.look(towards(placed), lambda: len(s.found) > 0, FOUND_DEADLINE_S)
        assert [m.data for m in s.found] == ['study']
    finally:
        s.close()
