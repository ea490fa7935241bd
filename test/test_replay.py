"""Replaying a recorded session. Offline: the controller rerun over its recorded inputs
reproduces the recorded commands exactly and differs when the gain changes. Through the graph:
pressure_controller on use_sim_time runs on the bag's /clock, and a looping replay (the clock
jumps back) causes no spike in its commands.

The session here is short and made so that Eq. 5's gain matters: the wearer turns away from the
target (the error grows), which the demo's simple wearer never does.
"""
import math
import subprocess
import sys
import time

import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PointStamped, PoseStamped
from std_msgs.msg import String

from fabric_guidance.bag import offline
from fabric_guidance.bag.recorder_status import recorded_counts
from fabric_guidance.core import ChannelMap, ray_orientation
from fabric_guidance import interface
from fabric_guidance.nodes import qos
from rosgraph import CONFIG, Graph, Probe, wait_until

pytestmark = pytest.mark.graph  # starts a process graph with DDS

CMAP = ChannelMap.load(CONFIG / 'hardware/channel_map.yaml')
L1 = CMAP.channels.index('L1')
EYE = np.array([0.0, 0.0, 1.2])
CAL = str(CONFIG / 'calibrations' / 'sim-wearer.yaml')


def direction(yaw_deg):
    y = math.radians(yaw_deg)
    return np.array([math.cos(y), math.sin(y), 0.0])


def gaze_msg(yaw):
    msg = PoseStamped()
    msg.header.frame_id = interface.IMMERSIVE_FRAME
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = EYE
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = ray_orientation(direction(yaw))
    return msg


def recorder_ready(probe):
    return all(probe.node.count_subscribers(t) >= n for t, n in (('controller_input', 1), ('gaze', 2)))


@pytest.fixture(scope='module')
def turning_session(tmp_path_factory):
    """pressure_controller (G = 0.05) and bag_recorder; the wearer looks ahead, a target 40 deg
    left appears, the wearer turns 20 deg right (the error grows), then holds; a second target
    (same place) follows, which vents the controller once."""
    tmp = tmp_path_factory.mktemp('turning')
    bag = tmp / 'bag'
    graph = Graph(tmp / 'logs')
    graph.start('bag_recorder', (), output=str(bag))
    graph.start('pressure_controller', ('params/guidance.yaml',), calibration_file=CAL, gain=0.05,
                target_publisher='test_probe')   # the probe plays target_selector
    probe = Probe(graph.domain_id)
    try:
        node = probe.node
        gaze = node.create_publisher(PoseStamped, interface.GAZE, qos.SENSOR_QOS)
        target = node.create_publisher(PointStamped, interface.TARGET, qos.LATCHED_QOS)
        name = node.create_publisher(String, interface.ACTIVE_TARGET, qos.LATCHED_QOS)
        counts = {}
        probe.subscribe(DiagnosticArray, '/diagnostics', 10,
                        lambda msg: counts.update(recorded_counts(msg) or {}))
        wait_until(lambda: recorder_ready(probe) and node.count_publishers('controller_input'), 15.0,
                   what='controller and recorder')
        # Looking ahead until the recorder writes the controller's steps: the three processes
        # have matched (on a loaded machine that comes well after the graph lists them).
        wait_until(lambda: gaze.publish(gaze_msg(0.0)) or counts.get('controller_input', 0) > 0, 20.0,
                   what="the recorder writing the controller's steps", interval=0.05)
        yaws = [0.0] * 15 + [-0.5 * k for k in range(40)] + [-20.0] * 40
        point = PointStamped()
        point.header.frame_id = interface.IMMERSIVE_FRAME
        point.point.x, point.point.y, point.point.z = EYE + 2.0 * direction(40.0)
        start = counts['controller_input']
        for k, yaw in enumerate(yaws):
            if k in (10, 80):
                name.publish(String(data='t1' if k == 10 else 't2'))
            if k >= 10 and k % 5 == 0:    # as target_selector: the position again after the name
                target.publish(point)
            gaze.publish(gaze_msg(yaw))
            time.sleep(0.02)              # the headset's pace, not a wait for anything
        # Stopped once the recorder has written (nearly) every step of the script.
        wait_until(lambda: counts['controller_input'] - start >= len(yaws) - 5, 20.0,
                   what='the recorder writing the scripted steps')
        assert graph.stop('pressure_controller') == 0
        assert graph.stop('bag_recorder') == 0
    finally:
        probe.close()
        graph.stop_all()
    assert (bag / 'metadata.yaml').is_file(), graph.log('bag_recorder')
    return bag


