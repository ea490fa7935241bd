"""One bag per block (live_study/block_bag.py): the package's bag_recorder as a child of the
session, into the folder the study store reserved, read back with rosbags' AnyReader (a reader
we did not write); a session killed with SIGKILL leaves a closed bag."""
import os
from pathlib import Path
import signal
import subprocess
import sys
import textwrap

import pytest
from rosbags.highlevel import AnyReader

from fabric_guidance import interface
from fabric_guidance.bag.recorder_status import recorded_counts
from fabric_guidance.live_study.block_bag import BlockRecorder, BlockRecorderError
from fabric_guidance.live_study.operator import Operator
from fabric_guidance.graph.process_graph import fresh_domain_id, wait_until
from fabric_guidance.study.plan import participant_blocks
from fabric_guidance.study.store import Study

pytestmark = pytest.mark.graph


def read_bag(path: Path) -> dict[str, list]:
    """topic -> decoded messages, with rosbags' own reader and the bag's own definitions."""
    out: dict[str, list] = {}
    with AnyReader([path]) as reader:
        for conn, _t, raw in reader.messages():
            out.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
    return out


def _gaze_publisher(op):
    from geometry_msgs.msg import PoseStamped
    pub = op.node.create_publisher(PoseStamped, interface.GAZE, interface.qos_profile('sensor'))

    # the operator's own subscription and the recorder's: matched before the first message
    wait_until(lambda: pub.get_subscription_count() >= 2, 20.0, what='the recorder matched the gaze publisher')

    def publish(i: int) -> None:
        msg = PoseStamped()
        msg.header.stamp = op.node.get_clock().now().to_msg()
        msg.header.frame_id = f'gaze-{i}'
        msg.pose.orientation.w = 1.0
        pub.publish(msg)
    return publish


