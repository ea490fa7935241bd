"""The lab graph: gaze_bridge, target_selector, pressure_controller, plc_output.

    ros2 launch fabric_guidance guidance.launch.py plc_host:=192.168.1.50 \
        calibration_file:=/data/calibrations/alice.yaml condition:=1 \
        bind_address:=192.168.1.10 allowed_senders:="['192.168.1.20']"

Parameters come from config/guidance.yaml (or params_file:=...); an argument given here
overrides the file, an argument left empty keeps the file's value.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

ARGUMENTS = {
    # name: (node, parameter, type, description)
    'plc_host': ('plc_output', 'plc_host', str, "the PLC's address (Modbus TCP)"),
    'plc_port': ('plc_output', 'plc_port', int, "the PLC's Modbus TCP port"),
    'calibration_file': ('pressure_controller', 'calibration_file', str, "the wearer's calibration (YAML)"),
    'condition': ('pressure_controller', 'condition', int, '1 surface adjusted, 2 surface fixed, 3 arm adjusted, 4 speech'),
    'bind_address': ('gaze_bridge', 'bind_address', str, 'UDP address the gaze bridge listens on'),
    'gaze_port': ('gaze_bridge', 'port', int, 'UDP port the gaze bridge listens on'),
    'allowed_senders': ('gaze_bridge', 'allowed_senders', list, "HoloLens addresses accepted, e.g. \"['192.168.1.20']\""),
}
NODES = ('gaze_bridge', 'target_selector', 'pressure_controller', 'plc_output')


def _nodes(context, *args, **kwargs):
    params_file = LaunchConfiguration('params_file').perform(context)
    use_sim_time = LaunchConfiguration('use_sim_time').perform(context).lower() == 'true'
    overrides = {name: {'use_sim_time': use_sim_time} for name in NODES}
    for arg, (node, parameter, kind, _) in ARGUMENTS.items():
        text = LaunchConfiguration(arg).perform(context)
        if not text:
            continue
        if kind is list:
            import yaml
            value = [str(v) for v in yaml.safe_load(text)]
        else:
            value = kind(text)
        overrides[node][parameter] = value
    return [Node(package='fabric_guidance', executable=name, name=name, output='screen',
                 parameters=[params_file, overrides[name]]) for name in NODES]


def generate_launch_description():
    share = get_package_share_directory('fabric_guidance')
    return LaunchDescription([
        DeclareLaunchArgument('params_file', default_value=os.path.join(share, 'config', 'guidance.yaml'),
                              description='parameter file of the four nodes'),
        DeclareLaunchArgument('use_sim_time', default_value='false', description='use /clock (rosbag replay)'),
        *[DeclareLaunchArgument(arg, default_value='', description=f'{desc} (empty: from params_file)')
          for arg, (_, _, _, desc) in ARGUMENTS.items()],
        OpaqueFunction(function=_nodes),
    ])