def test_offline_replay_exact_and_the_gain_shows(turning_session):
    rec = offline.load(turning_session)
    same = offline.replay(rec)
    assert same.compared > 30 and same.exact, same.worst
    grown = max(c[L1] for c in rec.commands)
    assert grown > min(c[L1] for c in rec.commands if c[L1] > 0) + 1.0   # Eq. 5 raised the pressure
    changed = offline.replay(rec, {'gain': 0.1})
    assert changed.largest > 1.0 and changed.worst['channel'] in ('L1', 'L2'), changed.worst
    out = subprocess.run([sys.executable, '-m', 'fabric_guidance.commands.replay', str(turning_session), '--offline',
                          '--set', 'gain=0.1'], capture_output=True, text=True, timeout=60)
    assert out.returncode == 1, out.stdout + out.stderr
    assert 'largest difference' in out.stdout and 'on L' in out.stdout and 'gain=0.1' in out.stdout
    print(out.stdout)


def test_looping_graph_replay_runs_on_bag_time_without_a_spike(turning_session, tmp_path):
    """replay BAG --loop with /clock; pressure_controller on use_sim_time. Recorded in turn, the
    looped session shows the clock jumping back and the command holding at the jump."""
    bag = tmp_path / 'looped'
    graph = Graph(tmp_path / 'logs')
    graph.start('bag_recorder', (), output=str(bag))
    # target_publisher: the replay's player (bag_player) plays target_selector here
    graph.start('pressure_controller', ('params/guidance.yaml',), calibration_file=CAL, gain=0.05, use_sim_time=True,
                target_publisher='bag_player')
    probe = Probe(graph.domain_id)
    try:
        wait_until(lambda: recorder_ready(probe) and probe.node.count_publishers('controller_input'), 15.0,
                   what='controller and recorder')
        # --wait: start only once the controller hears every topic, /clock included (discovery of
        # the replay process can take seconds on a loaded machine; the bag is under 2 s long).
        out = subprocess.run([sys.executable, '-m', 'fabric_guidance.commands.replay', str(turning_session), '--loop',
                              '--loops', '2', '--wait', '20'], capture_output=True, text=True, timeout=60,
                             env=graph.env)
        assert out.returncode == 0, out.stdout + out.stderr
        assert 'the clock jumps back' in out.stdout
        time.sleep(0.3)
        assert graph.stop('pressure_controller') == 0
        assert graph.stop('bag_recorder') == 0
    finally:
        probe.close()
        graph.stop_all()
    rec = offline.load(bag)
    # The control timer is steady: before the first /clock sim time reads 0 (and the node vents,
    # with no gaze). The steps on the bag's time are the ones to look at.
    rec.inputs = [i for i in rec.inputs if i.t > 0.0]
    ts = np.array([i.t for i in rec.inputs])
    # The controller ran on the bag's time (sim time, which the replay's /clock takes from the
    # bag's first message on), not on the wall clock of this run.
    meta = yaml.safe_load((turning_session / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    start = meta['starting_time']['nanoseconds_since_epoch'] * 1e-9
    assert start - 0.1 <= ts.min() and ts.max() <= start + meta['duration']['nanoseconds'] * 1e-9 + 1.0
    jumps = np.flatnonzero(np.diff(ts) < 0) + 1
    assert len(jumps) == 1, ts
    pairs = {i.step: rec.commands[i.command - rec.offset][L1] for i in rec.inputs
             if 0 <= i.command - rec.offset < len(rec.commands)}
    steps = sorted(pairs)
    p = np.array([pairs[s] for s in steps])
    jump_step = rec.inputs[jumps[0]].step
    k = steps.index(jump_step)
    increments = np.diff(p)
    assert increments.max() > 0.5            # Eq. 5 raised the pressure while the wearer turned away
    assert p[k] == p[k - 1], (p[k - 3:k + 3])   # at the jump the derivative restarts: the command holds
    normal = np.abs(increments[: k - 1]).max()
    assert np.abs(increments[k - 1: k + 5]).max() <= normal + 1e-9, 'a spike after the clock jumped back'
    # ... and the looped session, clock jump included, reproduces offline exactly.
    assert offline.replay(rec).exact


def test_offline_replay_of_a_bag_cut_mid_guidance_compares_from_the_first_vent(turning_session):
    """A recorder started mid-session misses the steps that built Eq. 5's state. The replay must
    not report the difference that makes as the controller's: it compares from the first step
    whose state is known (a vent), and a step missing in the middle unsyncs it again."""
    from dataclasses import replace

    from fabric_guidance.bag.controller_io import setup_from_dict
    from fabric_guidance.core.control_step import guidance_step, safe_command
    rec = offline.load(turning_session)
    setup = setup_from_dict(rec.setups[0][1])

    def naive_diff(i):           # the step rerun from a fresh controller, as a naive replay would
        inp = rec.inputs[i]
        channels, reason, _ = guidance_step(setup, setup.make_controller(), inp)
        recorded = rec.commands[inp.command - rec.offset]
        return 0.0 if reason else float(np.abs(safe_command(channels, setup.p_max_kpa) - recorded).max())

    cuts = [i for i in range(1, len(rec.inputs) - 5)
            if not rec.inputs[i].reset and naive_diff(i) > 1.0]
    assert cuts, 'the session has no step whose Eq. 5 state matters'
    cut = cuts[0]
    late = offline.replay(replace(rec, inputs=rec.inputs[cut:]))
    assert late.unsynced >= 1 and late.compared > 5 and late.exact, late.worst
    gap = offline.replay(replace(rec, inputs=rec.inputs[:cut] + rec.inputs[cut + 1:]))
    assert gap.step_gaps == 1 and gap.unsynced >= 1 and gap.exact, gap.worst


def test_pairing_offset_holds_when_the_recorder_stores_a_command_before_its_input():
    """Input and command of a step arrive microseconds apart in two subscriptions: either may
    be stored first. The recorder missed the node's first 5 commands (offset 5); one stall
    delivers a batch at once."""
    inputs, input_ts, command_ts = [], [], []
    for step in range(200):
        t = step * 11_000_000                       # 90 Hz steps [ns]
        command_first = step % 2 == 0
        inputs.append(step + 5)                     # the node's command index of this step
        input_ts.append(t + (3000 if command_first else 0))
        command_ts.append(t + (0 if command_first else 3000))
    command_ts[50:60] = [command_ts[59] + 1] * 10   # a stall: ten commands taken at once
    assert offline.pairing_offset(inputs, input_ts, command_ts) == 5
    assert offline.pairing_offset(inputs[1:], input_ts[1:], command_ts) == 5   # an input lost


def replay_onto(graph, bag, *extra, timeout=60):
    return subprocess.run([sys.executable, '-m', 'fabric_guidance.commands.replay', str(bag), '--wait', '10', *extra],
                          capture_output=True, text=True, timeout=timeout, env=graph.env)


def test_a_graph_replay_never_moves_a_live_suit(turning_session, tmp_path):
    """A live graph (mock PLC, plc_output, an enabled pressure_controller on the wall clock, no
    active target): the replay of a guided session refuses in one line before its first message;
    under its own namespace it plays, unheard. The registers, read over Modbus all along, stay 0
    and the controller never takes the recorded target."""
    from fabric_guidance.plc import PlcClient, RegisterMap
    from rosgraph import free_port
    port = free_port()
    files = ('params/guidance.yaml', 'params/sim.yaml')
    graph = Graph(tmp_path / 'logs')
    graph.start('mock_plc', files, port=port)
    graph.start('plc_output', files, plc_port=port)
    graph.start('pressure_controller', files, calibration_file=CAL, gain=0.05)
    probe = Probe(graph.domain_id)
    client = PlcClient(RegisterMap.load(CONFIG / 'hardware/plc_register_map.yaml'), '127.0.0.1', port)
    reads, stop = [], [False]

    def watch():   # every register read, over Modbus, while the replays run
        while not stop[0]:
            try:
                reads.append(client.read_commands_kpa())
            except Exception:  # noqa: BLE001 - the mock starting: no read yet
                client.close()
            time.sleep(0.01)
    import threading
    watcher = threading.Thread(target=watch, daemon=True)
    try:
        diagnostics = probe.subscribe(DiagnosticArray, '/diagnostics', 10)
        wait_until(lambda: any('plc_output: PLC output' == s.name and s.message == 'writing commands'
                               for m in diagnostics for s in m.status), 30.0,
                   what="plc_output writing the enabled controller's commands (0: no target)")
        watcher.start()
        refused = replay_onto(graph, turning_session)
        remapped = replay_onto(graph, turning_session, '--namespace', 'replay')
        time.sleep(0.5)   # the registers watched past the replay's end
        stop[0] = True
        watcher.join(2)
        targets = [s for m in diagnostics for s in m.status if s.name == 'pressure_controller: guidance']
    finally:
        stop[0] = True
        client.close()
        probe.close()
        graph.stop_all()
    assert len(reads) > 100, len(reads)
    assert not any(np.any(r) for r in reads), f'a register moved: {next(r for r in reads if np.any(r))}'
    assert refused.returncode == 2, refused.stdout + refused.stderr
    lines = [line for line in refused.stdout.splitlines() if line.strip()]
    assert len(lines) == 1 and 'refusing to publish' in lines[0] and (
        '/plc_output drives a suit there' in lines[0] or '/pressure_controller runs on the wall clock' in lines[0]), \
        refused.stdout
    assert remapped.returncode == 0, remapped.stdout + remapped.stderr
    assert 'under /replay' in remapped.stdout and 'messages republished' in remapped.stdout
    assert targets and not any('t1' in kv.value or 't2' in kv.value for s in targets for kv in s.values
                               if kv.key == 'target'), [kv for s in targets[-1:] for kv in s.values]
