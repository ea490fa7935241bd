"""Managed (lifecycle) nodes: the ROS 2 node lifecycle, with venting on every way out of active.

A hardware-facing node of the package is a `ManagedNode` (rclpy.lifecycle.LifecycleNode), so
that an operator or a launch file drives it with the standard services (`ros2 lifecycle set
/plc_output deactivate`) and sees its state on /diagnostics. A subclass fills in four hooks:

  configure()   read and check its files, build its objects, connect; raise on anything wrong
                (the message names the file or field): the node stays unconfigured
  activate()    from now on, guide / write commands
  deactivate()  vent at once; keep what configure built (the link stays up)
  release()     vent if it can, then drop what configure built (cleanup, shutdown, error)

Parameters are declared in the constructor, before any transition, as every node here does.
With the parameter `autostart` (default true) the node configures and activates itself at
start-up, so the process graphs of the tests and `make demo` run as before; the launch files set
it false and use launch_ros's lifecycle events instead (docs/lifecycle.md). Publishers stay
ordinary publishers: diagnostics and the measured pressures are wanted in every state, and the
vent on deactivate must still go out while deactivating.
"""
from __future__ import annotations

from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn

from .parameters import declare

UNCONFIGURED, INACTIVE, ACTIVE, FINALIZED = 'unconfigured', 'inactive', 'active', 'finalized'


class ConfigureError(RuntimeError):
    """A node could not configure itself at start-up (autostart): the process ends with it."""


def one_line(exc: BaseException) -> str:
    return ' '.join(str(exc).split())[:300] or type(exc).__name__


class ManagedNode(LifecycleNode):
    """A LifecycleNode whose every transition out of active vents (see the module doc)."""

    def __init__(self, name: str, **kwargs):
        super().__init__(name, **kwargs)
        self.autostart = declare(self, 'autostart', True,
                                 'configure and activate at start-up; false: wait for the lifecycle '
                                 'services (launch files, an operator with `ros2 lifecycle set`)',
                                 read_only=True)
        self.state_label = UNCONFIGURED
        self.configured = False
        self.active = False
        self.configure_error = ''
        self._starting = False     # autostart: the transitions log one line between them

    # ------------------------------------------------------------- the hooks
    def configure(self) -> None:
        raise NotImplementedError

    def activate(self) -> None:
        raise NotImplementedError

    def deactivate(self) -> None:
        raise NotImplementedError

    def release(self) -> None:
        raise NotImplementedError

    # ----------------------------------------------------------- transitions
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self.configure()
        except Exception as exc:   # noqa: BLE001 - a bad file or parameter: one line, stay unconfigured
            self.configure_error = one_line(exc)
            if not self._starting:   # at start-up the process says it once ("cannot start: ...")
                self.get_logger().error(f'cannot configure: {self.configure_error}')
            self._release_quietly()
            return TransitionCallbackReturn.FAILURE
        self.configured, self.configure_error, self.state_label = True, '', INACTIVE
        self._say('configured (inactive)')
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.activate()
        self.active, self.state_label = True, ACTIVE
        self._say('active')
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = False     # first: nothing guides or writes a command from here on
        self.deactivate()
        self.state_label = INACTIVE
        self.get_logger().info('deactivated (vented)')
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._released(UNCONFIGURED, 'cleaned up (vented)')

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._released(FINALIZED, 'shut down (vented)')

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        # A transition raised: vent, drop everything, and go back to unconfigured.
        return self._released(UNCONFIGURED, f'error processing (from {state.label}): vented, unconfigured',
                              self.get_logger().error)

    def _released(self, label: str, what: str, log=None) -> TransitionCallbackReturn:
        """Vent and drop what configure opened, then stand in `label`."""
        self._release_quietly()
        self.state_label = label
        (log or self.get_logger().info)(what)
        return TransitionCallbackReturn.SUCCESS

    def _say(self, what: str) -> None:
        if not self._starting:
            self.get_logger().info(what)

    def _release_quietly(self) -> None:
        self.active = False
        try:
            self.release()
        except Exception as exc:   # noqa: BLE001 - the transition must still end
            self.get_logger().error(f'releasing after {self.state_label}: {one_line(exc)}')
        self.configured = False

    # -------------------------------------------------------------- start-up
    def start_up(self) -> None:
        """With autostart: configure and activate now; ConfigureError with the reason if the
        node cannot configure (the process then ends with one line, as a plain node did)."""
        if not self.autostart:
            self.get_logger().info('unconfigured: waiting for the lifecycle services (autostart false)')
            return
        self._starting = True
        try:
            if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                raise ConfigureError(self.configure_error or 'configure failed')
            if self.trigger_activate() != TransitionCallbackReturn.SUCCESS:
                raise ConfigureError('activate failed')
        finally:
            self._starting = False
        self.get_logger().info('configured and active (autostart)')

    def lifecycle_values(self) -> dict:
        """The state for /diagnostics."""
        values = {'lifecycle state': self.state_label}
        if self.configure_error:
            values['configure error'] = self.configure_error
        return values
