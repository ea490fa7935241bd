"""The paper's micromanipulation demonstration: the lab graph (guidance.launch.py) guiding the
wearer to the holding pipette, the microbead and the injection pipette of a micromanipulation
stack, whose poses (PoseStamped, microscope frame, m) are mapped x1000 into the immersive frame.

    # with the real stack: remap its pose topics onto the live targets
    ros2 launch fabric_guidance micromanipulation.launch.py plc_host:=192.168.1.50 \
        calibration_file:=/data/calibrations/alice.yaml \
        holding_pipette_topic:=/micromanipulation/holding_pipette/pose \
        microbead_topic:=/micromanipulation/microbead/pose \
        injection_pipette_topic:=/micromanipulation/injection_pipette/pose
    # all simulated: micromanipulator_sim, mock_plc and wearer_sim with the sim wearer's calibration
    ros2 launch fabric_guidance micromanipulation.launch.py micromanipulator_sim:=true wearer_sim:=true

guidance.launch.py loads config/params/guidance.yaml (or base_params_file:=...) and then
config/params/micromanipulation.yaml (or micromanipulation_params_file:=...) for every node, the second
winning (no merged copy is written). The other arguments of guidance.launch.py (plc_host,
calibration_file, condition, ...) pass through. With wearer_sim:=true the lab graph starts once
the mock PLC listens, and the mock PLC outlives plc_output's vent on shutdown. namespace:=NAME
puts every node, the simulated ones included, in that namespace (a second suit on the domain).
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, GroupAction, IncludeLaunchDescription, OpaqueFunction
from launch.conditions import IfCondition
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node, SetRemap

from fabric_guidance.graph.launch_support import (NodeOverrides, after_mock_plc_listens, lab_node_kwargs,
                                                  launch_namespace, loopback_dds_actions, namespace_argument,
                                                  require_own_plc)

OBJECTS = ('holding_pipette', 'microbead', 'injection_pipette')
PASS_THROUGH = ('plc_host', 'plc_port', 'calibration_file', 'wearer', 'condition', 'study', 'bind_address', 'gaze_port',
                'allowed_senders', 'headset_address', 'display_port', 'use_sim_time', 'autostart', 'keystore',
                'discovery_server', 'start_discovery_server', 'respawn', 'respawn_delay', 'mock_plc')


def _graph(context, *args, **kwargs):
    share = get_package_share_directory('fabric_guidance')
    base_file = LaunchConfiguration('base_params_file').perform(context)
    extra_file = LaunchConfiguration('micromanipulation_params_file').perform(context)
    arguments = {'params_file': base_file, 'extra_params_file': extra_file}
    for name in PASS_THROUGH:
        value = LaunchConfiguration(name).perform(context)
        if value:
            arguments[name] = value
    namespace = launch_namespace(context)
    if namespace:
        arguments['namespace'] = namespace
    simulated_wearer = LaunchConfiguration('wearer_sim').perform(context).lower() == 'true'
    if simulated_wearer and arguments.get('mock_plc', '').strip().lower() == 'true':
        raise ValueError('launch argument mock_plc:=true with wearer_sim:=true: wearer_sim:=true starts its own '
                         'mock PLC; give one of them')
    # Its own mock PLC (simulated) or the lab's PLC: with a namespace, named here.
    require_own_plc(namespace, {name: arguments.get(name, '')
                                for name in (('plc_port',) if simulated_wearer else ('plc_host', 'plc_port'))})
    if simulated_wearer:
        arguments.setdefault('plc_host', '127.0.0.1')
        arguments.setdefault('calibration_file', os.path.join(share, 'config', 'calibrations', 'sim-wearer.yaml'))
        arguments.setdefault('headset_address', '127.0.0.1')   # the simulated headset is wearer_sim
        arguments.setdefault('display_port', '5006')
        arguments.setdefault('respawn', 'false')   # simulated: guide at once, as sim.launch.py
    remaps = [SetRemap(src=f'live_targets/{name}', dst=LaunchConfiguration(f'{name}_topic')) for name in OBJECTS]
    lab = GroupAction([
        *remaps,
        IncludeLaunchDescription(PythonLaunchDescriptionSource(os.path.join(share, 'launch', 'guidance.launch.py')),
                                 launch_arguments=arguments.items()),
    ])
    sim_params = os.path.join(share, 'config', 'params', 'sim.yaml')
    stack = Node(package='fabric_guidance', executable='micromanipulator_sim', namespace=namespace,
                 name='micromanipulator_sim', output='screen', parameters=[extra_file],
                 condition=IfCondition(LaunchConfiguration('micromanipulator_sim')),
                 remappings=[(f'live_targets/{name}', LaunchConfiguration(f'{name}_topic'))
                             for name in OBJECTS], **lab_node_kwargs(context, 'micromanipulator_sim'))
    if not simulated_wearer:
        return [lab, stack]
    # The simulated PLC and wearer on the ports the lab graph was given, if any.
    ports = NodeOverrides(context)
    mock_ports = {'port': int(arguments['plc_port'])} if 'plc_port' in arguments else {}
    wearer_ports = {'bridge_port': int(arguments['gaze_port'])} if 'gaze_port' in arguments else {}
    wearer_ports['display_port'] = int(arguments['display_port'])
    mock_plc = Node(package='fabric_guidance', executable='mock_plc', name='mock_plc', namespace=namespace,
                    output='screen', parameters=[sim_params, *ports.files('mock_plc', mock_ports)],
                    **lab_node_kwargs(context, 'mock_plc'))
    wearer = Node(package='fabric_guidance', executable='wearer_sim', name='wearer_sim', namespace=namespace,
                  output='screen',
                  parameters=[sim_params, *ports.files('wearer_sim', wearer_ports)],
                  **lab_node_kwargs(context, 'wearer_sim'))
    # All simulated: DDS on loopback, as sim.launch.py (a real plc_output elsewhere on the
    # domain must never hear this graph's pressure_command).
    return [*loopback_dds_actions(share), mock_plc, wearer, stack, after_mock_plc_listens(mock_plc, [lab]),
            ports.cleanup_action()]


def generate_launch_description():
    share = get_package_share_directory('fabric_guidance')
    config = os.path.join(share, 'config')
    return LaunchDescription([
        DeclareLaunchArgument('base_params_file', default_value=os.path.join(config, 'params', 'guidance.yaml'),
                              description='parameters of the lab graph'),
        DeclareLaunchArgument('micromanipulation_params_file',
                              default_value=os.path.join(config, 'params', 'micromanipulation.yaml'),
                              description='live targets, scale, offset and sequence (loaded '
                                          'after base_params_file: its values win)'),
        *[DeclareLaunchArgument(f'{name}_topic', default_value=f'live_targets/{name}',
                                description=f"the stack's PoseStamped topic of the {name.replace('_', ' ')} "
                                            '(microscope frame, m)') for name in OBJECTS],
        DeclareLaunchArgument('micromanipulator_sim', default_value='false',
                              description='also start the simulated micromanipulation stack'),
        DeclareLaunchArgument('wearer_sim', default_value='false',
                              description="also start mock_plc and wearer_sim, with the sim wearer's calibration"),
        *[DeclareLaunchArgument(name, default_value='', description='passed to guidance.launch.py (empty: its default)')
          for name in PASS_THROUGH],
        namespace_argument(),
        OpaqueFunction(function=_graph),
    ])
