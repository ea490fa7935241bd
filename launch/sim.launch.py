"""The simulated graph: the lab graph (guidance.launch.py) against a mock PLC and a simulated
wearer, with the simulated wearer's calibration and config/params/sim.yaml over config/params/guidance.yaml
for every node (as `make demo` runs it).

    ros2 launch fabric_guidance sim.launch.py condition:=2
    # a study session's graph (docs/study.md): wearer_sim a participant of the paper's accuracy task
    ros2 launch fabric_guidance sim.launch.py study:=accuracy
    # a second suit beside the first, on the same domain (docs/interfaces.md, "Names and namespaces")
    ros2 launch fabric_guidance sim.launch.py namespace:=suit_b plc_port:=1602 gaze_port:=5105 display_port:=5106

With a namespace, plc_port:= is required (the launch refuses to start without it): a second
suit on the default port would reach the first suit's mock PLC.

The lab graph starts once the mock PLC listens (plc_output's first connection then succeeds).
On Ctrl-C the mock PLC stays up until plc_output has vented and closed its connection
(mock_plc's shutdown_grace_s), whichever process the signal reaches first.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, IncludeLaunchDescription, OpaqueFunction
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from fabric_guidance.graph.launch_support import (NodeOverrides, after_mock_plc_listens, lab_node_kwargs,
                                                  launch_namespace, loopback_dds_actions, namespace_argument,
                                                  require_own_plc, study_argument, study_params_files)

#: The mock PLC's port without a namespace (config/params/guidance.yaml's plc_port).
DEFAULT_PLC_PORT = '1502'


def _graph(context, *args, **kwargs):
    share = get_package_share_directory('fabric_guidance')
    sim_params = os.path.join(share, 'config', 'params', 'sim.yaml')
    plc_port = LaunchConfiguration('plc_port').perform(context)
    # A second simulated suit with the default port would find the first suit's mock PLC there.
    require_own_plc(launch_namespace(context), {'plc_port': plc_port})
    plc_port = plc_port or DEFAULT_PLC_PORT
    gaze_port = LaunchConfiguration('gaze_port').perform(context)
    display_port = LaunchConfiguration('display_port').perform(context)
    lab = IncludeLaunchDescription(
        PythonLaunchDescriptionSource(os.path.join(share, 'launch', 'guidance.launch.py')),
        launch_arguments={
            'extra_params_file': sim_params,
            'calibration_file': os.path.join(share, 'config', 'calibrations', 'sim-wearer.yaml'),
            'condition': LaunchConfiguration('condition'),
            'plc_host': '127.0.0.1',
            'plc_port': plc_port,
            'gaze_port': gaze_port,
            # The simulated headset is wearer_sim, on this machine.
            'headset_address': '127.0.0.1',
            'display_port': display_port,
            'autostart': LaunchConfiguration('autostart'),
            # The simulated graph guides at once, as `make demo` does; the lab's restarts and
            # their enable gate are for a wearer (guidance.launch.py).
            'respawn': 'false',
            'namespace': LaunchConfiguration('namespace'),
            'study': LaunchConfiguration('study'),
        }.items())
    namespace = launch_namespace(context)
    ports = NodeOverrides(context)
    mock_plc = Node(package='fabric_guidance', executable='mock_plc', name='mock_plc', namespace=namespace,
                    output='screen',
                    parameters=[sim_params, ports.file('mock_plc', {'port': int(plc_port)})],
                    **lab_node_kwargs(context, 'mock_plc'))
    wearer = Node(package='fabric_guidance', executable='wearer_sim', name='wearer_sim', namespace=namespace,
                  output='screen',
                  parameters=[sim_params, *study_params_files(context, share),
                              ports.file('wearer_sim', {'bridge_port': int(gaze_port),
                                                        'display_port': int(display_port)})],
                  **lab_node_kwargs(context, 'wearer_sim'))
    return [mock_plc, wearer, after_mock_plc_listens(mock_plc, [lab]), ports.cleanup_action()]


def generate_launch_description():
    # The simulated graph talks to nobody else: Fast DDS on 127.0.0.1 only, as in `make demo`
    # and the tests, on Jazzy (Fast DDS 2) as on Kilted (Fast DDS 3).
    return LaunchDescription([
        *loopback_dds_actions(get_package_share_directory('fabric_guidance')),
        DeclareLaunchArgument('condition', default_value='1',
                              description='1 surface adjusted, 2 surface fixed, 3 arm adjusted, '
                                          '4 speech'),
        DeclareLaunchArgument('plc_port', default_value='',
                              description=f"the mock PLC's Modbus TCP port (empty: {DEFAULT_PLC_PORT}; "
                                          'required with a namespace)'),
        DeclareLaunchArgument('gaze_port', default_value='5005',
                              description='UDP port of the gaze bridge'),
        DeclareLaunchArgument('display_port', default_value='5006',
                              description="UDP port of the simulated headset's display (wearer_sim)"),
        DeclareLaunchArgument('autostart', default_value='true',
                              description='configure and activate the lifecycle nodes (false: leave them '
                                          'to the operator)'),
        namespace_argument(),
        study_argument(),
        OpaqueFunction(function=_graph),
    ])
