"""What the package's launch files share (imported by launch/*.launch.py only: it needs launch).

- `NodeOverrides`: launch arguments as node-scoped parameter files, loaded after the parameter
  files so that they win by construction (a `/**` file, which is what launch_ros makes of a
  dict, wins or loses by the order rcl happens to merge its entries in), removed at shutdown.
- `after_mock_plc_listens`: start actions once mock_plc accepts connections, so that
  plc_output's first connection succeeds instead of logging an ERROR.
- `lifecycle_bring_up`: launch_ros's lifecycle events that configure a managed node once its
  process runs and activate it once it is configured (the launch argument autostart).
"""
from __future__ import annotations

import atexit
import os
import shutil
import tempfile

from launch.actions import RegisterEventHandler
from launch.event_handlers import OnProcessIO, OnShutdown
import yaml

#: The line mock_plc logs once its listener accepts connections (nodes/mock_plc.py).
MOCK_PLC_LISTENING = 'mock PLC listening on'


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
        namespace = self._context.launch_configurations.get('ros_namespace') or ''
        fqn = '/'.join(part for part in (namespace.strip('/'), node_name) if part)
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
