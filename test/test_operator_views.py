"""The operator's views shipped in config/ (docs/operator_views.md): the RViz2 configuration and
the Foxglove layout name only topics of fabric_guidance/interface.py, with the types their
displays and panels read, in the immersive frame."""
import json
from pathlib import Path
import re
import subprocess
import sys

import pytest
import yaml

from fabric_guidance import interface
from fabric_guidance.lab import views
from fabric_guidance.core.channels import ChannelMap

ROOT = Path(__file__).resolve().parent.parent
RVIZ = ROOT / 'config' / 'rviz' / 'fabric_guidance.rviz'
FOXGLOVE = ROOT / 'config' / views.FOXGLOVE_LAYOUT
CHANNELS = ChannelMap.load(ROOT / 'config' / 'hardware' / 'channel_map.yaml').channels

#: RViz display class -> the message type it subscribes to (ros2/rviz,
#: rviz_default_plugins/plugins_description.xml `message_type`); None: no topic. A display of
#: any other class fails the test until it is added here.
RVIZ_DISPLAY_TYPES = {
    'rviz_default_plugins/Grid': None,
    'rviz_default_plugins/Axes': None,
    'rviz_default_plugins/Pose': 'geometry_msgs/msg/PoseStamped',
    'rviz_default_plugins/PointStamped': 'geometry_msgs/msg/PointStamped',
    'rviz_default_plugins/MarkerArray': 'visualization_msgs/msg/MarkerArray',
}


def _topic_of(absolute: str) -> interface.Topic:
    """The interface's topic of an absolute name in the root namespace, as the views use them."""
    assert absolute.startswith('/'), f'{absolute}: the views name topics absolutely'
    name = absolute if absolute in (t.name for t in interface.TOPICS) else absolute[1:]
    return interface.topic(name)


def _displays(displays):
    for display in displays:
        if display['Class'] == 'rviz_common/Group':
            yield from _displays(display.get('Displays', []))
        else:
            yield display


@pytest.fixture(scope='module')
def rviz():
    return yaml.safe_load(RVIZ.read_text())


def test_rviz_fixed_frame_is_the_immersive_frame(rviz):
    assert rviz['Visualization Manager']['Global Options']['Fixed Frame'] == interface.IMMERSIVE_FRAME


def test_rviz_displays_read_the_interfaces_topics_with_the_publishers_qos(rviz):
    topics = {}
    for display in _displays(rviz['Visualization Manager']['Displays']):
        cls = display['Class']
        assert cls in RVIZ_DISPLAY_TYPES, f'display {display["Name"]!r}: class {cls} not in the table'
        expected_type = RVIZ_DISPLAY_TYPES[cls]
        assert ('Topic' in display) == (expected_type is not None), display['Name']
        assert display['Enabled'] is True, display['Name']
        if expected_type is None:
            continue
        qos = display['Topic']
        topic = _topic_of(qos['Value'])
        assert topic.type == expected_type, (f'{display["Name"]}: {topic.name} is {topic.type}, '
                                             f'{cls} reads {expected_type}')
        # The subscription must match the publisher (a reliable reader gets nothing from a
        # best-effort writer) and get a latched topic's last message when RViz starts late.
        reliable, latched, _ = interface.QOS_KINDS[topic.qos]
        assert qos['Reliability Policy'] == ('Reliable' if reliable else 'Best Effort'), topic.name
        assert qos['Durability Policy'] == ('Transient Local' if latched else 'Volatile'), topic.name
        assert qos['History Policy'] == 'Keep Last' and qos['Depth'] >= 1, topic.name
        topics[topic.name] = cls
    # What the issue asks the view to show: gaze ray, head pose, targets.
    assert topics == {interface.GAZE: 'rviz_default_plugins/Pose', interface.HEAD_POSE: 'rviz_default_plugins/Pose',
                      interface.TARGET_MARKERS: 'rviz_default_plugins/MarkerArray'}


def test_rviz_draws_the_gaze_as_an_arrow_along_its_x_axis(rviz):
    # gaze's orientation has its x axis along the ray (interface.py): RViz's arrow is drawn along x.
    [gaze] = [d for d in _displays(rviz['Visualization Manager']['Displays'])
              if d.get('Topic', {}).get('Value') == '/' + interface.GAZE]
    assert gaze['Shape'] == 'Arrow' and gaze['Shaft Length'] > 0


def test_rviz_tools_publish_nothing(rviz):
    # Tools such as SetGoal or PublishPoint publish on topics the package does not know.
    for tool in rviz['Visualization Manager']['Tools']:
        assert 'Topic' not in tool, tool['Class']


#: What Foxglove's 3D panel draws of a topic, by the topic's type (geometry_msgs/PoseStamped as an
#: arrow or axes, visualization_msgs/MarkerArray as its markers).
FOXGLOVE_3D_TYPES = {'geometry_msgs/msg/PoseStamped', 'visualization_msgs/msg/MarkerArray'}


@pytest.fixture(scope='module')
def foxglove():
    return json.loads(FOXGLOVE.read_text())


