"""pressure_controller: the feedback law (Eq. 5) on live gaze and target, the four conditions,
and Algorithm 1 run live with the wearer.

Subscribes  gaze (PoseStamped), target (PointStamped), active_target (String); the last two only
            from this namespace's target_selector, a target no older than 1 s (control_inputs.py)
Publishes   pressure_command (Float64MultiArray, kPa, in the order of the `channels` parameter),
            controller_input (Float64MultiArray, every step right before its command: the exact
            inputs the step used, layout in bag/controller_io.py), controller_parameters (String,
            YAML, latched: parameters, calibration and channel map; again after a live calibration),
            speech (String, condition 4), calibration_status (String), /diagnostics
Services    start_calibration (Trigger), enable (SetBool), vent (Trigger), trial_gate (SetBool)

Two gates (controller_gates.py): the operator's arm, the enable latch (`enable false` and `vent`
stop every pressure the node sends, a running calibration included, and only `enable true`
lifts it; no lifecycle transition, parameter, new calibration, start_calibration or trial gate
does; start_enabled is its value when the process starts: false in the lab launch, so a
restarted controller waits for the operator), and the study session's trial gate. Pressure
flows only while both are open.

Parameters set at run time take effect at once or are refused with the reason (the table in
core/controller_parameters.py says which and what each does; on_set_parameters applies them).
The safety limits (p_max_kpa, gaze_timeout_s, stall_timeout_s) only tighten, and a tightening
is held across restarts (held_limits.py); use_sim_time is fixed while the node runs.

It publishes a command every control step, all zeros whenever it must not guide: disabled,
vented, no calibration, no active target, or no valid gaze for gaze_timeout_s.

Steps: with step_on_gaze (the default) a step runs on every valid gaze sample, so a sample
reaches the suit without waiting for a timer; the control_rate_hz timer still steps whenever
no step ran for one of its periods (no gaze: it is what notices the stale gaze and vents).
Eq. 5 adds G once per step, so with step_on_gaze it acts once per gaze sample (the HoloLens'
30 Hz is the paper's rate); step_on_gaze false steps on the timer alone, as before.

Time: the t of Eq. 5 is the node clock, so with use_sim_time:=true it is the bag's /clock (a
replay), and a clock that jumps back (a looping replay) restarts Eq. 5's derivative in the core.
The control timer, gaze staleness, the no-progress (stall) watch and the calibration's schedule
run on the steady clock, whatever the ROS clock does: a ROS-time timer can stay silent after
/clock jumps back, and a gaze judged fresh, a stall never reached or a calibration step never
ended on a stopped (or absent) sim clock would keep the suit pressurised. Safety never waits on
/clock; controller_input records the steady time of each step so the offline replay reruns the
stall watch as it ran.
"""
from __future__ import annotations

from array import array
from pathlib import Path
import shutil
import subprocess
import sys
import time

import numpy as np
import yaml
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PointStamped, PoseStamped
from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import SetBool, Trigger

from ..core import (Calibration, CalibrationProcedure, ChannelMap, GeometryError, GuidanceController,
                    angles_between, condition, phrase, ray_direction, target_direction)
from ..core.calibration import DONE, FAILED, Acceptance
from ..core import calibration_state
from ..core.channels import ChannelMapError
from ..core.controller_parameters import PARAMETERS, SETUP
from ..core.feedback import REST
from ..core.power_law import load_fit_libraries
from ..core.safe_input import check_wearer
from ..core.geometry import DIRECTIONS
from ..bag.controller_io import FIELDS, encode_input, setup_to_dict
from ..core.control_step import RESET_KEEP_STALL, RESET_VENT, ControllerSetup, StepInput, guidance_step, safe_command
from ..interface import (CALIBRATION_STATE, CALIBRATION_STATUS, CONTROLLER_INPUT, CONTROLLER_PARAMETERS,
                         DIAGNOSTICS, ENABLE, GAZE, PRESSURE_COMMAND, SPEECH, START_CALIBRATION, TRIAL_GATE, VENT)
