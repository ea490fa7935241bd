"""launch/guidance.launch.py and launch/sim.launch.py under launch_pytest, in a ROS 2 workspace.

launch, launch_ros and launch_pytest come with a ROS 2 installation and do not install from the
package index, so outside a workspace this module is skipped. test_graph.py runs the same nodes
as separate processes with the same parameter files, and runs everywhere.
"""
import os
import time

import pytest

launch_pytest = pytest.importorskip(
    'launch_pytest', reason='launch_pytest is missing (it ships with a ROS 2 installation, not the package index); '
                            'test_graph.py covers the same nodes and parameter files as processes')
import launch  # noqa: E402
from launch.actions import IncludeLaunchDescription  # noqa: E402
from launch.launch_description_sources import PythonLaunchDescriptionSource  # noqa: E402
from ament_index_python.packages import get_package_share_directory  # noqa: E402

import rclpy  # noqa: E402
from std_msgs.msg import Float64MultiArray, String  # noqa: E402

from fabric_guidance.nodes import common  # noqa: E402

SHARE = get_package_share_directory('fabric_guidance')
SESSION_DEADLINE_S = 60.0


def _include(name, **arguments):
    return IncludeLaunchDescription(PythonLaunchDescriptionSource(os.path.join(SHARE, 'launch', name)),
                                    launch_arguments=arguments.items())


@launch_pytest.fixture
def sim_graph():
    return launch.LaunchDescription([_include('sim.launch.py'), launch_pytest.actions.ReadyToTest()])


@launch_pytest.fixture
def lab_graph():
    # No PLC at this port: the lab graph must come up, stay vented and say so.
    return launch.LaunchDescription([_include('guidance.launch.py', plc_port='1'),
                                     launch_pytest.actions.ReadyToTest()])


def _collect(node, msg_type, topic, qos):
    got = []
    node.create_subscription(msg_type, topic, got.append, qos)
    return got


def _spin_until(node, predicate, timeout):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
        if predicate():
            return True
    return False


@pytest.mark.launch(fixture=sim_graph)
def test_sim_launch_guides_through_every_target():
    with rclpy.init():
        node = rclpy.create_node('launch_test_probe')
        found = _collect(node, String, common.TARGET_FOUND, common.EVENT_QOS)
        commands = _collect(node, Float64MultiArray, common.PRESSURE_COMMAND, common.COMMAND_QOS)
        assert _spin_until(node, lambda: len(found) >= 4, SESSION_DEADLINE_S), f'found only {found}'
        assert [m.data for m in found] == ['front_left', 'up_right', 'down_left', 'down_right']
        assert max(max(m.data) for m in commands) <= 375.0


@pytest.mark.launch(fixture=lab_graph)
def test_lab_launch_comes_up_vented_without_gaze():
    with rclpy.init():
        node = rclpy.create_node('launch_test_probe')
        commands = _collect(node, Float64MultiArray, common.PRESSURE_COMMAND, common.COMMAND_QOS)
        assert _spin_until(node, lambda: len(commands) >= 10, 20.0)
        assert all(max(m.data) == 0.0 for m in commands)