def test_foxglove_layout_is_the_generated_one():
    assert FOXGLOVE.read_text() == views.foxglove_json(), (
        f'{FOXGLOVE.relative_to(ROOT)} differs from the generator: '
        f'python -m fabric_guidance.lab.views --foxglove > {FOXGLOVE.relative_to(ROOT)}')
    out = subprocess.run([sys.executable, '-m', 'fabric_guidance.lab.views', '--foxglove'], capture_output=True,
                         text=True, timeout=60, check=True).stdout
    assert out == FOXGLOVE.read_text()


def _panel_ids(node):
    if isinstance(node, str):
        return [node]
    return _panel_ids(node['first']) + _panel_ids(node['second'])


def test_foxglove_layout_places_every_configured_panel_once(foxglove):
    placed = _panel_ids(foxglove['layout'])
    assert sorted(placed) == sorted(foxglove['configById']) and len(set(placed)) == len(placed)
    kinds = {panel.split('!')[0] for panel in placed}
    assert kinds == {'3D', 'Plot', 'DiagnosticSummary', 'RawMessages'}


def test_foxglove_3d_panel_shows_gaze_head_pose_and_targets_in_the_immersive_frame(foxglove):
    [three_d] = [c for panel, c in foxglove['configById'].items() if panel.startswith('3D!')]
    assert three_d['followTf'] == interface.IMMERSIVE_FRAME
    shown = {}
    for name, settings in three_d['topics'].items():
        topic = _topic_of(name)
        assert topic.type in FOXGLOVE_3D_TYPES, f'{name}: the 3D panel does not draw {topic.type}'
        assert settings['visible'] is True, name
        shown[topic.name] = settings
    assert set(shown) == {interface.GAZE, interface.HEAD_POSE, interface.TARGET_MARKERS}
    assert shown[interface.GAZE]['type'] == 'arrow'      # along the pose's x axis: the gaze ray


def test_foxglove_plots_are_the_channel_maps_channels_in_order(foxglove):
    plots = {c['paths'][0]['value'].split('.')[0]: c for panel, c in foxglove['configById'].items()
             if panel.startswith('Plot!')}
    assert set(plots) == {'/' + interface.PRESSURE_COMMAND, '/' + interface.MEASURED_PRESSURE}
    for topic, plot in plots.items():
        assert _topic_of(topic).type == 'std_msgs/msg/Float64MultiArray'
        series = [(p['label'], p['value']) for p in plot['paths']]
        assert series == [(name, f'{topic}.data[{i}]') for i, name in enumerate(CHANNELS)]
        assert all(p['enabled'] for p in plot['paths'])


def test_foxglove_names_only_the_interfaces_topics(foxglove):
    """Every topic a panel reads, wherever the panel keeps it, is a topic of the interface."""
    named = set()
    for panel, config in foxglove['configById'].items():
        for key, value in _items(config):
            if key in ('value', 'topicPath', 'topicToRender'):
                named.add(re.match(r'(/[^.\[{]+)', value).group(1))
        named |= set(config.get('topics', {}))
    assert named == {'/gaze', '/head_pose', '/target_markers', '/pressure_command', '/measured_pressure',
                     '/diagnostics', '/active_target'}
    for name in named:
        _topic_of(name)          # KeyError for a topic the interface does not have
    assert _topic_of('/diagnostics').type == 'diagnostic_msgs/msg/DiagnosticArray'


def _items(node):
    if isinstance(node, dict):
        for key, value in node.items():
            if isinstance(value, str):
                yield key, value
            yield from _items(value)
    elif isinstance(node, list):
        for value in node:
            yield from _items(value)


def test_the_generator_follows_another_channel_map(tmp_path):
    data = yaml.safe_load((ROOT / 'config' / 'hardware' / 'channel_map.yaml').read_text())
    data['channels'] = list(reversed(data['channels']))
    path = tmp_path / 'reversed.yaml'
    path.write_text(yaml.safe_dump(data))
    layout = json.loads(views.foxglove_json(path))
    labels = [p['label'] for p in layout['configById'][views.COMMAND_PANEL]['paths']]
    assert labels == data['channels'] and labels != list(CHANNELS)


def test_a_bag_holds_every_topic_the_views_read(rviz, foxglove):
    """Opened on a recorded bag, neither view misses a topic (target_markers included)."""
    names = {d['Topic']['Value'] for d in _displays(rviz['Visualization Manager']['Displays']) if 'Topic' in d}
    for config in foxglove['configById'].values():
        names |= set(config.get('topics', {}))
        names |= {re.match(r'(/[^.\[{]+)', value).group(1) for key, value in _items(config)
                  if key in ('value', 'topicPath', 'topicToRender')}
    assert '/target_markers' in names and '/pressure_command' in names
    assert [n for n in sorted(names) if not _topic_of(n).recorded] == []


def test_the_foxglove_layout_of_a_namespaced_graph_reads_that_graphs_topics():
    """`--namespace suit_a`: every topic of the layout is suit_a's, /diagnostics the shared one."""
    import json
    import re
    text = views.foxglove_json(namespace='suit_a')
    topics = set(re.findall(r'"(/[a-z_/]+)(?:\.data\[\d+\])?"', text))
    assert topics and all(t.startswith('/suit_a/') or t == interface.DIAGNOSTICS for t in topics), topics
    assert json.loads(text)['configById'].keys() == json.loads(views.foxglove_json())['configById'].keys()
