"""Recording a guided session: `fabric-guidance demo --record DIR` (run_demo(record_dir=...))
writes a rosbag2 bag in MCAP that an independent reader (mcap + mcap_ros2) decodes completely,
with the QoS profiles in its metadata; the offline replay reproduces its commands exactly."""
import atexit
import dataclasses
import functools
from pathlib import Path
import shutil
import subprocess
import sys
import tempfile

import pytest
import yaml

# The independent reader (package.xml: mcap-ros2-support, which brings mcap). Without it this
# module skips with one line instead of failing `colcon test` at collection.
make_reader = pytest.importorskip('mcap.reader', reason='mcap is not installed (rosdep key mcap-ros2-support; '
                                  'pip install mcap-ros2-support)').make_reader
DecoderFactory = pytest.importorskip('mcap_ros2.decoder', reason='mcap_ros2 is not installed (rosdep key '
                                     'mcap-ros2-support; pip install mcap-ros2-support)').DecoderFactory

from fabric_guidance.bag import offline  # noqa: E402 (after the skips)
from fabric_guidance.bag.controller_io import FIELDS, INPUT_SIZE, setup_from_yaml  # noqa: E402
from fabric_guidance.bag.topics import TOPICS  # noqa: E402
from fabric_guidance.core.channels import ChannelMap, label_names  # noqa: E402
from fabric_guidance.paths import config_path, node_parameters  # noqa: E402


pytestmark = pytest.mark.graph  # starts a process graph with DDS

CHANNELS = ChannelMap.load(config_path('hardware/channel_map.yaml')).channels

#: Every topic a demo session publishes (calibration_status and speech: none in condition 1;
#: calibration_state: the latched `idle` of pressure_controller's start).
EXPECTED = {'/gaze', '/head_pose', '/target', '/active_target', '/target_found', '/target_markers',
            '/calibration_state', '/pressure_command', '/measured_pressure', '/diagnostics', '/controller_input',
            '/controller_parameters'}


@functools.lru_cache(maxsize=None)
def recorded_demo_bag() -> Path:
    """One demo session recorded (shared with test_replay.py: run once per test process)."""
    from fabric_guidance.commands.demo import run_demo
    out = Path(tempfile.mkdtemp(prefix='fabric-guidance-test-record-'))
    atexit.register(shutil.rmtree, out, True)   # kept for the test process's life, then removed
    with open(out / 'demo.out', 'w') as stream:
        code = run_demo(1, timeout_s=45.0, out_dir=out / 'logs', stream=stream, record_dir=out / 'bags')
    assert code == 0, (out / 'demo.out').read_text()
    bags = list((out / 'bags').iterdir())
    assert len(bags) == 1, bags
    return bags[0]


