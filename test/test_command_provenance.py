"""Commands that must never reach the registers (docs/safety.md, "Where a command comes from").

The rig of test_node_plc.py (mock_plc and plc_output as processes, the test playing the
controller as a node named pressure_controller, the PLC read back with a Modbus client) and:

- a second publisher of pressure_command (another node): refused, counted, registers untouched;
- a bag recorded by the package's bag_recorder, its pressure_command played back into the live
  graph as `ros2 bag play` does (a node named rosbag2_player publishing the recorded CDR on the
  recorded topic with the recorded QoS, read with rosbags): refused, registers stay at 0; and by
  `fabric-guidance replay`'s player: it refuses to publish into a namespace with a plc_output;
- plc_output frozen (SIGSTOP) while the controller publishes, the controller dead during the
  freeze, then SIGCONT: the commands that waited in the frozen process are aged from when they
  were sent, so none is written (the PLC watchdog is set long here, so only plc_output can vent).

Every wait is a condition with a deadline, then a bounded hold-check of the registers.
"""
import signal
import subprocess
import sys
import time

from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np
import pytest
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64MultiArray

from fabric_guidance.bag.recorder_status import recorded_counts
from fabric_guidance.interface import CLOCK, CLOCK_KIND, PRESSURE_COMMAND, qos_profile
from fabric_guidance.nodes.qos import COMMAND_QOS
from rosgraph import Probe, wait_until
from test_node_plc import (COMMAND_DEADLINE_S, COMMAND_TIMEOUT_S, LAYOUT, N, OUTPUT_STATUS, POLL_S, TOLERANCE_KPA, Rig,
                           record_vent)

pytestmark = pytest.mark.graph  # starts a process graph with DDS

#: What the foreign publishers send: well below p_max, far from 0.
FOREIGN_KPA = 150.0
#: Registers are read this long after the last foreign message was published (every POLL_S):
#: several write cycles and more than the rig's command_timeout_s, so a written command would show.
HOLD_S = COMMAND_TIMEOUT_S + 1.0
#: A publisher matched with plc_output (discovery on a loaded 2-core machine).
MATCH_DEADLINE_S = 15.0
#: plc_output's diagnostics report the refusals (one period and slack).
REFUSAL_REPORTED_S = 3.0
#: bag_recorder started (a cold process start) and 20 commands written.
RECORD_DEADLINE_S = 20.0
#: The mock's watchdog in the freeze test: longer than the test, so that only plc_output vents.
LONG_WATCHDOG_S = 60.0
#: The freeze: longer than the rig's command_timeout_s, so every command published is stale at SIGCONT.
FREEZE_S = COMMAND_TIMEOUT_S + 0.7
#: SIGCONT of plc_output -> registers at 0 (its first write cycle, a loaded machine).
THAW_VENT_DEADLINE_S = 0.5


@pytest.fixture
def rig(tmp_path):
    made = []

    def make(**overrides):
        made.append(Rig(tmp_path / f'graph{len(made)}', **overrides))
        return made[-1]
    yield make
    for r in made:
        r.close()


def hold_registers(rig, expected, duration_s, what, vented_ok=False):
    """Every read for duration_s equals `expected` (the registers were there before). With
    vented_ok a read of all zeros passes too (a vent is safe: plc_output's reconnection after a
    Modbus timeout on a loaded machine vents for a cycle); the foreign value never does."""
    end = time.monotonic() + duration_s
    reads = vented = 0
    while time.monotonic() < end:
        r = rig.registers()
        assert r is not None, f'{what}: PLC unreachable'
        if vented_ok and not np.any(r):
            vented += 1
        else:
            assert np.max(np.abs(r - expected)) <= TOLERANCE_KPA, f'{what}: registers read {r}, expected {expected}'
        reads += 1
        time.sleep(POLL_S)
    assert vented < reads, f'{what}: vented for the whole {duration_s} s'
    if vented:
        print(f'\n[provenance] {what}: {vented} of {reads} reads vented (none foreign)')
    return reads


def refusals(rig, n=0):
    status = rig.latest_status(OUTPUT_STATUS, n)
    values = {kv.key: kv.value for kv in status.values} if status else {}
    return int(values.get("commands refused (not the controller's)", 0)), status, values


def publish_until_heard(pub, msg, count, rate_hz=20.0):
    """Wait for plc_output to match `pub`, then publish `msg` `count` times at rate_hz."""
    wait_until(lambda: pub.get_subscription_count() > 0, MATCH_DEADLINE_S, what='plc_output matched')
    for _ in range(count):
        pub.publish(msg)
        time.sleep(1.0 / rate_hz)


