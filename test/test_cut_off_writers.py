"""Nothing lost when a writer is killed.

- A recording cut at any byte reads up to its last intact chunk, never a damaged message, and
  tells what it lost; cut before its first intact chunk it is one clear BagReadError.
- bag_recorder SIGKILLed while messages flow: the bag replays offline up to the kill, saying
  what was lost, and `recover` writes a complete bag that the indexed reader, the mcap library
  and rosbags open with the same messages.
- A process SIGKILLed in the middle of atomic writes (a calibration, a large report) leaves the
  old file or the new one, each whole.
"""
import hashlib
import os
from pathlib import Path
import random
import shutil
import signal
import subprocess
import sys
import time

from hypothesis import given, settings, strategies as st
from mcap.reader import make_reader
import pytest

from fabric_guidance.bag.reader import BagReadError, raw_messages
from fabric_guidance.bag.writer import BagWriter, typestore
from fabric_guidance.core.calibration import Calibration
from rosgraph import CONFIG, ROOT, Graph, Probe, wait_until

STRING = 'std_msgs/msg/String'
N_MESSAGES = 1200
FLUSH_EVERY = 97             # messages per chunk: the recorder's flush, a dozen chunks


def _payload(topic: str, i: int) -> bytes:
    store = typestore()
    msg = store.types[STRING](data=f'{topic} message {i} ' + 'x' * (i % 61))
    return bytes(store.serialize_cdr(msg, STRING))


