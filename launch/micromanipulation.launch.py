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

guidance.launch.py takes one params_file: this file merges config/guidance.yaml (or
base_params_file:=...) with config/micromanipulation.yaml (or micromanipulation_params_file:=...),
node by node, the second winning, into a temporary file and passes that on. The other arguments
of guidance.launch.py (plc_host, calibration_file, condition, ...) pass through.
"""
import os
import tempfile

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, GroupAction, IncludeLaunchDescription, OpaqueFunction
from launch.conditions import IfCondition
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node, SetRemap
import yaml

OBJECTS = ('holding_pipette', 'microbead', 'injection_pipette')
PASS_THROUGH = ('plc_host', 'plc_port', 'calibration_file', 'condition', 'bind_address', 'gaze_port',
                'allowed_senders', 'use_sim_time')


def merge_params(base: dict, extra: dict) -> dict:
    """Node by node: the parameters of `extra` over those of `base`."""
    out = {node: {'ros__parameters': dict((section or {}).get('ros__parameters', {}))}
           for node, section in (base or {}).items()}
    for node, section in (extra or {}).items():
        out.setdefault(node, {'ros__parameters': {}})['ros__parameters'].update(
            (section or {}).get('ros__parameters', {}))
    return out


def _graph(context, *args, **kwargs):
    share = get_package_share_directory('fabric_guidance')
    base_file = LaunchConfiguration('base_params_file').perform(context)
    extra_file = LaunchConfiguration('micromanipulation_params_file').perform(context)
    with open(base_file) as f:
        base = yaml.safe_load(f)
    with open(extra_file) as f:
        extra = yaml.safe_load(f)
    fd, merged = tempfile.mkstemp(prefix='fabric_guidance_micromanipulation_', suffix='.yaml')
    with os.fdopen(fd, 'w') as f:
        yaml.safe_dump(merge_params(base, extra), f, sort_keys=False)

    arguments = {'params_file': merged}
    for name in PASS_THROUGH:
        value = LaunchConfiguration(name).perform(context)
        if value:
            arguments[name] = value
    simulated_wearer = LaunchConfiguration('wearer_sim').perform(context).lower() == 'true'
    if simulated_wearer:
        arguments.setdefault('plc_host', '127.0.0.1')
        arguments.setdefault('calibration_file', os.path.join(share, 'config', 'calibrations', 'sim-wearer.yaml'))
    remaps = [SetRemap(src=f'live_targets/{name}', dst=LaunchConfiguration(f'{name}_topic')) for name in OBJECTS]
    lab = GroupAction([
        *remaps,
        IncludeLaunchDescription(PythonLaunchDescriptionSource(os.path.join(share, 'launch', 'guidance.launch.py')),
                                 launch_arguments=arguments.items()),
    ])
    sim_params = os.path.join(share, 'config', 'sim.yaml')
    actions = [lab,
               Node(package='fabric_guidance', executable='micromanipulator_sim', name='micromanipulator_sim',
                    output='screen', parameters=[merged], condition=IfCondition(LaunchConfiguration('micromanipulator_sim')),
                    remappings=[(f'live_targets/{name}', LaunchConfiguration(f'{name}_topic')) for name in OBJECTS])]
    if simulated_wearer:
        actions += [Node(package='fabric_guidance', executable=name, name=name, output='screen',
                         parameters=[sim_params]) for name in ('mock_plc', 'wearer_sim')]
    return actions


def generate_launch_description():
    share = get_package_share_directory('fabric_guidance')
    config = os.path.join(share, 'config')
    return LaunchDescription([
        DeclareLaunchArgument('base_params_file', default_value=os.path.join(config, 'guidance.yaml'),
                              description='parameters of the lab graph'),
        DeclareLaunchArgument('micromanipulation_params_file',
                              default_value=os.path.join(config, 'micromanipulation.yaml'),
                              description='live targets, scale, offset and sequence (merged over base_params_file)'),
        *[DeclareLaunchArgument(f'{name}_topic', default_value=f'live_targets/{name}',
                                description=f"the stack's PoseStamped topic of the {name.replace('_', ' ')} "
                                            '(microscope frame, m)') for name in OBJECTS],
        DeclareLaunchArgument('micromanipulator_sim', default_value='false',
                              description='also start the simulated micromanipulation stack'),
        DeclareLaunchArgument('wearer_sim', default_value='false',
                              description="also start mock_plc and wearer_sim, with the sim wearer's calibration"),
        *[DeclareLaunchArgument(name, default_value='', description='passed to guidance.launch.py (empty: its default)')
          for name in PASS_THROUGH],
        OpaqueFunction(function=_graph),
    ])
