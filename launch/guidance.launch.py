"""The lab graph: gaze_bridge, target_selector, pressure_controller, plc_output, headset_display.

    ros2 launch fabric_guidance guidance.launch.py plc_host:=192.168.1.50 \
        calibration_file:=/data/calibrations/alice.yaml condition:=1 \
        bind_address:=192.168.1.10 allowed_senders:="['192.168.1.20']" headset_address:=192.168.1.20

headset_address goes to gaze_bridge (clock pings) and headset_display (display messages), the
two nodes that send to the HoloLens (docs/headset.md).

pressure_controller and plc_output are lifecycle nodes: with autostart:=true (the default) this
launch configures and activates them; autostart:=false leaves them unconfigured for the
operator (`ros2 lifecycle set /plc_output configure`, then activate; docs/lifecycle.md).

respawn:=true (the default) restarts a node whose process died, respawn_delay:=2.0 s later,
and starts pressure_controller disabled: every start, first or respawned, stays vented until
the operator calls `enable` (`ros2 service call /pressure_controller/enable std_srvs/srv/SetBool
"{data: true}"`).
The lifecycle nodes then bring themselves up at every start (their autostart parameter, from
the launch argument) instead of by the launch's lifecycle events. respawn:=false: nothing
restarts, and the controller guides as soon as it is active (docs/lifecycle.md, "Restarts").

namespace:=suit_a starts every node in that namespace: topics resolve there and the services
are the nodes' own (`/suit_a/pressure_controller/enable`), so that a second suit runs on the
same domain (docs/interfaces.md, "Names and namespaces"). It needs that suit's own PLC address
(plc_host:= and/or plc_port:=): without one the launch refuses to start, naming them, as the
parameter file's address is the root suit's PLC.

mock_plc:=true runs the lab graph against a mock PLC on this PC (plc_host 127.0.0.1, plc_port or
1502), started first: a lab's dry run with the real headset and a person, no suit (docs/launch.md);
`fabric-guidance dry-run --headset-address ...` starts the same without `ros2 launch`.

keystore:=DIR runs each node in its SROS2 enclave, security enforced (docs/security.md);
discovery_server:=ADDRESS[:PORT] makes every node a client of that discovery server, and
start_discovery_server:=true also runs it here (docs/lab_network.md). Unset, nothing changes.

Parameters come from config/params/guidance.yaml (or params_file:=...), then extra_params_file:=...
if given (its values win), then config/params/study-<task>.yaml with study:=speed|accuracy (a
study session's settings, docs/study.md); an argument given here overrides both, an argument left empty keeps
the files' value. The arguments reach each node as a file keyed by the node's own name, loaded
last: a node-scoped value loaded later always wins in rcl, whatever else the launch sets.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode, Node
import yaml

from fabric_guidance.interface import MANAGED_NODES
from fabric_guidance.graph.launch_support import (NodeOverrides, after_mock_plc_listens, lab_launch_arguments,
                                                  lab_network_actions, lab_node_kwargs, launch_namespace,
                                                  lifecycle_bring_up, namespace_argument, require_own_plc,
                                                  respawn_arguments,
                                                  respawn_enabled, respawn_kwargs, study_argument,
                                                  study_params_files)

ARGUMENTS = {
    # name: (node, parameter, type, description)
    'plc_host': ('plc_output', 'plc_host', str, "the PLC's address (Modbus TCP)"),
    'plc_port': ('plc_output', 'plc_port', int, "the PLC's Modbus TCP port"),
    'calibration_file': ('pressure_controller', 'calibration_file', str,
                         "the wearer's calibration (YAML)"),
    'wearer': ('pressure_controller', 'wearer', str,
               "the participant's id: a calibration is written as <wearer>.yaml in calibration_dir, and "
               'that file is loaded when it exists'),
    'condition': ('pressure_controller', 'condition', int,
                  '1 surface adjusted, 2 surface fixed, 3 arm adjusted, 4 speech'),
    'bind_address': ('gaze_bridge', 'bind_address', str, 'UDP address the gaze bridge listens on'),
    'gaze_port': ('gaze_bridge', 'port', int, 'UDP port the gaze bridge listens on'),
    'allowed_senders': ('gaze_bridge', 'allowed_senders', list,
                        "HoloLens addresses accepted, e.g. \"['192.168.1.20']\""),
    'headset_address': (('gaze_bridge', 'headset_display'), 'headset_address', str,
                        "the HoloLens's address: clock pings and display messages go there"),
    'display_port': (('gaze_bridge', 'headset_display'), 'display_port', int,
                     "the headset app's downlink UDP port"),
}
NODES = ('gaze_bridge', 'target_selector', 'pressure_controller', 'plc_output', 'headset_display')
#: Lifecycle nodes (nodes/managed.py): brought up by this launch's lifecycle events, not by themselves.
MANAGED = MANAGED_NODES
#: The mock PLC's port with mock_plc:=true and no plc_port:= (config/params/guidance.yaml's).
MOCK_PLC_PORT = 1502


def argument_value(name: str, kind, text: str):
    """The typed value of launch argument `name`; ValueError names the argument."""
    try:
        if kind is list:
            value = yaml.safe_load(text)
            if not isinstance(value, list):
                raise ValueError('not a list')
            return [str(v) for v in value]
        return kind(text)
    except (ValueError, yaml.YAMLError) as exc:
        raise ValueError(f'launch argument {name}:={text!r} is not a {kind.__name__} '
                         f'({exc})') from None


def _nodes(context, *args, **kwargs):
    files = [LaunchConfiguration('params_file').perform(context)]
    extra = LaunchConfiguration('extra_params_file').perform(context)
    if extra:
        files.append(extra)
    files += study_params_files(context, get_package_share_directory('fabric_guidance'))
    use_sim_time = LaunchConfiguration('use_sim_time').perform(context).lower() == 'true'
    overrides = {name: {'use_sim_time': use_sim_time} for name in NODES}
    for arg, (nodes, parameter, kind, _) in ARGUMENTS.items():
        text = LaunchConfiguration(arg).perform(context)
        if text:
            for node in (nodes,) if isinstance(nodes, str) else nodes:
                overrides[node][parameter] = argument_value(arg, kind, text)
    # '' as well as 'true': a including launch file that declares the argument empty (passing
    # through, as micromanipulation.launch.py does) forwards '' into this scope.
    text = LaunchConfiguration('autostart').perform(context).strip().lower()
    if text not in ('', 'true', 'false'):
        raise ValueError(f'launch argument autostart:={text!r} is not true or false')
    autostart = text != 'false'
    if respawn_enabled(context):
        # Every start of the controller, first or respawned, waits for the operator's enable:
        # a respawn must not resume guidance on its own.
        overrides['pressure_controller']['start_enabled'] = False
    generated = NodeOverrides(context)
    namespace = launch_namespace(context)
    require_own_plc(namespace, {arg: LaunchConfiguration(arg).perform(context) for arg in ('plc_host', 'plc_port')})
    mock_port = _mock_plc_port(context)
    if mock_port is not None:
        overrides['plc_output'].update(plc_host='127.0.0.1', plc_port=mock_port)
    actions = []
    for name in NODES:
        lab = lab_node_kwargs(context, name)     # enclave, discovery server: {} when unset
        restart = respawn_kwargs(context, name)
        if name in MANAGED:
            # The launch drives the transitions over DDS, except with a keystore or a discovery
            # server: the launch process is neither in an enclave nor a client of the server, so
            # it could not reach the nodes' lifecycle services; they then bring themselves up.
            # So they do with respawn: a request sent to a respawned node while the graph still
            # lists its dead predecessor's service is lost, and the node would stay unconfigured.
            by_launch = not lab and not restart
            overrides[name]['autostart'] = False if by_launch else autostart
            node = LifecycleNode(package='fabric_guidance', executable=name, name=name, namespace=namespace,
                                 output='screen', parameters=[*files, generated.file(name, overrides[name])],
                                 **lab, **restart)
            actions += [node, *(lifecycle_bring_up(node) if autostart and by_launch else [])]
        else:
            actions.append(Node(package='fabric_guidance', executable=name, name=name, namespace=namespace,
                                output='screen',
                                parameters=[*files, generated.file(name, overrides[name])], **lab, **restart))
    if mock_port is None:
        return [*lab_network_actions(context), *actions, generated.cleanup_action()]
    # The lab nodes once the mock listens: plc_output's first connection then succeeds.
    mock = Node(package='fabric_guidance', executable='mock_plc', name='mock_plc', namespace=namespace,
                output='screen', parameters=[generated.file('mock_plc', {'port': mock_port})],
                **lab_node_kwargs(context, 'mock_plc'))
    return [*lab_network_actions(context), mock, after_mock_plc_listens(mock, actions), generated.cleanup_action()]


def _mock_plc_port(context) -> int | None:
    """The mock PLC's port with mock_plc:=true, None without; ValueError names the argument."""
    text = LaunchConfiguration('mock_plc').perform(context).strip().lower()
    if text not in ('', 'true', 'false'):
        raise ValueError(f'launch argument mock_plc:={text!r} is not true or false')
    if text != 'true':
        return None
    host = LaunchConfiguration('plc_host').perform(context).strip()
    if host not in ('', '127.0.0.1', 'localhost'):
        raise ValueError(f'launch argument plc_host:={host!r} with mock_plc:=true: the mock PLC listens on this PC '
                         '(127.0.0.1); leave plc_host empty, or mock_plc false for the PLC at that address')
    port = LaunchConfiguration('plc_port').perform(context).strip()
    return argument_value('plc_port', int, port) if port else MOCK_PLC_PORT