def test_a_second_publisher_moves_no_register(rig):
    r = rig()
    # The graph's controller is silent (vented); a second node sends 150 kPa on every channel.
    with Probe(r.graph.domain_id, 'second_publisher') as other:
        pub = other.node.create_publisher(Float64MultiArray, PRESSURE_COMMAND, COMMAND_QOS)
        msg = Float64MultiArray(layout=LAYOUT, data=[FOREIGN_KPA] * N)
        publish_until_heard(pub, msg, 40)
        reads = hold_registers(r, np.zeros(N), HOLD_S, 'a second publisher alone')
        # While the controller guides, the other node's commands change nothing either.
        command = np.full(N, 40.0)
        r.command(command)
        r.wait_registers(command, COMMAND_DEADLINE_S, "the controller's command in the registers")
        publish_until_heard(pub, msg, 40)
        reads += hold_registers(r, command, HOLD_S, 'a second publisher beside the controller', vented_ok=True)
        wait_until(lambda: refusals(r)[0] >= 80, REFUSAL_REPORTED_S, what='80 refusals on /diagnostics')
    n, _, values = refusals(r)
    assert '/second_publisher' in values['refused by publisher'], values
    assert 'from /second_publisher' in values['last refusal'], values
    log = r.graph.log('plc_output')
    assert 'refusing pressure_command from /second_publisher' in log, log[-2000:]
    assert log.count('refusing pressure_command') < 10, 'the refusal line is throttled'
    print(f'\n[provenance] second publisher: {n} commands refused, {reads} register reads unchanged')


def test_a_freshly_refused_publisher_warns_on_diagnostics(rig):
    r = rig()
    r.command(np.full(N, 30.0))
    r.wait_registers(np.full(N, 30.0), COMMAND_DEADLINE_S, "the controller's command")
    wait_until(lambda: (s := r.latest_status(OUTPUT_STATUS)) and s.level == DiagnosticStatus.OK,
               REFUSAL_REPORTED_S, what='plc_output OK while only the controller publishes')
    with Probe(r.graph.domain_id, 'second_publisher') as other:
        pub = other.node.create_publisher(Float64MultiArray, PRESSURE_COMMAND, COMMAND_QOS)
        start = len(r.diagnostics)
        wait_until(lambda: pub.get_subscription_count() > 0, MATCH_DEADLINE_S, what='plc_output matched')
        timer = other.node.create_timer(0.05, lambda: pub.publish(
            Float64MultiArray(layout=LAYOUT, data=[FOREIGN_KPA] * N)))
        wait_until(lambda: any(s.level == DiagnosticStatus.WARN and 'refusing pressure_command' in s.message
                               for s in r.statuses(OUTPUT_STATUS, start)),
                   REFUSAL_REPORTED_S, what='WARN "refusing pressure_command" on /diagnostics')
        timer.cancel()


# ------------------------------------------------------------------ a recorded bag played back
def record_commands(r, bag, command):
    """The package's bag_recorder records the controller's `command` for a while, then closes."""
    r.graph.start('bag_recorder', (), output=str(bag), topics=[PRESSURE_COMMAND])
    r.command(command)
    r.wait_registers(command, COMMAND_DEADLINE_S, 'the command in the registers while recording')

    def recorded():
        counts = [recorded_counts(m) for m in r.diagnostics]
        return max((c.get(PRESSURE_COMMAND, 0) for c in counts if c), default=0)
    wait_until(lambda: recorded() >= 20, RECORD_DEADLINE_S, what='20 commands recorded')
    last = r.stop_commands()
    assert r.graph.stop('bag_recorder', signal.SIGINT) == 0, r.graph.log('bag_recorder')
    r.time_to_vent(last, 2.0, 'the controller stopped after recording')
    return last


def _rclpy_qos(qos) -> QoSProfile:
    """rosbags' Qos (the bag's offered_qos_profiles) as rclpy's, as `ros2 bag play` adapts it."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=max(1, int(qos.depth)),
        reliability=(ReliabilityPolicy.RELIABLE if qos.reliability.name == 'RELIABLE'
                     else ReliabilityPolicy.BEST_EFFORT),
        durability=(DurabilityPolicy.TRANSIENT_LOCAL if qos.durability.name == 'TRANSIENT_LOCAL'
                    else DurabilityPolicy.VOLATILE))


def play_like_ros2_bag(domain_id, bag):
    """`ros2 bag play BAG --topics /pressure_command`: a node named rosbag2_player publishes the
    recorded serialized messages on the recorded topic with the recorded QoS, paced as recorded.
    Returns how many it published and the largest value they carry."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_KILTED)
    with Reader(bag) as reader:
        conns = [c for c in reader.connections if c.topic == '/' + PRESSURE_COMMAND]
        assert conns, f'{bag}: no /pressure_command recorded'
        qos = _rclpy_qos(conns[0].ext.offered_qos_profiles[0])
        msgs = [(ts, data) for _, ts, data in reader.messages(connections=conns)]
    peak = max(max(store.deserialize_cdr(data, 'std_msgs/msg/Float64MultiArray').data) for _, data in msgs)
    with Probe(domain_id, 'rosbag2_player') as player:
        pub = player.node.create_publisher(Float64MultiArray, conns[0].topic, qos)
        wait_until(lambda: pub.get_subscription_count() > 0, MATCH_DEADLINE_S, what='plc_output matched')
        t0, start = msgs[0][0], time.monotonic()
        for ts, data in msgs:
            time.sleep(max(0.0, start + (ts - t0) * 1e-9 - time.monotonic()))
            pub.publish(data)
        return len(msgs), float(peak)


