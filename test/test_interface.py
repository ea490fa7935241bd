"""fabric_guidance/interface.py is the one source of the package's topic and service names,
types and QoS: docs/interfaces.md's tables are generated from it, the bag code derives from it."""
from pathlib import Path
import subprocess
import sys

import pytest

from fabric_guidance import interface
from fabric_guidance.bag.topics import BAG_QOS, TOPICS

DOCS = Path(__file__).resolve().parent.parent / 'docs' / 'interfaces.md'


def test_docs_tables_are_the_generated_ones():
    docs = DOCS.read_text()
    for table in interface.markdown().rstrip('\n').split('\n\n'):
        header = table.splitlines()[0]
        assert table + '\n' in docs, (
            f'docs/interfaces.md: the table under "{header}" differs from '
            '`python -m fabric_guidance.interface --markdown`; paste its output')


def test_markdown_command_prints_the_tables():
    out = subprocess.run([sys.executable, '-m', 'fabric_guidance.interface', '--markdown'],
                         capture_output=True, text=True, timeout=60, check=True).stdout
    assert out == interface.markdown()
    assert '| `gaze` | geometry_msgs/PoseStamped | sensor data' in out


def test_names_are_unique_and_every_qos_kind_known():
    names = [t.name for t in interface.TOPICS]
    assert len(names) == len(set(names))
    assert {t.qos for t in interface.TOPICS} <= set(interface.QOS_KINDS)
    assert len({s.name for s in interface.SERVICES}) == len(interface.SERVICES)


def test_bag_topics_derive_from_the_interface():
    recorded = {t.name: (t.type, t.qos) for t in interface.TOPICS if t.recorded}
    assert TOPICS == recorded
    assert interface.CONTROLLER_INPUT in TOPICS and interface.MAX_WRITTEN not in TOPICS
    for kind, (reliable, latched, depth) in interface.QOS_KINDS.items():
        if kind in BAG_QOS:
            assert BAG_QOS[kind].depth == depth
            assert (BAG_QOS[kind].durability.name == 'TRANSIENT_LOCAL') == latched
            assert (BAG_QOS[kind].reliability.name == 'RELIABLE') == reliable


def test_qos_profile_of_each_kind():
    from rclpy.qos import DurabilityPolicy, ReliabilityPolicy, qos_profile_sensor_data
    assert interface.qos_profile(interface.SENSOR) == qos_profile_sensor_data
    for kind, (reliable, latched, depth) in interface.QOS_KINDS.items():
        profile = interface.qos_profile(kind)
        assert profile.depth == depth
        assert (profile.reliability == ReliabilityPolicy.RELIABLE) == reliable
        assert (profile.durability == DurabilityPolicy.TRANSIENT_LOCAL) == latched
    with pytest.raises(KeyError, match='unknown QoS kind'):
        interface.qos_profile('fast')


def test_interface_imports_no_rclpy():
    code = ('import sys, fabric_guidance.interface, fabric_guidance.bag.topics; '
            'sys.exit(any(m.split(".")[0] == "rclpy" for m in sys.modules))')
    assert subprocess.run([sys.executable, '-c', code], timeout=60).returncode == 0
