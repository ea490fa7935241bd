"""The simulated graph: the lab graph (guidance.launch.py) against a mock PLC and a simulated
wearer, with the simulated wearer's calibration. What `make demo` runs without `launch`.

    ros2 launch fabric_guidance sim.launch.py condition:=2
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, IncludeLaunchDescription, SetEnvironmentVariable
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    share = get_package_share_directory('fabric_guidance')
    sim_params = os.path.join(share, 'config', 'sim.yaml')
    lab = IncludeLaunchDescription(
        PythonLaunchDescriptionSource(os.path.join(share, 'launch', 'guidance.launch.py')),
        launch_arguments={
            'calibration_file': os.path.join(share, 'config', 'calibrations', 'sim-wearer.yaml'),
            'condition': LaunchConfiguration('condition'),
            'plc_host': '127.0.0.1',
        }.items())
    return LaunchDescription([
        # The simulated graph talks to nobody else: DDS discovery stays on this machine.
        SetEnvironmentVariable('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST'),
        # issue 14: and its sockets on 127.0.0.1 only (config/fastdds_loopback.xml)
        SetEnvironmentVariable('FASTDDS_DEFAULT_PROFILES_FILE',
                               os.path.join(share, 'config', 'fastdds_loopback.xml')),
        DeclareLaunchArgument('condition', default_value='1',
                              description='1 surface adjusted, 2 surface fixed, 3 arm adjusted, 4 speech'),
        Node(package='fabric_guidance', executable='mock_plc', name='mock_plc', output='screen',
             parameters=[sim_params]),
        Node(package='fabric_guidance', executable='wearer_sim', name='wearer_sim', output='screen',
             parameters=[sim_params]),
        lab,
    ])