def test_a_recorded_bag_played_back_moves_no_register(rig, tmp_path):
    r = rig()
    bag = tmp_path / 'session'
    record_commands(r, bag, np.full(N, FOREIGN_KPA))
    played, peak = play_like_ros2_bag(r.graph.domain_id, bag)
    assert played >= 10 and peak == FOREIGN_KPA, (played, peak)
    reads = hold_registers(r, np.zeros(N), HOLD_S, 'the bag played back as `ros2 bag play` does')
    wait_until(lambda: refusals(r)[0] >= played, REFUSAL_REPORTED_S,
               what='every played-back command refused on /diagnostics')
    assert '/rosbag2_player' in refusals(r)[2]['refused by publisher']

    # The package's own player (`fabric-guidance replay BAG --topics pressure_command`) does not
    # even publish: plc_output drives a suit in that namespace (bag/player.py's LiveGuard). It waits
    # for every publisher of its own to be matched, /clock too: a subscriber of /clock here lets it
    # look at the graph as soon as plc_output has matched, not at the end of --wait.
    r.probe.subscribe(Clock, CLOCK, qos_profile(CLOCK_KIND))
    replay = subprocess.run([sys.executable, '-m', 'fabric_guidance.commands.cli', 'replay', str(bag), '--topics',
                             PRESSURE_COMMAND, '--wait', str(MATCH_DEADLINE_S)],
                            env={**r.graph.env}, capture_output=True, text=True, timeout=120)
    assert replay.returncode == 2, replay.stdout + replay.stderr
    assert replay.stdout.strip() == ('fabric-guidance replay: refusing to publish /pressure_command: /plc_output '
                                     'drives a suit there. A replay drives only a controller of its own (started '
                                     'with use_sim_time:=true): replay into another ROS_DOMAIN_ID, or under a '
                                     'namespace of its own with --namespace replay'), replay.stdout
    reads += hold_registers(r, np.zeros(N), HOLD_S, 'the bag replayed by fabric-guidance replay')
    assert '/bag_player' not in refusals(r)[2]['refused by publisher']   # nothing sent to refuse
    print(f'\n[provenance] bag of {played} commands at {peak:g} kPa played back twice: '
          f'{reads} register reads all 0')


# ------------------------------------------------------------------ a frozen plc_output
def test_commands_that_waited_in_a_frozen_plc_output_are_not_written(rig):
    """The controller publishes while plc_output is stopped, dies during the freeze, and the
    freeze outlasts command_timeout_s: after SIGCONT the queued commands are stale (aged from
    their sending) and the registers go to 0 and stay there."""
    r = rig(mock={'watchdog_s': LONG_WATCHDOG_S})
    command = np.full(N, 120.0)
    r.command(command)
    r.wait_registers(command, COMMAND_DEADLINE_S, 'the command in the registers')
    proc = r.graph.processes['plc_output']
    proc.send_signal(signal.SIGSTOP)
    try:
        time.sleep(0.3)                     # commands keep coming into the frozen process
        last = r.stop_commands()            # the controller dies
        time.sleep(FREEZE_S)
        stale_by = time.monotonic() - last
    finally:
        proc.send_signal(signal.SIGCONT)
    thawed = time.monotonic()
    seconds = r.time_to_vent(thawed, THAW_VENT_DEADLINE_S, 'SIGCONT of plc_output after the controller died')
    record_vent('SIGCONT of plc_output, the controller dead (from SIGCONT)', seconds, THAW_VENT_DEADLINE_S)
    hold_registers(r, np.zeros(N), HOLD_S, 'commands queued in the frozen plc_output')
    print(f'\n[provenance] freeze: the last command {stale_by:.2f} s old at SIGCONT; registers 0 '
          f'{seconds:.3f} s after SIGCONT and for {HOLD_S} s after')