def test_a_blocks_bag_holds_its_presses_and_gaze(tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray
    study = Study.open(tmp_path / 'study')
    study.add_participant('01')
    from fabric_guidance.live_study.simulated import design_of
    from fabric_guidance.sim.scene import load_scene, scene_path
    design = design_of(load_scene(scene_path('paper-speed')), 'random')
    store = study.session('01', 1, design)
    block = participant_blocks(design, '01', 0)[0]
    path = store.bag_path(block)
    assert path.name.endswith('_run-1_bag') and not path.exists()
    op = Operator(fresh_domain_id())
    counts = {}
    op.node.create_subscription(DiagnosticArray, interface.DIAGNOSTICS,
                                lambda m: counts.update(recorded_counts(m) or {}), 10)
    rec = BlockRecorder(op)
    try:
        rec.start(path)
        publish = _gaze_publisher(op)
        wait_until(lambda: op.confirm_pub.get_subscription_count() >= 2, 20.0,
                   what='the recorder matched the confirm publisher')
        op.press_key('keyboard')
        op.press_key('headset')
        sent = []

        def stream():
            # gaze is best effort (a sample may be lost under load, as on the real graph): at the
            # gaze rate until the recorder has written 20
            sent.append(len(sent))
            publish(sent[-1])
            return counts.get(interface.GAZE, 0) >= 20 and counts.get(interface.CONFIRM, 0) >= 2
        wait_until(stream, 30.0, interval=1 / 90, what='the recorder wrote 20 gaze and 2 presses')
        with pytest.raises(BlockRecorderError, match='already recorded'):
            rec.start(tmp_path / 'other_bag')
        assert rec.stop() == path
    finally:
        rec.stop()
        op.close()
    msgs = read_bag(path)
    assert [m.frame_id for m in msgs['/confirm']] == ['keyboard', 'headset']      # reliable: both, in order
    got = [int(m.header.frame_id.split('-')[1]) for m in msgs['/gaze']]
    assert len(got) >= 20 and got == sorted(set(got)) and set(got) <= set(sent), got
    # a redone block gets run-2: the first one's bag stays as it is
    assert store.bag_path(block).name.endswith('_run-2_bag')


CHILD = textwrap.dedent('''
    import sys, time
    from pathlib import Path
    from fabric_guidance.live_study.block_bag import BlockRecorder
    from fabric_guidance.live_study.operator import Operator
    op = Operator(int(sys.argv[1]))
    BlockRecorder(op).start(Path(sys.argv[2]))
    print('recording', flush=True)
    time.sleep(600)
''')


def test_a_session_killed_with_sigkill_leaves_a_closed_bag(tmp_path):
    path = tmp_path / 'block-1_run-1_bag'
    child = subprocess.Popen([sys.executable, '-c', CHILD, str(fresh_domain_id()), str(path)],
                             stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == 'recording'
        os.kill(child.pid, signal.SIGKILL)
        child.wait(10)
        # the recorder heard its parent die (SIGINT) and closed the bag with its metadata
        wait_until(lambda: (path / 'metadata.yaml').exists(), 20.0, what=f'{path}/metadata.yaml written')
        with AnyReader([path]) as reader:
            assert {c.topic for c in reader.connections} >= {'/gaze', '/confirm'}
    finally:
        if child.poll() is None:
            child.kill()


def _seconds(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def test_a_simulated_sessions_blocks_each_have_their_bag(tmp_path):
    import yaml
    from fabric_guidance.live_study.session_graph import run_study_session
    from fabric_guidance.sim.scene import load_scene, scene_path
    from fabric_guidance.study.store import read_tsv
    data = yaml.safe_load(scene_path('paper-accuracy').read_text())
    data.update(conditions=[1, 2], repetitions=1)
    (tmp_path / 'short.yaml').write_text(yaml.safe_dump(data, sort_keys=False))
    out = tmp_path / 'study'
    assert run_study_session(load_scene(tmp_path / 'short.yaml'), 1, out, lambda line: None) == 0
    folder = out / 'sub-01' / 'ses-1' / 'beh'
    rows = read_tsv(folder / 'sub-01_ses-1_task-accuracy_beh.tsv')[1]
    bags = sorted(folder.glob('*_bag'))
    assert [b.name for b in bags] == [f'sub-01_ses-1_task-accuracy_run-{k}_bag' for k in (1, 2)]
    assert len(rows) == 2 and {r['status'] for r in rows} == {'ok'}
    for bag in bags:
        msgs = read_bag(bag)
        # the block's press (wearer_sim's, through the headset uplink as the clicker's), the gaze
        # it was judged on, the display's lines
        presses = [m.frame_id for m in msgs['/confirm']]
        assert presses and set(presses) == {'headset'}, bag
        # The gaze the press was judged on: samples up to the press's capture stamp (how many
        # depends on when the wearer pressed: 89 once, in a block whose press came early).
        press_s = _seconds(msgs['/confirm'][0].stamp)
        assert sum(_seconds(g.header.stamp) <= press_s for g in msgs['/gaze']) >= 10, bag
        lines = [m.data for m in msgs['/study_display']]
        assert 'done sequence' in lines and 'done block' in lines, lines
    assert 'done session' in [m.data for m in read_bag(bags[-1])['/study_display']]


def test_a_bag_that_cannot_be_written_costs_one_line_not_the_block(tmp_path):
    from fabric_guidance.live_study.block_bag import BlockBags

    class Store:
        recorded = []

        def bag_path(self, block):
            path = tmp_path / 'taken_bag'
            path.mkdir(exist_ok=True)         # a folder already there: the recorder refuses it
            return path

        def record(self, step):
            self.recorded.append(step)

    class Block:
        key, order = 'accuracy-order1-cond1', 1

    lines = []
    bags = BlockBags(None, Store(), say=lines.append)
    bags.begin(Block())
    assert len(lines) == 1 and 'block 1: no bag' in lines[0] and 'taken_bag: exists' in lines[0], lines
    assert bags.recorder.process is None and bags.block is None
    bags.record('step')                       # the trials go on being recorded
    assert Store.recorded == ['step']
    bags.close()