from ..paths import resolve
from .array_layout import named_layout
from .diagnostics import publish_diagnostics, status
from .control_inputs import ControlInputs
from .controller_gates import Gates
from .controller_settings import LiveParameters
from .managed import ManagedNode
from .parameters import declare_table
from .qos import COMMAND_QOS, EVENT_QOS, LATCHED_QOS, SENSOR_QOS
from .spin import run


class PressureController(ControlInputs, Gates, LiveParameters, ManagedNode):
    """Eq. 5 as a lifecycle node (nodes/managed.py): configure loads the channel map and the
    calibration; only while active does it step and guide; deactivate, cleanup, shutdown and
    error processing publish a vent. Topics and services exist in every state (the latched
    target is known at activation; `vent` always answers)."""

    def __init__(self, **kwargs):
        super().__init__('pressure_controller', **kwargs)
        # Every parameter from the one table (core/controller_parameters.py); `channels` at the
        # first configure, once the channel map it mirrors is loaded.
        # self.v: the values in force, kept by on_set_parameters (everything reads them from here).
        self.v = v = declare_table(self, PARAMETERS[:-1])
        check_wearer(v['wearer'], 'parameter "wearer"')
        condition(v['condition'])
        self.hold_error = ''
        self.load_held_limits()   # a limit tightened before a restart is in force again
        self.started = time.time()   # tells a restart from a vent (diagnostics `started`)
        self.channel_map = self.calibration = self.setup = self.controller = None
        self.zeros = np.zeros(0)
        self.control_timer = None
        self._declaring = False

        #: The operator's arm, the enable latch (module doc): only enable and vent move it after this.
        self.enabled = v['start_enabled']
        #: The study session's trial gate (controller_gates.py): open unless a session closes it.
        self.gate_open = True
        self.gaze_origin = self.gaze_direction = None
        self.gaze_received = -float('inf')   # self.now_s(): the steady clock
        self.step_count = 0
        self.last_step_s = -float('inf')      # self.now_s() of the latest step
        self.command_count = 0
        self.reset_pending = 0                # RESET_VENT, RESET_KEEP_STALL between steps (controller_input)
        self.target = None
        self.target_name = ''
        self.awaiting_target = False          # a new name came; wait for a position published after it
        self.speech_due = False
        self.procedure: CalibrationProcedure | None = None
        self.last_status = ''
        self.vent_reason = 'starting'
        self.invalid_inputs = 0
        # Gaze samples taken, those whose own step vented, and steps that guided (not a vent):
        # /diagnostics, where samples go.
        self.gaze_samples = self.gaze_vented = self.guided_steps = 0

        self.command_pub = self.create_publisher(Float64MultiArray, PRESSURE_COMMAND, COMMAND_QOS)
        self.command_msg = Float64MultiArray()   # its layout names the channels once configured
        self.input_msg = Float64MultiArray(layout=named_layout(FIELDS))
        self.input_pub = self.create_publisher(Float64MultiArray, CONTROLLER_INPUT, COMMAND_QOS)
        self.parameters_pub = self.create_publisher(String, CONTROLLER_PARAMETERS, LATCHED_QOS)
        self.speech_pub = self.create_publisher(String, SPEECH, EVENT_QOS)
        self.status_pub = self.create_publisher(String, CALIBRATION_STATUS, EVENT_QOS)
        # The same progress as fields, latched (core/calibration_state.py); the sentence is for people.
        self.state_pub = self.create_publisher(String, CALIBRATION_STATE, LATCHED_QOS)
        self.state_pub.publish(String(data=calibration_state.encode(calibration_state.CalibrationState(self.wearer))))
        self.saved = ('', '', '')   # file, fit report, error of the latest finish_calibration
        self.diag_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS, 10)
        self.create_subscription(PoseStamped, GAZE, self.on_gaze, SENSOR_QOS)
        self.subscribe_control_inputs()
        self.create_service(Trigger, START_CALIBRATION, self.on_start_calibration)
        self.create_service(SetBool, ENABLE, self.on_enable)
        self.create_service(Trigger, VENT, self.on_vent)
        self.create_service(SetBool, TRIAL_GATE, self.on_trial_gate)
        self.steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.alone_seen = self.duplicate = False   # controller_gates.check_unique
        self.alone_checks = 0
        self.duplicate_text = ''
        self.create_timer(1.0, self.on_second, clock=self.steady)
        self.add_on_set_parameters_callback(self.on_set_parameters)

    # ---- the values in force
    @property
    def condition(self):
        return condition(self.v['condition'])

    @property
    def layout(self) -> str:
        return self.condition.layout or 'suit'

    @property
    def p_max(self) -> float:
        return self.v['p_max_kpa']

    @property
    def gaze_timeout(self) -> float:
        return self.v['gaze_timeout_s']

    @property
    def wearer(self) -> str:
        return self.v['wearer']

    def cal_dir_of(self, value: str) -> Path:
        return Path(value).expanduser() if value else Path.home() / '.fabric_guidance' / 'calibrations'

    @property
    def cal_dir(self) -> Path:
        return self.cal_dir_of(self.v['calibration_dir'])

    def read_calibration(self, cal_file: str) -> Calibration | None:
        """The calibration of a calibration_file value ('' none); FileNotFoundError, or the
        loader's error naming the file and field."""
        if not cal_file:
            return None
        path = resolve(cal_file, '')
        if not path.is_file():
            raise FileNotFoundError(f'calibration file {path}: does not exist')
        return Calibration.load(path)

    # ---- lifecycle
    def configure(self) -> None:
        v = self.v
        channel_map_file = resolve(v['channel_map_file'], 'hardware/channel_map.yaml')
        channel_map = ChannelMap.load(channel_map_file)
        if self.layout not in channel_map.layouts:
            # Checked here: the first guidance step would otherwise fail after start-up.
            raise ChannelMapError(f'channel map {channel_map_file}: field '
                                  f'"layouts" has no layout "{self.layout}" for condition '
                                  f'{self.condition.number}; it has {list(channel_map.layouts)}')
        if self.has_parameter('channels'):
            channels = self.get_parameter('channels').value
            if list(channels) != list(channel_map.channels):
                raise ChannelMapError(f'channel map {channel_map_file}: channels {list(channel_map.channels)} '
                                      f'differ from the parameter "channels" {list(channels)} of the first '
                                      'configure; restart the node to change the channel order')
        else:
            self._declaring = True
            try:
                declare_table(self, PARAMETERS[-1:], channels=list(channel_map.channels))
            finally:
                self._declaring = False
        cal_file = v['calibration_file']
        try:
            calibration = self.read_calibration(cal_file)
        except FileNotFoundError as exc:
            # A first-time wearer has no file yet: the node comes up to calibrate them.
            calibration = None
            self.get_logger().warning(f'{exc}: no calibration; call start_calibration to calibrate '
                                      f'{self.wearer} (written to {self.cal_dir / (self.wearer + ".yaml")})')
            cal_file = ''
        self.same_person(calibration, v['wearer'], cal_file)
        self.channel_map, self.calibration = channel_map, calibration
        self.setup = self.make_setup(calibration, v)
        self.zeros = np.zeros(len(channel_map.channels))
        self.command_msg.layout = named_layout(channel_map.channels)
        self.warn_origin(calibration)
        self.controller = self._make_controller()
        self.publish_parameters(self.step_count)
        # Algorithm 1's fit runs in this node: its scipy import now, not inside a control step
        # (it takes 1-2 s, longer than gaze_timeout_s: the calibration would fail on it).
        load_fit_libraries()
        self.start_timer()
        self.get_logger().info(
            f'condition {self.condition.number} ({self.condition.name}), G = {v["gain"]}, P_MAX = {self.p_max} kPa, '
            f'calibration: {cal_file or "none"}' + ('' if self.enabled else '; disabled until enable'))

    def make_setup(self, calibration: Calibration | None, values) -> ControllerSetup:
        setup = {p.name: values[p.name] for p in SETUP}
        setup['stall_timeout_s'] = setup['stall_timeout_s'] or None   # ROS has no null: 0 = never
        return ControllerSetup(calibration=calibration, channel_map=self.channel_map, **setup)

    def start_timer(self) -> None:
        if self.control_timer is not None:
            self.destroy_timer(self.control_timer)
        self.period_s = 1.0 / self.setup.control_rate_hz
        self.control_timer = self.create_timer(self.period_s, self.on_timer, clock=self.steady)

    def activate(self) -> None:
        # The enable latch stays as it is: a deactivate/activate is no operator's enable. Eq. 5
        # starts afresh from the gaze at activation; a latched stall stays latched.
        self.vent_controller(forget_stall=False)

    def deactivate(self) -> None:
        self.vent_all('deactivated', forget_stall=False)

    def release(self) -> None:
        self.vent_all('released')
        if self.control_timer is not None:
            self.destroy_timer(self.control_timer)
            self.control_timer = None
        self.controller = self.setup = self.calibration = None

    def vent_all(self, why: str, forget_stall: bool = True) -> None:
        """Vent now: the controller's state, a running calibration, and a zero command out."""
        self.vent_controller(forget_stall)
        self.end_calibration(why)
        if self.zeros.size:
            self.publish(self.zeros)

    def kept(self) -> str:
        """What a failed calibration leaves in use, truthfully."""
        if self.calibration is None:
            return f'no previous calibration of {self.wearer}: no guidance until one succeeds'
        return f'the previous calibration is kept ({self.calibration.wearer})'

    def end_calibration(self, why: str) -> None:
        """End a running calibration now, failed (the caller vents)."""
        if self.procedure is None:
            return
        self.procedure = None
        self.last_status = f'failed: {why}; {self.kept()}'
        self.status_pub.publish(String(data=self.last_status))
        self.state_pub.publish(String(data=calibration_state.encode(
            calibration_state.failed(self.wearer, why, self.calibration is not None))))
        self.get_logger().error(f'calibration {self.last_status}')

    def warn_origin(self, cal: Calibration | None) -> None:
        if cal is not None and cal.origin_warning and self.setup.guidance_frame == REST:
            self.get_logger().warning(cal.origin_warning)

    def _make_controller(self) -> GuidanceController | None:
        return self.setup.make_controller()

    def publish_parameters(self, from_step: int) -> None:
        """The controller's parameters (YAML), valid from control step `from_step` on."""
        d = setup_to_dict(self.setup)
        d['from_step'] = int(from_step)
        self.parameters_pub.publish(String(data=yaml.safe_dump(d, sort_keys=False)))

    def now_s(self) -> float:
        """The clock gaze staleness is judged on: always the steady clock (see the module doc)."""
        return time.monotonic()

    def vent_controller(self, forget_stall: bool = True) -> None:
        """Vent between steps (recorded as `reset` in the next controller_input: RESET_VENT when
        any vent since the last step forgot a stall, else RESET_KEEP_STALL)."""
        keep = not forget_stall and self.reset_pending != RESET_VENT
        self.reset_pending = RESET_KEEP_STALL if keep else RESET_VENT
        if self.controller is not None:
            self.controller.vent(forget_stall)

    # ---- inputs
    def on_gaze(self, msg: PoseStamped) -> None:
        """A gaze sample, aged from its capture stamp as well as from its arrival: samples that
        waited in this process while it was frozen (SIGSTOP, a paused VM) are as old as their
        stamps say when it wakes, not fresh. The stamp is compared with this node's ROS clock,
        the clock it was stamped on (the system clock live, the bag's /clock in a replay); with
        no stamp or no ROS time (use_sim_time before /clock) the arrival alone counts."""
        p, q = msg.pose.position, msg.pose.orientation
        try:
            direction = ray_direction([q.x, q.y, q.z, q.w])
            origin = np.array([p.x, p.y, p.z])
            if not np.all(np.isfinite(origin)):
                raise GeometryError('gaze origin is not finite')
        except GeometryError:
            self.invalid_inputs += 1
            return
        self.gaze_origin, self.gaze_direction = origin, direction
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        now_ns = self.get_clock().now().nanoseconds
        age_s = (now_ns - stamp_ns) * 1e-9 if stamp_ns > 0 and now_ns > 0 else 0.0
        self.gaze_received = self.now_s() - max(0.0, age_s)
        self.gaze_samples += 1
        if self.v['step_on_gaze'] and self.active:
            self.step()
            self.gaze_vented += bool(self.vent_reason)

    def on_timer(self) -> None:
        self.check_inputs_clean()
        # The minimum rate: skipped while gaze steps come at least this often.
        if self.active and self.now_s() - self.last_step_s >= 0.9 * self.period_s:
            self.step()

    def on_active_target(self, msg: String) -> None:
        if msg.data == self.target_name:
            return
        self.target_name = msg.data
        self.target = None
        self.awaiting_target = bool(msg.data)
        self.vent_controller()

    def on_target(self, msg: PointStamped) -> None:
        point = np.array([msg.point.x, msg.point.y, msg.point.z])
        if not np.all(np.isfinite(point)):
            self.invalid_inputs += 1
            return
        if not self.target_name:
            return
        self.target = point
        if self.awaiting_target:
            self.awaiting_target = False
            self.speech_due = self.condition.speech
            self.vent_controller()   # the next step begins from the gaze at that moment

    # ---- services
    def on_start_calibration(self, request, response):
        if not self.active:
            response.success, response.message = False, f'cannot calibrate: the node is {self.state_label}'
            return response
        if self.procedure is not None:
            response.success, response.message = False, 'a calibration is already running'
            return response
        if not self.enabled:
            response.success = False
            response.message = ("cannot calibrate: the operator's arm is off (enable false, vent or a restart): "
                                'the operator must call enable first')
            return response
        if not self.gate_open:
            response.success, response.message = False, "cannot calibrate: the study session's trial gate is closed"
            return response
        if self.now_s() - self.gaze_received > self.gaze_timeout:
            response.success = False
            response.message = f'cannot calibrate: no valid gaze in the last {self.gaze_timeout} s'
            return response
        v = self.v
        try:
            self.procedure = CalibrationProcedure(
                self.wearer, p_max=self.p_max, steps=v['calibration_steps'], dwell_s=v['calibration_dwell_s'],
                rest_s=v['calibration_rest_s'],
                record_window_s=min(v['calibration_window_s'], v['calibration_dwell_s'], v['calibration_rest_s']),
                acceptance=Acceptance(v['calibration_min_r2'], v['calibration_min_span_deg'],
                                      v['calibration_max_reversal_deg'], v['calibration_max_rmse_kpa']),
                rest_tolerance_deg=v['calibration_rest_tolerance_deg'] or None, max_rest_s=v['calibration_max_rest_s'])
        except ValueError as exc:
            response.success, response.message = False, f'cannot calibrate: {exc}'
            return response
        response.success = True
        response.message = (f'calibrating {self.wearer}: {len(DIRECTIONS)} directions x {v["calibration_steps"]} '
                            f'steps, about {self.procedure.duration_s:.0f} s')
        self.get_logger().info(response.message)
        return response

    # ---- the control step
    def publish(self, channels: np.ndarray) -> None:
        # Last line of defence: nothing above P_MAX and nothing non-finite leaves this node.
        safe = safe_command(channels, self.p_max)
        # One message object reused (publish serialises at once); array('d', bytes) skips the
        # per-element checks a list goes through.
        self.command_msg.data = array('d', safe.tobytes())
        self.command_pub.publish(self.command_msg)
        self.command_count += 1

    def step(self) -> None:
        t = self.get_clock().now().nanoseconds * 1e-9   # ROS time: sim time in a replay
        fresh = self.now_s() - self.gaze_received <= self.gaze_timeout
        clock = self.now_s()   # the steady clock: the stall watch and the calibration's schedule
        if self.procedure is not None and not self.flowing:   # no pressure past a gate, whatever closed it
            self.end_calibration('guidance disabled' if not self.enabled else 'trial gate closed')
        inp = StepInput(t, self.gaze_origin, self.gaze_direction, self.target, fresh, self.flowing,
                        bool(self.target_name) and self.target is not None, self.reset_pending,
                        self.procedure is not None, self.condition.number, self.step_count, self.command_count,
                        clock)
        self.reset_pending = 0
        self.step_count += 1
        self.last_step_s = clock
        # The exact inputs of this step, right before its command (offline replay reruns them).
        if self.input_pub.get_subscription_count():   # volatile: unheard, it would be dropped anyway
            self.input_msg.data = array('d', encode_input(inp))
            self.input_pub.publish(self.input_msg)
        if self.procedure is not None:
            self.publish(self.calibration_step(clock, fresh))
            return
        if self.speech_due and fresh and self.target is not None:
            self.say()
        channels, reason, invalid = guidance_step(self.setup, self.controller, inp)
        stalled = self.controller is not None and reason == self.controller.stalled
        if stalled and reason and reason != self.vent_reason:
            self.get_logger().warning(f'guidance to {self.target_name}: {reason}')
        self.vent_reason = reason
        self.guided_steps += not reason
        self.invalid_inputs += invalid
        self.publish(channels)

    def say(self) -> None:
        self.speech_due = False
        try:
            angles = angles_between(self.gaze_direction, target_direction(self.gaze_origin, self.target))
        except GeometryError:
            return
        text = phrase(angles.horizontal, angles.vertical)
        self.speech_pub.publish(String(data=text))
        self.get_logger().info(f'speech for {self.target_name}: "{text}"')
        if self.v['speak'] and shutil.which('espeak-ng'):
            subprocess.Popen(['espeak-ng', text], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    def calibration_step(self, clock: float, fresh: bool) -> np.ndarray:
        """Algorithm 1's step at `clock`, the steady clock: a stopped /clock cannot freeze a step."""
        proc = self.procedure
        if not fresh:
            proc.fail(f'the gaze stream stopped for more than {self.gaze_timeout} s')
        cmd = proc.tick(clock, self.gaze_direction if fresh else None)
        direction_pressures = np.zeros(len(DIRECTIONS))
        if cmd.direction is not None:
            direction_pressures[DIRECTIONS.index(cmd.direction)] = cmd.pressure
        # While resting (vented, facing front) the wearer is told which direction comes next.
        where = cmd.direction or (f'before {proc.direction}' if proc.direction else '')
        text = (f'{cmd.phase} {where} step {cmd.step}/{len(proc.schedule)} '
                f'{cmd.pressure:.0f} kPa {100 * cmd.progress:.0f}%')
        if cmd.phase == DONE:
            text = self.finish_calibration()
        elif cmd.phase == FAILED:
            text = f'failed: {proc.error}; {self.kept()}'
            self.get_logger().error(f'calibration {text}')
            self.procedure = None
            attempt = proc.attempt(self.calibration)
            if attempt is not None:
                # The refused fit's report, beside (not over) the kept calibration's.
                import dataclasses
                self.write_report(dataclasses.replace(attempt, wearer=f'{self.wearer}-refused'),
                                  self.cal_dir,
                                  f'refused calibration of {self.wearer}: {proc.error}')
        if text != self.last_status:
            self.last_status = text
            self.status_pub.publish(String(data=text))
            file, report, error = self.saved if cmd.phase == DONE else ('', '', '')
            self.state_pub.publish(String(data=calibration_state.encode(calibration_state.of_procedure(
                self.wearer, proc, cmd, file=file, report=report, error=error,
                previous_kept=self.calibration is not None))))
        return self.channel_map.to_channels(direction_pressures, self.layout) if self.procedure else self.zeros

    def finish_calibration(self) -> str:
        proc, self.procedure = self.procedure, None
        try:
            cal = proc.result(base=self.calibration)
            path = cal.save(self.cal_dir / f'{self.wearer}.yaml')
        except (ValueError, OSError) as exc:
            self.get_logger().error(f'calibration not saved: {exc}')
            self.saved = ('', '', f'not saved: {exc}')
            return f'failed: {exc}; {self.kept()}'
        self.calibration = cal
        self.setup.calibration = cal
        self.warn_origin(cal)
        self.controller = self._make_controller()
        self.publish_parameters(self.step_count)   # the next step uses the new calibration
        fits = ', '.join(f'{d} R^2 {cal.directions[d].fit.get("r2", float("nan")):.3f}' for d in DIRECTIONS)
        self.get_logger().info(f'calibration written to {path} ({fits})')
        txt, png = self.write_report(cal, path.parent, str(path))
        self.saved = (str(path), str(txt), '')
        return f'done: {path}; fit report {txt}, {png}'

    def write_report(self, cal: Calibration, folder: Path, source: str):
        """The fit report (text and PNG) in `folder`. Drawing takes about a second, so it runs
        off the control loop; the calibration is saved (or kept) whatever happens to it."""
        import threading
        from ..lab.calibration_report import report_paths, write_fit_report
        txt, png = report_paths(cal, folder)
        logger = self.get_logger()

        def write_report():
            try:
                write_fit_report(cal, folder, source=source)
                logger.info(f'fit report written: {txt}, {png}')
            except Exception as exc:  # noqa: BLE001 - a report failure must not touch the calibration
                logger.error(f'fit report not written: {exc!r}')
        self.report_thread = threading.Thread(target=write_report, name='fit_report')
        self.report_thread.start()
        return txt, png

    def publish_diagnostics(self) -> None:
        if self.configure_error:
            level, message = DiagnosticStatus.ERROR, f'unconfigured: {self.configure_error}'
        elif self.duplicate:
            level, message = DiagnosticStatus.ERROR, self.duplicate_text
        elif not self.active:
            level, message = DiagnosticStatus.WARN, f'{self.state_label}: not guiding (vented)'
        elif self.procedure is not None:
            level, message = DiagnosticStatus.OK, f'calibrating: {self.last_status}'
        elif self.vent_reason == 'disabled' or not self.flowing:
            level, message = DiagnosticStatus.WARN, (
                "vented: the operator's arm is off (enable false, vent or a restart): nothing guides until enable"
                if not self.enabled else "vented: the study session's trial gate is closed")
        elif self.vent_reason:
            level, message = DiagnosticStatus.WARN, f'vented: {self.vent_reason}'
        else:
            level, message = DiagnosticStatus.OK, f'guiding to {self.target_name}'
        if self.held_text:
            message += f'; held limits: {self.held_text}'
        pressures = self.controller.pressures if self.controller is not None else np.zeros(len(DIRECTIONS))
        values = {'condition': self.condition.number, 'target': self.target_name, 'invalid_inputs': self.invalid_inputs,
                  'refused_inputs': self.refused_inputs, 'last_input_refusal': self.last_input_refusal,
                  'enabled': self.enabled, 'armed': self.enabled, 'trial_gate': 'open' if self.gate_open else 'closed',
                  'started': f'{self.started:.6f}', 'p_max_kpa': f'{self.p_max:g}',
                  'held_limits': (self.held_text or 'none') + (f'; {self.hold_error}' if self.hold_error else ''),
                  'wearer': self.wearer,
                  # whose calibration guides ('' none): a study session sees a first-time participant
                  'calibration': self.calibration.wearer if self.calibration is not None else '',
                  'gaze_samples': self.gaze_samples, 'gaze_vented': self.gaze_vented, 'guided_steps': self.guided_steps,
                  **self.lifecycle_values()}
        values.update({f'{d}_kpa': f'{p:.1f}' for d, p in zip(DIRECTIONS, pressures)})
        publish_diagnostics(self, self.diag_pub, [status(self, 'guidance', level, message, values)])

    def safe_shutdown(self) -> None:
        self.active = False
        if self.zeros.size:
            self.publish(self.zeros)
            # Reliable: wait (briefly) until the subscribers have it, the process ends right after
            # (a test under load once saw the zeros never arrive).
            self.command_pub.wait_for_all_acked(Duration(seconds=1.0))
            self.get_logger().info('vented on shutdown')


def main(args=None) -> int:
    return run(PressureController, args)


if __name__ == '__main__':
    sys.exit(main())