def test_a_frozen_plc_output_writes_commands_again_once_they_are_fresh(rig):
    """The control case: the controller alive through the freeze, guidance comes back at SIGCONT
    (the aging refuses old commands, not the controller)."""
    r = rig(mock={'watchdog_s': LONG_WATCHDOG_S})
    command = np.full(N, 80.0)
    r.command(command)
    r.wait_registers(command, COMMAND_DEADLINE_S, 'the command in the registers')
    proc = r.graph.processes['plc_output']
    proc.send_signal(signal.SIGSTOP)
    time.sleep(FREEZE_S)
    proc.send_signal(signal.SIGCONT)
    r.wait_registers(command, COMMAND_DEADLINE_S, 'the live command back after SIGCONT', hold_s=0.3)


# ------------------------------------------------------------------ the decisions, without ROS
def _source(publishers, clock=None):
    from fabric_guidance.nodes.command_source import CommandSource, Publisher
    now = [0.0]
    src = CommandSource('/pressure_controller', lambda: [Publisher(*p) for p in publishers],
                        clock=clock or (lambda: now[0]))
    return src, now


CONTROLLER = ('pressure_controller', '/', b'\x01' * 16)
PLAYER = ('rosbag2_player', '/', b'\x02' * 16)


def test_the_sender_is_checked_by_its_gid():
    publishers = [CONTROLLER, PLAYER]
    src, now = _source(publishers)
    gid = {'implementation_identifier': 'rmw_fastrtps_cpp'}
    assert src.check({'publisher_gid': {**gid, 'data': CONTROLLER[2]}}) == ''
    assert src.check({'publisher_gid': {**gid, 'data': PLAYER[2]}}) == 'from /rosbag2_player'
    assert src.check({'publisher_gid': {**gid, 'data': b'\x03' * 16}}).startswith('from a publisher the graph')
    # A controller in another namespace is not this graph's.
    src, _ = _source([('pressure_controller', '/other', b'\x04' * 16)])
    assert src.check({'publisher_gid': {**gid, 'data': b'\x04' * 16}}) == 'from /other/pressure_controller'
    assert src.refused == 1 and src.refused_by == {'/other/pressure_controller': 1}


def test_a_restarted_controller_is_found_on_the_next_lookup():
    publishers = [CONTROLLER]
    src, now = _source(publishers)
    new = b'\x05' * 16
    assert src.check({'publisher_gid': {'data': CONTROLLER[2]}}) == ''
    publishers[:] = [('pressure_controller', '/', new)]
    # Within a refresh period of the last lookup it is refused (vented, safe); after it, found.
    assert src.check({'publisher_gid': {'data': new}}) != ''
    now[0] += 0.25
    assert src.check({'publisher_gid': {'data': new}}) == ''
    # A flood of unknown senders looks the graph up once per refresh period only.
    calls = []
    src2, now2 = _source([])
    src2._publishers = lambda: calls.append(1) or []
    for _ in range(100):
        src2.check({'publisher_gid': {'data': b'\x06' * 16}})
    assert len(calls) == 1


def test_without_publisher_gid_any_other_publisher_refuses_every_command():
    """Jazzy's rclpy has no MessageInfo.publisher_gid: the graph must show the controller alone."""
    publishers = [CONTROLLER]
    src, now = _source(publishers)
    info = {'source_timestamp': 1, 'received_timestamp': 1}
    assert src.check(info) == ''
    publishers.append(PLAYER)
    now[0] += 1.0
    assert 'while other nodes publish it: /rosbag2_player' in src.check(info)
    publishers.pop()
    now[0] += 1.0
    assert src.check(info) == ''
    publishers.clear()
    now[0] += 1.0
    assert src.check(info).startswith('from a publisher the graph does not name')


def test_a_command_is_as_old_as_its_source_timestamp():
    from fabric_guidance.nodes.command_source import sent_age_s
    now_ns = 10_000_000_000
    sent_1_2_s_ago = {'source_timestamp': now_ns - 1_200_000_000, 'received_timestamp': now_ns}
    assert sent_age_s(sent_1_2_s_ago, now_ns) == pytest.approx(1.2)
    # Stamped after now (a clock stepped back): negative, not 0, so plc_output cannot take it for
    # fresh (it vents, counting it invalid).
    assert sent_age_s({'source_timestamp': now_ns + 5_000_000, 'received_timestamp': 0}, now_ns) == \
        pytest.approx(-0.005)
    # No source time (a middleware that gives 0): unknown age, refused by plc_output.
    assert sent_age_s({'source_timestamp': 0, 'received_timestamp': now_ns}, now_ns) is None
    assert sent_age_s(None, now_ns) is None