def test_demo_record_decodes_with_an_independent_reader():
    bag = recorded_demo_bag()
    files = list(bag.glob('*.mcap'))
    assert len(files) == 1
    counts, schemas = {}, {}
    with open(files[0], 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary.statistics.message_count > 0
        for schema, channel, message, decoded in reader.iter_decoded_messages():   # every message of every topic
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            schemas[channel.topic] = (schema.name, schema.encoding)
            assert channel.message_encoding == 'cdr'
            if channel.topic == '/pressure_command':
                assert len(decoded.data) == 18 and max(decoded.data) <= 375.0
                assert label_names(decoded.layout.dim[0].label) == CHANNELS
            elif channel.topic == '/measured_pressure':
                assert label_names(decoded.layout.dim[0].label) == CHANNELS
            elif channel.topic == '/controller_input':
                assert len(decoded.data) == INPUT_SIZE
                assert label_names(decoded.layout.dim[0].label) == FIELDS
            elif channel.topic == '/controller_parameters':
                assert setup_from_yaml(decoded.data).condition == 1
            elif channel.topic == '/gaze':
                assert decoded.header.frame_id == 'immersive'
            elif channel.topic == '/diagnostics':
                assert decoded.status
    assert EXPECTED <= set(counts), set(counts)
    assert sum(counts.values()) == summary.statistics.message_count
    for topic in EXPECTED:
        assert schemas[topic] == (TOPICS.get(topic, TOPICS.get(topic.lstrip('/')))[0], 'ros2msg')
    assert counts['/pressure_command'] > 100 and counts['/controller_parameters'] == 1


def test_the_targets_decode_from_the_definitions_the_bag_carries():
    """target_markers as a reader without ROS sees it (mcap_ros2 on the schema in the bag): the
    demo's four targets of guidance.yaml, spheres in the immersive frame named in `text`, the
    active one red, each activated in turn."""
    params = node_parameters('params/guidance.yaml', 'target_selector')
    names, positions = params['target_names'], params['target_positions']
    [mcap] = recorded_demo_bag().glob('*.mcap')
    with open(mcap, 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        found = [(schema, decoded)
                 for schema, _, _, decoded in reader.iter_decoded_messages(topics=['/target_markers'])]
    assert found, 'no target_markers in the bag'
    schema = found[0][0]
    assert (schema.name, schema.encoding) == ('visualization_msgs/msg/MarkerArray', 'ros2msg')
    definition = schema.data.decode()
    for used in ('visualization_msgs/Marker', 'std_msgs/Header', 'builtin_interfaces/Time', 'geometry_msgs/Pose',
                 'std_msgs/ColorRGBA', 'builtin_interfaces/Duration', 'sensor_msgs/CompressedImage',
                 'visualization_msgs/UVCoordinate', 'visualization_msgs/MeshFile'):
        assert f'MSG: {used}\n' in definition, used
    active = []
    for _, msg in found:
        assert [m.text for m in msg.markers] == names
        for i, m in enumerate(msg.markers):
            assert m.header.frame_id == 'immersive' and m.ns == 'targets' and m.id == i
            assert (m.type, m.action) == (2, 0)                      # SPHERE, ADD
            assert [m.pose.position.x, m.pose.position.y, m.pose.position.z] == positions[3 * i:3 * i + 3]
            assert m.scale.x == m.scale.y == m.scale.z == 0.1
        red = [m.text for m in msg.markers if (m.color.r, m.color.g, m.color.b) == (1.0, 0.0, 0.0)]
        assert len(red) <= 1, red
        active.append(red[0] if red else '')
    in_turn = [a for i, a in enumerate(active) if a and (i == 0 or a != active[i - 1])]
    assert in_turn == names, active


def test_metadata_lists_the_offered_qos_profiles():
    meta = yaml.safe_load((recorded_demo_bag() / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['storage_identifier'] == 'mcap' and meta['version'] == 9
    topics = {t['topic_metadata']['name']: t['topic_metadata'] for t in meta['topics_with_message_count']}
    assert set(topics) == {'/' + t.lstrip('/') for t in TOPICS}
    for name, md in topics.items():
        assert md['type_description_hash'].startswith('RIHS01_'), name
        assert len(md['offered_qos_profiles']) == 1, name
    qos = {name: md['offered_qos_profiles'][0] for name, md in topics.items()}
    assert qos['/gaze']['reliability'] == 'best_effort' and qos['/gaze']['depth'] == 5
    assert qos['/active_target']['durability'] == 'transient_local'
    assert qos['/target']['durability'] == 'transient_local'
    assert qos['/controller_parameters']['durability'] == 'transient_local'
    assert qos['/pressure_command']['reliability'] == 'reliable' and qos['/pressure_command']['depth'] == 10
    assert qos['/pressure_command']['durability'] == 'volatile'
    assert qos['/speech']['depth'] == 50


def test_offline_replay_reproduces_the_demo_exactly():
    bag = recorded_demo_bag()
    result = offline.replay(offline.load(bag))
    assert result.compared > 100 and result.unmatched == 0 and result.step_gaps == 0
    # The recorder may stop between the last step's input and its command; no more than that.
    assert result.after_last_command <= 1
    assert result.exact, result.worst
    print(f'offline replay: {result.compared} steps, {result.bag_duration_s:.2f} s of session in '
          f'{result.read_s + result.run_s:.3f} s: {result.speedup:.0f}x real time '
          '(printed, not asserted: the speed goal lives in `make bench`)')
    # The CLI as the user runs it.
    out = subprocess.run([sys.executable, '-m', 'fabric_guidance.commands.replay', str(bag), '--offline'],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
    assert 'reproduced exactly' in out.stdout and 'x real time' in out.stdout


def test_steps_past_the_last_recorded_command_are_told_apart_from_lost_commands():
    rec = offline.load(recorded_demo_bag())
    whole = offline.replay(rec)
    cut = offline.replay(dataclasses.replace(rec, commands=rec.commands[:-3]))
    # (the last command may be the vent sent at shutdown, which belongs to no step)
    assert cut.after_last_command >= whole.after_last_command + 2 and cut.unmatched == whole.unmatched
    assert cut.compared + cut.after_last_command == whole.compared + whole.after_last_command and cut.exact
    # A command lost mid-session shifts every later one: those steps no longer reproduce.
    holed = offline.replay(dataclasses.replace(rec, commands=rec.commands[:50] + rec.commands[51:]))
    assert holed.mismatched > 0 and not holed.exact
