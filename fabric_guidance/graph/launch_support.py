"""What the package's launch files share (imported by launch/*.launch.py only: it needs launch).

- `namespace_argument`, `launch_namespace`: the launch argument namespace (every node of the
  launch in it; the parameter files are keyed `/**/<node>` so that it keeps its configuration);
  `require_own_plc` (suit_plc.py): a namespaced launch names its suit's own PLC address.
- `NodeOverrides`: launch arguments as node-scoped parameter files, loaded after the parameter
  files so that they win by construction (a `/**` file, which is what launch_ros makes of a
  dict, wins or loses by the order rcl happens to merge its entries in), removed at shutdown.
- `after_mock_plc_listens`: start actions once mock_plc accepts connections, so that
  plc_output's first connection succeeds instead of logging an ERROR.
- `lifecycle_bring_up`: launch_ros's lifecycle events that configure a managed node once its
  process runs and activate it once it is configured (the launch argument autostart).
- `respawn_kwargs`: the launch arguments respawn and respawn_delay as launch_ros Node keyword
  arguments, for the nodes that may restart (docs/lifecycle.md, "Restarts").
- `lab_launch_arguments`, `lab_node_kwargs`, `lab_network_actions`: the lab's keystore (each
  node in its SROS2 enclave, security enforced; docs/security.md) and discovery server (each
  node its client; optionally started by the launch; docs/lab_network.md). Unset: no change.
- `loopback_dds_actions`: the simulated graph's DDS on 127.0.0.1 (config/fastdds_loopback.xml),
  under the profile variable of Fast DDS 3 (Kilted) and of Fast DDS 2 (Jazzy) alike.
"""
from __future__ import annotations

import atexit
import os
import shutil
import sys
import tempfile

from launch.actions import (DeclareLaunchArgument, ExecuteProcess, RegisterEventHandler, SetEnvironmentVariable,
                            UnsetEnvironmentVariable)
from launch.event_handlers import OnProcessIO, OnShutdown
import yaml

from ..lab import discovery_server, lab_network, security_policy
from .lab_graph import MOCK_PLC_LISTENING, RESPAWN_DELAY_S, STUDY_TASKS, study_params_file
from .suit_plc import require_own_plc

# The launch files' rule on a namespaced suit's PLC (suit_plc.py); what `fabric-guidance dry-run`
# shares with the lab launch (lab_graph.py).
__all__ = ['require_own_plc', 'MOCK_PLC_LISTENING', 'STUDY_TASKS']


def loopback_dds_actions(share: str) -> list:
    """Environment actions that keep every later process of the launch on loopback DDS: the
    package's loopback profile under the distribution's Fast DDS variable name, the profile deciding alone
    (rmw's LOCALHOST range would add a send socket on every interface); without the profile, at
    least discovery stays on this machine."""
    profile = os.path.join(share, 'config', 'fastdds_loopback.xml')
    if not os.path.isfile(profile):
        return [SetEnvironmentVariable('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')]
    env = lab_network.profile_env(profile)
    # The other name unset: Fast DDS 3 would take an inherited old one over this profile.
    return [*(UnsetEnvironmentVariable(name) for name in lab_network.PROFILE_VARIABLES if name not in env),
            *(SetEnvironmentVariable(name, value) for name, value in env.items()),
            SetEnvironmentVariable('ROS_AUTOMATIC_DISCOVERY_RANGE', 'SYSTEM_DEFAULT')]


def namespace_argument() -> DeclareLaunchArgument:
    return DeclareLaunchArgument('namespace', default_value='',
                                 description="every node of the launch in this namespace (e.g. suit_a: a second "
                                             "suit on the same domain; its services are then "
                                             "/suit_a/pressure_controller/enable ...); empty: the root")


def study_argument() -> DeclareLaunchArgument:
    return DeclareLaunchArgument('study', default_value='',
                                 description="the paper's task of a study session (docs/study.md): speed or "
                                             'accuracy loads config/params/study-<task>.yaml last; empty: none')


def study_params_files(context, share: str) -> list:
    """[config/params/study-<task>.yaml] for the launch argument study, [] when empty."""
    task = context.launch_configurations.get('study', '')
    if not task:
        return []
    if task not in STUDY_TASKS:
        raise ValueError(f"launch argument study:={task!r}: one of {', '.join(STUDY_TASKS)} or empty")
    return [os.path.join(share, 'config', study_params_file(task))]


