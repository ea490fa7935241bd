"""The operator's views shipped in config/ (docs/operator_views.md): the RViz2 configuration and
the Foxglove layout name only topics of fabric_guidance/interface.py, with the types their
displays and panels read, in the immersive frame."""
from pathlib import Path

import pytest
import yaml

from fabric_guidance import interface

ROOT = Path(__file__).resolve().parent.parent
RVIZ = ROOT / 'config' / 'rviz' / 'fabric_guidance.rviz'

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