def generate_launch_description():
    share = get_package_share_directory('fabric_guidance')
    return LaunchDescription([
        DeclareLaunchArgument('params_file',
                              default_value=os.path.join(share, 'config', 'params', 'guidance.yaml'),
                              description='parameter file of the five nodes'),
        DeclareLaunchArgument('extra_params_file', default_value='',
                              description='a second parameter file, loaded after params_file '
                                          '(its values win; empty: none)'),
        study_argument(),
        DeclareLaunchArgument('use_sim_time', default_value='false',
                              description='use /clock (rosbag replay)'),
        DeclareLaunchArgument('autostart', default_value='true',
                              description='configure and activate pressure_controller and plc_output '
                                          '(false: leave them unconfigured for the operator)'),
        *[DeclareLaunchArgument(arg, default_value='',
                                description=f'{desc} (empty: from params_file)')
          for arg, (_, _, _, desc) in ARGUMENTS.items()],
        DeclareLaunchArgument('mock_plc', default_value='false',
                              description='true: a mock PLC on this PC instead of the suit (plc_host 127.0.0.1, '
                                          f'plc_port or {MOCK_PLC_PORT}): a dry run with the real headset'),
        namespace_argument(),
        *respawn_arguments(),      # respawn, respawn_delay
        *lab_launch_arguments(),   # keystore, discovery_server, start_discovery_server
        OpaqueFunction(function=_nodes),
    ])