def launch_namespace(context) -> str:
    """The launch argument namespace as a node's `namespace=` ('' : the root, or whatever an
    enclosing PushRosNamespace set); ValueError naming the argument for an invalid one."""
    text = context.launch_configurations.get('namespace', '').strip()
    if text and not all(part.replace('_', 'a').isalnum() and not part[0].isdigit()
                        for part in text.strip('/').split('/')):
        raise ValueError(f'launch argument namespace:={text!r} is not a ROS namespace (letters, digits and _ '
                         'in /-separated tokens, none starting with a digit)')
    return text.rstrip('/') if text != '/' else text


class NodeOverrides:
    """One parameter file per node, keyed by the node's fully qualified name, in a directory of
    this launch that an OnShutdown handler (or, failing that, the launch process's exit)
    removes; the nodes read their files at start-up."""

    def __init__(self, context):
        self._context = context
        self._dir: str | None = None

    def file(self, node_name: str, parameters: dict) -> str:
        if self._dir is None:
            self._dir = tempfile.mkdtemp(prefix='fabric_guidance_launch_')
            # OnShutdown removes it with the launch; atexit when `ros2 launch` itself exits (a
            # launch interrupted twice can end before its shutdown handlers ran).
            atexit.register(shutil.rmtree, self._dir, True)
        # As launch_ros resolves the node's namespace: the launch argument, under an enclosing
        # PushRosNamespace unless it is absolute.
        namespace = launch_namespace(self._context)
        pushed = '' if namespace.startswith('/') else self._context.launch_configurations.get('ros_namespace') or ''
        fqn = '/'.join(part for part in (*pushed.split('/'), *namespace.split('/'), node_name) if part)
        path = os.path.join(self._dir, f'{node_name}.yaml')
        with open(path, 'w') as f:
            yaml.safe_dump({f'/{fqn}': {'ros__parameters': parameters}}, f, sort_keys=False)
        return path

    def files(self, node_name: str, parameters: dict) -> list:
        """[the file] for a parameters list, or [] when there is nothing to override."""
        return [self.file(node_name, parameters)] if parameters else []

    def cleanup_action(self):
        directory = self._dir
        if directory is None:
            return RegisterEventHandler(OnShutdown(on_shutdown=lambda event, context: None))
        return RegisterEventHandler(OnShutdown(
            on_shutdown=lambda event, context: shutil.rmtree(directory, ignore_errors=True)))


def lifecycle_bring_up(node_action) -> list:
    """Configure `node_action` (a launch_ros LifecycleNode) when its process has started and
    activate it the first time it is configured. Later transitions are the operator's: a
    configure after a cleanup does not activate by itself."""
    from launch.actions import EmitEvent
    from launch.event_handlers import OnProcessStart
    from launch.events import matches_action
    from launch_ros.event_handlers import OnStateTransition
    from launch_ros.events.lifecycle import ChangeState
    from lifecycle_msgs.msg import Transition

    def change(transition_id):
        return EmitEvent(event=ChangeState(lifecycle_node_matcher=matches_action(node_action),
                                           transition_id=transition_id))
    return [
        RegisterEventHandler(OnStateTransition(target_lifecycle_node=node_action, start_state='configuring',
                                               goal_state='inactive', handle_once=True,
                                               entities=[change(Transition.TRANSITION_ACTIVATE)])),
        RegisterEventHandler(OnProcessStart(target_action=node_action,
                                            on_start=[change(Transition.TRANSITION_CONFIGURE)])),
    ]


#: The nodes of the lab graph that the lab launch restarts when their process dies (respawn).
#: mock_plc stands for the PLC and never restarts; bag_recorder is not in the lab launch (a
#: restarted recorder would start a new bag: docs/lifecycle.md).
RESPAWNED = ('gaze_bridge', 'target_selector', 'pressure_controller', 'plc_output', 'headset_display')


def respawn_enabled(context) -> bool:
    """The launch argument respawn: '' (an including launch passing it through unset) or 'true'."""
    text = context.launch_configurations.get('respawn', '').strip().lower()
    if text not in ('', 'true', 'false'):
        raise ValueError(f'launch argument respawn:={text!r} is not true or false')
    return text != 'false'