@pytest.fixture(scope='module')
def written(tmp_path_factory):
    """A bag with a known message sequence in many chunks (BagWriter.flush as bag_recorder
    calls it), closed properly; per chunk where it ends with its message index records and the
    messages up to it; where the data section ends (its DataEnd record)."""
    bag = tmp_path_factory.mktemp('written') / 'bag'
    sent = []
    with BagWriter(bag) as w:
        for topic in ('/a', '/b'):
            w.add_topic(topic, STRING)
        for i in range(N_MESSAGES):
            topic = '/b' if i % 3 == 0 else '/a'
            sent.append((topic, 1_700_000_000_000_000_000 + i * 10_000_000, _payload(topic, i)))
            w.write(*sent[-1])
            if i % FLUSH_EVERY == FLUSH_EVERY - 1:
                assert w.flush(fsync=False)
    [mcap] = bag.glob('*.mcap')
    with open(mcap, 'rb') as f:
        summary = make_reader(f).get_summary()
    ends = sorted(c.chunk_start_offset + c.chunk_length + c.message_index_length for c in summary.chunk_indexes)
    assert len(ends) == -(-N_MESSAGES // FLUSH_EVERY)
    before = [min(N_MESSAGES, (k + 1) * FLUSH_EVERY) for k in range(len(ends))]
    data = mcap.read_bytes()
    data_end = max(ends)
    if data[data_end] == 0x0c:             # rosbags' metadata record, written on close
        data_end += 9 + int.from_bytes(data[data_end + 1:data_end + 9], 'little')
    assert data[data_end] == 0x0f          # then the DataEnd record
    record_ends = sorted(c.chunk_start_offset + c.chunk_length for c in summary.chunk_indexes)
    return bag, data, sent, list(zip(ends, before)), data_end, record_ends


def _expected(chunks, cut: int) -> int:
    """Messages in the chunks wholly before byte `cut`, their message index included."""
    return max([n for end, n in chunks if end <= cut], default=0)


def _by_topic(messages) -> dict:
    out = {}
    for topic, _, data in messages:
        out.setdefault(topic, []).append(data)
    return out


def _read_cut(folder: Path, content: bytes, name='cut'):
    """raw_messages of a bag folder holding only `content` as its .mcap (no metadata.yaml)."""
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir()
    (folder / f'{name}.mcap').write_bytes(content)
    recovered = []
    got = [(t, ts, data) for t, _, ts, data in raw_messages(folder, recovered=recovered)]
    return got, recovered


def test_a_cut_at_any_byte_reads_up_to_the_last_intact_chunk(written, tmp_path):
    bag, data, sent, chunks, _, _ = written
    rng = random.Random(7)
    cuts = {0, 1, 7, 8, 9, 50, len(data) - 1}
    for end, _ in chunks:
        cuts |= {end - 9, end - 1, end, end + 1, end + 9}
    cuts |= set(range(0, len(data), len(data) // 120)) | {rng.randrange(len(data)) for _ in range(60)}
    outcomes = {'error': 0, 'recovered': 0}
    for cut in sorted(c for c in cuts if 0 <= c < len(data)):
        n = _expected(chunks, cut)
        if n == 0:
            with pytest.raises(BagReadError) as err:
                _read_cut(tmp_path / 'c', data[:cut])
            line = str(err.value)
            assert '\n' not in line and 'cut.mcap' in line and len(line) < 300, line
            outcomes['error'] += 1
            continue
        got, [r] = _read_cut(tmp_path / 'c', data[:cut])
        # exactly the messages of the whole chunks, every byte as written: no damaged message
        assert _by_topic(got) == _by_topic(sent[:n]), cut
        assert [ts for _, ts, _ in got] == sorted(ts for _, ts, _ in sent[:n])
        assert r.total == n and r.size == cut and r.intact_end <= cut
        assert r.lost_bytes == cut - r.intact_end
        assert r.intact_end >= max(end for end, m in chunks if m <= n)
        line = r.describe()
        assert 'no summary section' in line and 'no metadata.yaml' in line and f'{n} messages' in line
        outcomes['recovered'] += 1
    assert outcomes['error'] and outcomes['recovered'] > 100, outcomes
    print(f'{sum(outcomes.values())} cut points of a {len(data)}-byte bag: {outcomes}')


@settings(max_examples=60, deadline=None, derandomize=True)
@given(cut=st.floats(0.0, 1.0), tail=st.one_of(st.binary(max_size=300),
                                               st.integers(1, 5000).map(lambda n: b'\x00' * n)))
def test_a_cut_with_anything_after_it_never_gives_a_damaged_message(written, tmp_path_factory, cut, tail):
    """What a crash leaves after the cut (a zero-filled tail, junk) is not read as messages."""
    _, data, sent, chunks, _, _ = written
    at = int(cut * (len(data) - 1))
    try:
        got, recovered = _read_cut(tmp_path_factory.mktemp('tail'), data[:at] + tail)
    except BagReadError as exc:
        assert '\n' not in str(exc)
        assert _expected(chunks, at) == 0, (at, str(exc))
        return
    full = _by_topic(sent)
    for topic, datas in _by_topic(got).items():
        assert datas == full[topic][:len(datas)], topic         # a prefix, byte for byte
    assert len(got) >= _expected(chunks, at)


def test_zeros_where_the_crash_cut_the_data_are_not_read_as_a_message(written, tmp_path):
    """A file system may show zeros where a crash cut the writes: here over the last bytes of a
    chunk's last message and all after it. The chunk parses (its last message with zeros for
    data); its message index, zeros too, does not: the chunk is not taken."""
    _, data, sent, chunks, _, record_ends = written
    for k in (1, 4, len(chunks) - 1):
        content = data[:record_ends[k] - 5] + bytes(len(data) - record_ends[k] + 5)
        got, [r] = _read_cut(tmp_path / 'zeros', content)
        assert _by_topic(got) == _by_topic(sent[:chunks[k - 1][1]]), k
        assert r.intact_end == chunks[k - 1][0] and 'lacks its message index' in r.describe(), r.describe()


def test_a_stale_metadata_file_and_a_cut_in_the_summary(written, tmp_path):
    bag, data, sent, chunks, data_end, _ = written
    folder = tmp_path / 'stale'
    got, [r] = _read_cut(folder, data[:data_end + 13 + 40])   # the whole data section, the summary cut
    assert len(got) == N_MESSAGES and 'the data section is whole' in r.describe()
    # a metadata.yaml left from another recording in the folder: its count is called stale
    shutil.copy(bag / 'metadata.yaml', folder / 'metadata.yaml')
    text = (folder / 'metadata.yaml').read_text().replace('bag.mcap', 'stale.mcap')
    (folder / 'metadata.yaml').write_text(text)
    (folder / 'cut.mcap').rename(folder / 'stale.mcap')
    (folder / 'stale.mcap').write_bytes(data[:chunks[2][0] + 3])
    recovered = []
    got = list(raw_messages(folder, recovered=recovered))
    assert len(got) == chunks[2][1]
    assert f'stale metadata.yaml (it counts {N_MESSAGES} messages)' in recovered[0].describe()


def _cli(*args, env=None):
    return subprocess.run([sys.executable, '-m', 'fabric_guidance.commands.cli', *map(str, args)], capture_output=True,
                          text=True, timeout=120, cwd=ROOT, env=env)


def _same_through_every_reader(recovered_bag: Path, expected: list) -> None:
    """The bag `recover` wrote, read by the package's indexed reader (no recovery needed), by
    the mcap library through its summary and by rosbags through metadata.yaml."""
    from rosbags.rosbag2 import Reader
    found = []
    indexed = [(t, ts, d) for t, _, ts, d in raw_messages(recovered_bag, recovered=found)]
    assert not found, [r.describe() for r in found]
    assert _by_topic(indexed) == _by_topic(expected)
    [mcap] = recovered_bag.glob('*.mcap')
    with open(mcap, 'rb') as f:
        reader = make_reader(f)
        assert reader.get_summary().statistics.message_count == len(expected)
        by_mcap = [(c.topic, m.log_time, bytes(m.data)) for _, c, m in reader.iter_messages()]
    assert _by_topic(by_mcap) == _by_topic(expected)
    with Reader(recovered_bag) as reader:
        by_rosbags = [(c.topic, ts, bytes(d)) for c, ts, d in reader.messages()]
        qos = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
    assert _by_topic(by_rosbags) == _by_topic(expected)
    return qos


def test_recover_writes_a_complete_bag_and_never_overwrites(written, tmp_path):
    _, data, sent, chunks, _, _ = written
    cut = tmp_path / 'cut'
    _read_cut(cut, data[:chunks[5][0] + 100])
    before = (cut / 'cut.mcap').read_bytes()
    proc = _cli('recover', cut)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert 'recovered a cut-off recording' in proc.stdout and 'written' in proc.stdout
    out = tmp_path / 'cut-recovered'
    _same_through_every_reader(out, sent[:chunks[5][1]])
    assert (cut / 'cut.mcap').read_bytes() == before and sorted(p.name for p in cut.iterdir()) == ['cut.mcap']
    again = _cli('recover', cut)
    assert again.returncode == 2 and 'exists already' in again.stdout, again.stdout
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith('.')] == []   # no staging left
    # the graph replay republishes the intact part and says so (no subscriber here: --wait 0)
    from fabric_guidance.graph.process_graph import fresh_domain_id, loopback_dds_env
    env = dict(os.environ, ROS_DOMAIN_ID=str(fresh_domain_id()), **loopback_dds_env())
    played = _cli('replay', cut, '--wait', '0', '--rate', '1000', '--topics', 'a', 'b', env=env)
    assert played.returncode == 0, played.stdout + played.stderr
    assert f'{chunks[5][1]} messages republished' in played.stdout
    assert len([line for line in played.stdout.splitlines() if 'recovered a cut-off recording' in line]) == 1
    nothing = _cli('recover', out)
    assert nothing.returncode == 0 and 'nothing to recover' in nothing.stdout
    (tmp_path / 'early').mkdir()
    (tmp_path / 'early' / 'early.mcap').write_bytes(data[:chunks[0][0] - 1])
    early = _cli('recover', tmp_path / 'early', '--out', tmp_path / 'x')
    assert early.returncode == 2 and 'before its first intact chunk' in early.stdout and not (tmp_path / 'x').exists()


# ---- bag_recorder killed


@pytest.mark.graph
def test_a_killed_recorder_leaves_a_bag_that_replays_up_to_the_kill(tmp_path):
    """pressure_controller guiding, bag_recorder (flush every 0.2 s) SIGKILLed while gaze and the
    controller's topics flow."""
    import numpy as np
    from geometry_msgs.msg import PointStamped, PoseStamped
    from std_msgs.msg import String
    from fabric_guidance import interface
    from fabric_guidance.bag import offline
    from fabric_guidance.bag.reader import scan_bag
    from fabric_guidance.core import ray_orientation
    from fabric_guidance.nodes import qos

    bag = tmp_path / 'bag'
    graph = Graph(tmp_path / 'logs')
    graph.start('bag_recorder', (), output=str(bag), flush_period_s=0.2)
    graph.start('pressure_controller', ('params/guidance.yaml',),
                calibration_file=str(CONFIG / 'calibrations' / 'sim-wearer.yaml'),
                target_publisher='test_probe')   # the probe plays target_selector
    probe = Probe(graph.domain_id)
    eye = np.array([0.0, 0.0, 1.2])

    def gaze_msg(yaw):
        y = np.radians(yaw)
        msg = PoseStamped()
        msg.header.frame_id = interface.IMMERSIVE_FRAME
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = eye
        o = msg.pose.orientation
        o.x, o.y, o.z, o.w = ray_orientation(np.array([np.cos(y), np.sin(y), 0.0]))
        return msg

    def on_disk() -> int:
        try:
            _, found, _ = scan_bag(bag)
        except (BagReadError, FileNotFoundError):
            return 0
        return sum(r.counts.get('/controller_input', 0) for r in found)

    try:
        node = probe.node
        gaze = node.create_publisher(PoseStamped, interface.GAZE, qos.SENSOR_QOS)
        target = node.create_publisher(PointStamped, interface.TARGET, qos.LATCHED_QOS)
        name = node.create_publisher(String, interface.ACTIVE_TARGET, qos.LATCHED_QOS)
        wait_until(lambda: node.count_subscribers('controller_input') >= 1 and node.count_subscribers('gaze') >= 2
                   and node.count_publishers('controller_input'), 20.0, what='controller and recorder')
        point = PointStamped()
        point.header.frame_id = interface.IMMERSIVE_FRAME
        point.point.x, point.point.y, point.point.z = eye + 2.0 * np.array([np.cos(0.7), np.sin(0.7), 0.0])
        name.publish(String(data='t1'))
        target.publish(point)
        deadline = time.monotonic() + 60.0
        seen = 0
        k = 0
        # Gaze keeps flowing, through the kill and after it, until a few hundred steps are on disk.
        while seen < 300:
            assert time.monotonic() < deadline, f'only {seen} steps on disk:\n{graph.log("bag_recorder")}'
            gaze.publish(gaze_msg(-0.2 * (k % 100)))
            k += 1
            time.sleep(0.02)             # gaze at about 50 Hz
            if k % 10 == 0:
                seen = on_disk()
        for _ in range(5):
            gaze.publish(gaze_msg(0.0))
            time.sleep(0.01)
        killed_ns = time.time_ns()
        assert graph.stop('bag_recorder', sig=signal.SIGKILL) == -signal.SIGKILL
        for _ in range(10):
            gaze.publish(gaze_msg(0.0))
            time.sleep(0.01)
    finally:
        probe.close()
        graph.stop_all()
    assert not (bag / 'metadata.yaml').exists()

    rec = offline.load(bag)
    assert len(rec.recovered) == 1 and 'no metadata.yaml' in rec.recovered[0]
    assert len(rec.inputs) >= seen                      # what was on disk before the kill stays
    result = offline.replay(rec)
    assert result.exact and result.step_gaps == 0 and result.unmatched == 0 and result.compared > 250, result
    _, [r], missing = scan_bag(bag)
    print(f'killed recorder: {r.total} messages recovered, the last {(killed_ns - r.last_ns) / 1e9:.2f} s '
          f'before the kill lost ({r.lost_bytes} bytes after the last intact chunk; flush_period_s 0.2)')

    proc = _cli('replay', bag, '--offline')
    assert proc.returncode == 0, proc.stdout + proc.stderr
    lines = [line for line in proc.stdout.splitlines() if 'recovered a cut-off recording' in line]
    assert len(lines) == 1 and 'no metadata.yaml' in lines[0] and 'lost the' in lines[0], proc.stdout
    assert 'of the recovered part' in proc.stdout

    proc = _cli('recover', bag)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    expected = [(t, ts, d) for t, _, ts, d in raw_messages(bag)]
    offered = _same_through_every_reader(tmp_path / 'bag-recovered', expected)
    assert offered['/gaze'][0].reliability.name == 'BEST_EFFORT'      # the channel's QoS kept
    assert offered['/controller_parameters'][0].durability.name == 'TRANSIENT_LOCAL'
    assert offline.replay(offline.load(tmp_path / 'bag-recovered')).exact


# ---- atomic writes killed

_WRITER = r'''
import hashlib, sys
from pathlib import Path
kind, path = sys.argv[1], Path(sys.argv[2])
if kind == 'calibration':
    from fabric_guidance.core.calibration import Calibration
    base = Calibration.load(sys.argv[3])
    versions = [Calibration.from_dict(dict(base.to_dict(), wearer=w)) for w in ('old', 'new')]
    def write(k):
        versions[k % 2].save(path)
else:
    from fabric_guidance.atomic import write_text
    bodies = [(c * 4_000_000) for c in 'ab']
    def write(k):
        body = bodies[k % 2]
        write_text(path, body + '\n' + hashlib.sha256(body.encode()).hexdigest() + '\n')
k = 0
while True:
    write(k)
    k += 1
    if k == 2:
        print('both written', flush=True)
'''


def _whole(kind: str, path: Path) -> str:
    if kind == 'calibration':
        return Calibration.load(path).wearer
    body, digest, end = path.read_text().split('\n')
    assert end == '' and hashlib.sha256(body.encode()).hexdigest() == digest, f'{path}: a partial report'
    return body[0]


@pytest.mark.parametrize('kind', ['calibration', 'report'])
def test_a_writer_killed_mid_write_leaves_the_old_file_or_the_new(tmp_path, kind):
    path = tmp_path / ('cal.yaml' if kind == 'calibration' else 'report.txt')
    rng = random.Random(kind)
    seen = set()
    for attempt in range(12):
        proc = subprocess.Popen([sys.executable, '-c', _WRITER, kind, str(path),
                                 str(CONFIG / 'calibrations' / 'sim-wearer.yaml')],
                                stdout=subprocess.PIPE, text=True, cwd=ROOT)
        try:
            assert proc.stdout.readline().strip() == 'both written'
            time.sleep(rng.uniform(0.0, 0.15))   # not a wait: the kill lands at a random moment of the loop
            os.kill(proc.pid, signal.SIGKILL)
        finally:
            proc.kill()
            proc.wait()
            proc.stdout.close()
        seen.add(_whole(kind, path))
    assert seen <= ({'old', 'new'} if kind == 'calibration' else {'a', 'b'})
    print(f'{kind}: 12 kills, the file always whole; versions found {sorted(seen)}; '
          f'temporary files left by the kills: {len([p for p in tmp_path.iterdir() if p.name.endswith(".tmp")])}')
