"""The study's client of the graph, as an operator at the console: it sets parameters, calls
services and listens, and the guidance loop never waits on it.

Operator(domain_id) is an rclpy node in its own context, spun on a background thread. It keeps
the last GAZE_HISTORY_S of gaze (stamped at capture by gaze_bridge) for the session's driver,
which judges a key press on the gaze at the press's stamp (study.session); it queues the
presses of every `confirm` source; it places the session's target (target_selector's target_positions and
active_target in one atomic call), brings it back to the front, opens or closes the controller's
trial gate, switches the condition, and sends prompts and the `done` event to the headset
(study_display). It watches the operator's arm on the controller's diagnostics (`armed`, and
`started`: a restart) and how long ago the controller was heard (arm_dropped). enable() is the
operator's act alone: only the operator's key (live_session.operator_keys) and the simulated
operator (simulated.py, standing for a person) call it; the session never does.

Every blocking call has a deadline (OperatorError naming what did not answer). The guidance
nodes never call back into it: a stalled session leaves the graph as a stalled operator would
(vented between trials, guiding during one).
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
import math
import queue
import threading
import time
from typing import Any, Callable

from .. import interface
from ..core.geometry import GeometryError, ray_direction

#: Gaze kept until the driver has taken it (it takes the new samples every few ms) [s].
GAZE_HISTORY_S = 5.0
#: The session's one target in target_selector (its target_names in a study graph).
STUDY_TARGET = 'study'
#: Distance of the placed target from the eye [m] (the demo's scene targets are at 2 m).
TARGET_DISTANCE_M = 2.0
#: How long a service or parameter call may take before the operator says so [s].
CALL_TIMEOUT_S = 5.0
#: The controller publishes its diagnostics every second (and at once on an arm change); not
#: heard for this long, it counts as lost [s].
CONTROLLER_LOST_S = 3.5


class OperatorError(RuntimeError):
    """A node of the graph did not answer, or refused a request (the message says which)."""


@dataclass(frozen=True)
class Press:
    """One key press: its source, its stamp (PC clock, ns), and when the operator received it."""
    source: str
    stamp_ns: int
    received_ns: int


def target_position(yaw_deg: float, pitch_deg: float, eye_height_m: float,
                    distance_m: float = TARGET_DISTANCE_M) -> list[float]:
    """A target at (yaw, pitch) from the eye (REP 103: yaw positive left), in the immersive frame."""
    y, p = math.radians(yaw_deg), math.radians(pitch_deg)
    return [distance_m * math.cos(p) * math.cos(y), distance_m * math.cos(p) * math.sin(y),
            eye_height_m + distance_m * math.sin(p)]


class PendingCall:
    """A request on its way: done() is False until the answer came, then True (or OperatorError:
    no answer within the timeout, or `check` refused the answer); wait() blocks until then."""

    def __init__(self, name: str, future, deadline: float, timeout_s: float):
        self.name, self.future, self.deadline, self.timeout_s = name, future, deadline, timeout_s
        self.check: Callable[[Any], None] = lambda response: None
        self.done_at: float | None = None          # monotonic time the answer was seen [s]

    def done(self) -> bool:
        if self.done_at is not None:
            return True
        if not self.future.done():
            if time.monotonic() > self.deadline:
                raise OperatorError(f'service {self.name} did not answer within {self.timeout_s:.0f} s')
            return False
        self.done_at = time.monotonic()
        self.check(self.future.result())
        return True

    def wait(self):
        while not self.done():
            time.sleep(0.002)
        return self.future.result()


class Operator:
    """The session's hands on the graph (see the module docstring)."""

    def __init__(self, domain_id: int | None = None, eye_height_m: float = 1.2, name: str = 'study_operator',
                 namespace: str = ''):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from geometry_msgs.msg import PoseStamped
        from std_msgs.msg import Float64MultiArray, Header, String
        from diagnostic_msgs.msg import DiagnosticArray

        qos = interface.qos_profile
        self._rclpy = rclpy
        self.context = Context()
        rclpy.init(context=self.context, **({} if domain_id is None else {'domain_id': domain_id}))
        # In the graph's namespace: the table's relative names (gaze, confirm...) resolve in it.
        self.namespace = '/'.join(part for part in namespace.split('/') if part)
        self.node = rclpy.create_node(name, context=self.context, namespace='/' + self.namespace)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.eye_height_m = float(eye_height_m)
        self.lock = threading.Lock()
        self.gaze: deque = deque()              # (stamp_ns, origin, direction), in order of receipt
        self.gaze_total = 0                     # samples ever appended to gaze (its right end's count)
        self.presses: queue.Queue[Press] = queue.Queue()
        self.active = ''
        self.target: tuple[float, float] | None = None     # placed (yaw, pitch)
        self.commands: deque = deque(maxlen=200_000)        # (monotonic_ns, max kPa) of pressure_command
        self.controller_condition: int | None = None
        self.controller_wearer: str | None = None            # pressure_controller's `wearer`
        self.controller_calibration: str | None = None       # the wearer of its loaded calibration ('' none)
        self.armed: bool | None = None                       # the operator's arm on the controller
        self.controller_started: str | None = None           # its process's start (a restart changes it)
        self.controller_heard: float | None = None           # monotonic time of its last status
        self.calibration_state = None                        # core.calibration_state.CalibrationState
        self.headset_clock: str | None = None                # gaze_bridge's clock_state
        self._header_type, self._string_type = Header, String
        self.display_pub = self.node.create_publisher(String, interface.STUDY_DISPLAY, qos('event'))
        self.confirm_pub = self.node.create_publisher(Header, interface.CONFIRM, qos('event'))
        self.node.create_subscription(PoseStamped, interface.GAZE, self._on_gaze, qos('sensor'))
        self.node.create_subscription(Header, interface.CONFIRM, self._on_confirm, qos('event'))
        self.node.create_subscription(String, interface.ACTIVE_TARGET, self._on_active, qos('latched'))
        self.node.create_subscription(Float64MultiArray, interface.PRESSURE_COMMAND, self._on_command,
                                      qos('command'))
        self.node.create_subscription(DiagnosticArray, interface.DIAGNOSTICS, self._on_diagnostics, 10)
        self.node.create_subscription(String, interface.CALIBRATION_STATE, self._on_calibration_state, qos('latched'))
        self._clients: dict[str, Any] = {}
        self._running = True
        self._thread = threading.Thread(target=self._spin, name='study-operator', daemon=True)
        self._thread.start()

    # ---- spinning and callbacks (the executor thread)
    def _spin(self) -> None:
        while self._running and self.context.ok():
            self.executor.spin_once(timeout_sec=0.02)

    def now_ns(self) -> int:
        """The PC clock of the graph's stamps (the node's clock)."""
        return self.node.get_clock().now().nanoseconds

    def _on_gaze(self, msg) -> None:
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        q, p = msg.pose.orientation, msg.pose.position
        try:
            direction = ray_direction((q.x, q.y, q.z, q.w))
        except GeometryError:
            return
        with self.lock:
            self.gaze.append((stamp, (p.x, p.y, p.z), direction))
            self.gaze_total += 1
            while self.gaze and stamp - self.gaze[0][0] > GAZE_HISTORY_S * 1e9:
                self.gaze.popleft()

    def _on_confirm(self, msg) -> None:
        stamp = msg.stamp.sec * 1_000_000_000 + msg.stamp.nanosec
        self.presses.put(Press(msg.frame_id or 'unknown', stamp, self.now_ns()))

    def _on_active(self, msg) -> None:
        with self.lock:
            self.active = msg.data

    def _on_command(self, msg) -> None:
        with self.lock:
            self.commands.append((time.monotonic_ns(), max(msg.data, default=0.0)))

    def _on_diagnostics(self, msg) -> None:
        # /diagnostics is global: only the controller of this operator's namespace counts.
        mine = f'{self.namespace}/pressure_controller' if self.namespace else 'pressure_controller'
        bridge = f'{self.namespace}/gaze_bridge' if self.namespace else 'gaze_bridge'
        for st in msg.status:
            node = st.name.split(':')[0].strip().lstrip('/')
            if node == bridge:
                for kv in st.values:
                    if kv.key == 'clock_state':
                        self.headset_clock = kv.value
            if node == mine or (not self.namespace and st.name.startswith('pressure_controller')):
                self.controller_heard = time.monotonic()
                for kv in st.values:
                    if kv.key == 'armed':
                        self.armed = kv.value == 'True'
                    elif kv.key == 'started':
                        self.controller_started = kv.value
                    if kv.key == 'condition':
                        self.controller_condition = int(kv.value)
                    elif kv.key == 'wearer':
                        self.controller_wearer = kv.value
                    elif kv.key == 'calibration':
                        self.controller_calibration = kv.value

    def clock_state(self) -> str:
        """The trial column's clock state: 'synced' (gaze stamped at capture on the mapped
        headset clock), 'free' (stamped at receipt), '-' (gaze_bridge not heard yet)."""
        if self.headset_clock is None:
            return '-'
        return 'synced' if self.headset_clock == 'synchronised' else 'free'

    def _on_calibration_state(self, msg) -> None:
        from ..core.calibration_state import CalibrationStateError, decode
        try:
            self.calibration_state = decode(msg.data)
        except CalibrationStateError:
            pass

    # ---- what the wearer's gaze is
    def has_gaze(self) -> bool:
        """Whether a gaze sample has come from gaze_bridge (and is still in the history)."""
        with self.lock:
            return bool(self.gaze)

    # ---- requests
    def _client(self, srv_type, name: str):
        # A node-private name of the table (`~/enable`) is the owner's: its full name.
        if name.startswith('~/'):
            name = interface.full_name(name, self.namespace)
        client = self._clients.get(name)
        if client is None:
            client = self._clients[name] = self.node.create_client(srv_type, name)
        return client

    def call(self, srv_type, name: str, request, timeout_s: float = CALL_TIMEOUT_S):
        return self.call_begin(srv_type, name, request, timeout_s).wait()

    def call_begin(self, srv_type, name: str, request, timeout_s: float = CALL_TIMEOUT_S) -> 'PendingCall':
        """Send a request and return at once (its service waited for, when not yet discovered)."""
        client = self._client(srv_type, name)
        deadline = time.monotonic() + max(timeout_s, 15.0)   # discovery may take seconds under load
        while not client.service_is_ready():
            if time.monotonic() > deadline:
                raise OperatorError(f'service {name} is not on the graph')
            time.sleep(0.02)
        return PendingCall(name, client.call_async(request), time.monotonic() + timeout_s, timeout_s)

    def set_parameters(self, node: str, wait: bool = True, **values) -> 'PendingCall':
        """Set `values` on `node` in one atomic call (all or none); OperatorError with the reason.
        wait False: return once sent; the PendingCall's done() raises the refusal when it comes."""
        from rcl_interfaces.srv import SetParametersAtomically
        from rclpy.parameter import Parameter
        request = SetParametersAtomically.Request(
            parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in values.items()])

        def refused(response):
            if not response.result.successful:
                raise OperatorError(f'{node} refused {sorted(values)}: {response.result.reason}')
        pending = self.call_begin(SetParametersAtomically, self.node_name(node, 'set_parameters_atomically'), request)
        pending.check = refused
        if wait:
            pending.wait()
        return pending

    def parameter_services_missing(self, *nodes: str) -> list[str]:
        """The nodes of `nodes` whose set_parameters_atomically service is not yet discovered
        (empty: all are): a session waits for them before its first call."""
        from rcl_interfaces.srv import SetParametersAtomically
        return [n for n in nodes if not self._client(
            SetParametersAtomically, self.node_name(n, 'set_parameters_atomically')).service_is_ready()]

    def node_name(self, node: str, service: str) -> str:
        """A node's service in this operator's namespace: /<ns>/<node>/<service>."""
        return interface.full_name(f'~/{service}', self.namespace, node)

    def get_parameters(self, node: str, *names: str) -> list:
        """The values of `names` on `node` (None for one it does not have)."""
        from rcl_interfaces.srv import GetParameters
        from rclpy.parameter import parameter_value_to_python
        response = self.call(GetParameters, self.node_name(node, 'get_parameters'),
                             GetParameters.Request(names=list(names)))
        return [parameter_value_to_python(v) if v.type else None for v in response.values]

    def enable(self, on: bool) -> None:
        """The operator's arm (a person's act: never the session's). Arming returns once the
        controller's diagnostics say so (its `started` is then the process that was armed)."""
        from std_srvs.srv import SetBool
        if on:
            self.armed = None
        response = self.call(SetBool, interface.ENABLE, SetBool.Request(data=bool(on)))
        if not response.success:
            raise OperatorError(f'{interface.ENABLE}: {response.message}')
        if on:
            deadline = time.monotonic() + CALL_TIMEOUT_S
            while self.armed is not True:
                if time.monotonic() > deadline:
                    raise OperatorError(f'{interface.ENABLE}: armed, but its diagnostics did not say so within '
                                        f'{CALL_TIMEOUT_S:.0f} s')
                time.sleep(0.01)

    def trial_gate(self, on: bool) -> str:
        """The session's trial gate (closed: vented). '' done; else why pressure cannot flow
        (opening it while the operator's arm is off: the gate is open, nothing flows)."""
        from std_srvs.srv import SetBool
        response = self.call(SetBool, interface.TRIAL_GATE, SetBool.Request(data=bool(on)))
        if response.success:
            return ''
        if on:
            self.armed = False
        return response.message

    def arm_dropped(self, started: str | None) -> str:
        """Why the operator's arm is no longer as it was armed ('' it is): dropped (a vent,
        enable false), a restart of the controller (another `started` than `started`, when
        given), or no status from it for CONTROLLER_LOST_S."""
        heard = self.controller_heard
        if heard is None:      # not heard yet: a call to it says whether it is there
            return ''
        if time.monotonic() - heard > CONTROLLER_LOST_S:
            return f'pressure_controller not heard for {CONTROLLER_LOST_S:g} s (lost)'
        if started is not None and self.controller_started not in (None, started):
            return 'pressure_controller restarted (it waits for the operator)'
        if self.armed is False:
            return "the operator's arm dropped (a vent or enable false)"
        return ''

    def vent(self) -> None:
        from std_srvs.srv import Trigger
        self.call(Trigger, interface.VENT, Trigger.Request())

    def show_target(self, yaw_deg: float, pitch_deg: float, wait: bool = True) -> PendingCall:
        """The session's target at (yaw, pitch) from the eye, active (the display draws new dummies).
        wait False: return once the request is sent (target_selector answers its requests in order)."""
        pending = self.set_parameters('target_selector', wait=wait,
                                      target_positions=target_position(yaw_deg, pitch_deg, self.eye_height_m),
                                      active_target=STUDY_TARGET)
        self.target = (float(yaw_deg), float(pitch_deg))
        return pending

    def to_front(self, wait: bool = True) -> PendingCall:
        """No active target: the controller vents, the wearer looks back at the front."""
        pending = self.set_parameters('target_selector', wait=wait, active_target='')
        self.target = None
        return pending

    def display(self, line: str) -> None:
        """A line to the headset (headset_display's study_display: `prompt ...`, `found ...`, `done`)."""
        self.display_pub.publish(self._string_type(data=line))

    def press_key(self, source: str = 'keyboard') -> None:
        """A key at the operator's terminal: a confirm stamped now on the PC clock."""
        msg = self._header_type(frame_id=source)
        msg.stamp = self.node.get_clock().now().to_msg()
        self.confirm_pub.publish(msg)

    def set_condition(self, condition: int, extra_nodes: tuple[str, ...] = ()) -> None:
        """The controller's live `condition` (and that of `extra_nodes`, e.g. wearer_sim): one atomic
        call each; a node that answers has applied it (it vents and takes condition 3's arm layout
        or condition 4's speech from its next step), one that refuses raises OperatorError."""
        self.set_parameters('pressure_controller', condition=int(condition))
        for node in extra_nodes:
            self.set_parameters(node, condition=int(condition))

    def drain_presses(self) -> list[Press]:
        """Presses nobody asked for (between trials): taken off the queue, returned."""
        out = []
        while True:
            try:
                out.append(self.presses.get_nowait())
            except queue.Empty:
                return out

    def commands_between(self, start_ns: int, end_ns: int) -> list[float]:
        """The largest value of each pressure_command received in [start_ns, end_ns] (monotonic)."""
        with self.lock:
            return [kpa for t, kpa in self.commands if start_ns <= t <= end_ns]

    def close(self) -> None:
        self._running = False
        self._thread.join(5)
        self.executor.shutdown()
        self.node.destroy_node()
        self._rclpy.shutdown(context=self.context)