def respawn_kwargs(context, node: str) -> dict:
    """launch_ros Node keyword arguments that restart `node` respawn_delay seconds after its
    process died, as often as it dies (launch's delay is fixed; it has no growing back-off)."""
    if node not in RESPAWNED or not respawn_enabled(context):
        return {}
    text = context.launch_configurations.get('respawn_delay', '') or str(RESPAWN_DELAY_S)
    try:
        delay = float(text)
    except ValueError:
        delay = -1.0
    if not delay >= 0.0:
        raise ValueError(f'launch argument respawn_delay:={text!r} is not a number of seconds >= 0')
    return {'respawn': True, 'respawn_delay': delay}


def respawn_arguments() -> list:
    return [
        DeclareLaunchArgument('respawn', default_value='true',
                              description='restart a lab node whose process died (false: leave it down); '
                                          'the controller then starts disabled: guidance resumes only '
                                          'once the operator calls enable'),
        DeclareLaunchArgument('respawn_delay', default_value=str(RESPAWN_DELAY_S),
                              description='seconds from a node process dying to its restart'),
    ]


def after_mock_plc_listens(mock_plc, actions):
    """An event handler that returns `actions` the first time mock_plc logs that it listens."""
    started = []

    def on_output(event):
        if started or MOCK_PLC_LISTENING not in event.text.decode(errors='replace'):
            return None
        started.append(True)
        return actions

    return RegisterEventHandler(OnProcessIO(target_action=mock_plc, on_stdout=on_output,
                                            on_stderr=on_output))


def lab_launch_arguments() -> list:
    """The launch arguments of the lab's network set-up; empty or false: the launch as before."""
    return [
        DeclareLaunchArgument('keystore', default_value='',
                              description='SROS2 keystore (ros2 security generate_artifacts with the policy of '
                                          '`fabric-guidance security-policy`): each node in its enclave '
                                          '/fabric_guidance/<node>, security enforced (empty: '
                                          'ROS_SECURITY_KEYSTORE if set, else no security)'),
        DeclareLaunchArgument('discovery_server', default_value='',
                              description='ADDRESS[:PORT] of the Fast DDS discovery server: every node its client '
                                          '(ROS_DISCOVERY_SERVER; empty: as the environment says)'),
        DeclareLaunchArgument('start_discovery_server', default_value='false',
                              description='also run the discovery server on this PC, at discovery_server'),
    ]


def _setting(context, name: str, environment: str | None = None) -> str:
    # launch_configurations, not LaunchConfiguration: the simulated launches ask before the lab
    # launch that declares the arguments is included.
    value = context.launch_configurations.get(name, '')
    return value or (os.environ.get(environment, '') if environment else '')


def lab_node_kwargs(context, node: str) -> dict:
    """launch_ros Node keyword arguments for `node`: its enclave and ROS_SECURITY_* when the lab
    set a keystore, ROS_DISCOVERY_SERVER when it named a discovery server; {} otherwise. A
    keystore without the node's enclave stops the launch with one line."""
    keystore = _setting(context, 'keystore', 'ROS_SECURITY_KEYSTORE')
    kwargs = security_policy.node_security(node, keystore)
    if keystore:
        enclave = os.path.join(keystore, 'enclaves', security_policy.enclave_path(node).lstrip('/'))
        if not os.path.isdir(enclave):
            raise ValueError(f'keystore {keystore}: no enclave {security_policy.enclave_path(node)} '
                             f'({enclave} is missing; docs/security.md)')
    server = _setting(context, 'discovery_server')
    if server:
        kwargs.setdefault('additional_env', {}).update(discovery_server.client_env(server))
    return kwargs


def lab_network_actions(context) -> list:
    """The discovery server as a process of the launch when start_discovery_server:=true."""
    if _setting(context, 'start_discovery_server').lower() != 'true':
        return []
    server = _setting(context, 'discovery_server')
    if not server:
        raise ValueError('launch argument start_discovery_server:=true needs discovery_server:=ADDRESS[:PORT]')
    discovery_server.parse_locator(server)
    return [ExecuteProcess(cmd=[sys.executable, '-m', 'fabric_guidance.commands.cli', 'discovery-server',
                                '--listen', server], name='discovery_server', output='screen')]
