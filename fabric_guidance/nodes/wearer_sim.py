"""wearer_sim: a simulated wearer in the loop, sending gaze the way the HoloLens does.

It feels the regulators' measured pressures (measured_pressure, from the PLC), turns torso and
gaze, and sends gaze datagrams (wire format v1, Unity frame) over UDP to gaze_bridge. With
return_to_front it turns back to the front while no target is active, as the paper's wearers
did between targets; a target that comes before it could take a single step at the front (the
process was late) finds it at the front at once.

Two wearers:

- scene_file '' (default): fabric_guidance.sim.wearer.SimulatedWearer with the parameters
  `laws`, `tau_s` and `pull_memory_s`: deterministic, no noise, no delay (what `make demo` runs).
- scene_file set: wearer `wearer_index` of the scene's population with the scene's
  wearer-side effects: fabric_guidance.sim.scene_wearer.SceneSide (the order of the effects, the
  seeding and what the graph realises elsewhere are described there), stepped at
  dt = 1/gaze_rate_hz locked to the wall clock (a late timer tick runs the steps it missed, up
  to MAX_CATCH_UP_STEPS), one datagram per step at most.

It is also the simulated headset's display (display_port > 0): it listens for the display
messages of headset_display and the clock pings of gaze_bridge (docs/headset_wire_format.md),
answers each ping at once from its gaze socket (t2, t3 on the clock of its gaze stamps), and
publishes on headset_view one line for each thing the wearer newly sees (core.display_wire.
DisplayView): `next <target>`, `found <target>`, `dummies <n>`, `prompt <text> (<i>/<n>)`,
`phrase <text>`, `targets <n>, active <name>`.

With a scene and press_confirm it is also a study participant: it presses the confirm key
(sim.scene_wearer.KeyPress: the headless protocols' rule) and publishes the press on `confirm`
(frame_id 'wearer_sim', stamped now on the node's clock), or with press_uplink sends it as the
headset's clicker does: a `confirm` datagram stamped with the simulation step the key was
pressed in, on the clock of its gaze stamps, three times 20 ms apart (docs/headset_wire_format.md);
gaze_bridge maps it exactly as the gaze, so the session finds the gaze at the press as soon as
the sample of that step has arrived. A study session switches its
condition and repetition at run time (parameters `condition`, `repetition`): the scene's wearer
side starts afresh with that trial's random streams, as the headless engine's trial does.

Subscribes  measured_pressure (Float64MultiArray, kPa), active_target (String); with a scene
            also target (PointStamped: visual capture) and speech (String, condition 4)
Publishes   headset_view (String), confirm (std_msgs/Header; with press_confirm)
Sends       UDP gaze datagrams, clock echoes and (press_uplink) confirm datagrams to bridge_host:bridge_port
"""
from __future__ import annotations

import socket
import sys
import threading
import time

import numpy as np
from geometry_msgs.msg import PointStamped
from rclpy.node import Node
from rcl_interfaces.msg import SetParametersResult
from std_msgs.msg import Float64MultiArray, Header, String

from ..core import ChannelMap, PowerLaw, condition as condition_of, ray_orientation
from ..core import display_wire
from ..core.clock_sync import MAX_DATAGRAM_BYTES, answer_ping
from ..core.gaze_wire import (WireFormatError, encode_confirm, encode_datagram, ros_to_unity_point,
                              ros_to_unity_quaternion)
from ..core.geometry import GeometryError, azimuth_deg, elevation_deg
from ..paths import resolve
from ..sim.scene_wearer import REALISED_ELSEWHERE, KeyPress, SceneSide, load_scene_file
from ..sim.wearer import PULL_MEMORY_S, SimulatedWearer, gaze_from_angles
from ..core import calibration_state
from ..interface import ACTIVE_TARGET, CALIBRATION_STATE, CONFIRM, HEADSET_VIEW, MEASURED_PRESSURE, SPEECH, TARGET
from .parameters import declare, declare_config_file
from .qos import COMMAND_QOS, EVENT_QOS, LATCHED_ALL_QOS, LATCHED_QOS
from .spin import run

#: Measured pressures older than this are not felt any more (the PLC link is gone) [s].
PRESSURE_TIMEOUT_S = 0.5
#: With a scene, simulation steps run locked to the wall clock: a late tick runs the steps it
#: missed, up to this many; a longer stall (the process was not scheduled) is not replayed.
MAX_CATCH_UP_STEPS = 5
#: How far before a timer tick its simulation step is put [s] (ticks come a little late, never early).
TICK_MARGIN_S = 0.0005
#: The headset sends each confirm datagram this many times, this far apart [s] (wire format).
CONFIRM_REPEATS, CONFIRM_REPEAT_S = 3, 0.02


class WearerSim(Node):
    def __init__(self, **kwargs):
        super().__init__('wearer_sim', **kwargs)
        self.address = (declare(self, 'bridge_host', '127.0.0.1', 'where gaze_bridge listens'),
                        declare(self, 'bridge_port', 5005, 'gaze_bridge UDP port', low=1, high=65535))
        rate = declare(self, 'gaze_rate_hz', 60.0, 'gaze datagrams per second (with a scene: simulation steps '
                       'per second)', 'Hz', low=1.0, high=2000.0)
        tau = declare(self, 'tau_s', 0.4, 'torso/gaze time constant (simple wearer only)', 's', low=0.01, high=10.0)
        memory = declare(self, 'pull_memory_s', PULL_MEMORY_S, 'a pause in the pull shorter than this is the same '
                         'pull resumed (simple wearer only)', 's', low=0.0, high=60.0)
        self.layout = declare(self, 'layout', 'suit', 'which channels the wearer feels: suit or arm')
        laws = declare(self, 'laws', [20.0, 0.65, 25.0, 22.0, 0.62, 20.0, 40.0, 0.55, 30.0, 38.0, 0.58, 35.0],
                       "the wearer's own power law a, b, c per direction (left, right, down, up); simple wearer "
                       'only')
        self.eye_height = declare(self, 'eye_height_m', 1.2, 'gaze origin above the immersive origin', 'm',
                                  low=0.0, high=3.0)
        self.return_to_front = declare(self, 'return_to_front', True,
                                       'turn back to the front while no target is active (the speed protocol)')
        channel_map_file = declare_config_file(self, 'channel_map_file', 'hardware/channel_map.yaml', 'channel map',
                                               read_only=False)
        scene_file = declare(self, 'scene_file', '', "scene (YAML path, or a name of config/scenes/): the wearer "
                             "and the wearer-side effects of the scene; '' = the simple deterministic wearer")
        wearer_index = declare(self, 'wearer_index', 0, "with scene_file: which wearer of the scene's population",
                               low=0, high=9999)
        condition = declare(self, 'condition', 0, "with scene_file: the paper's condition 1-4 (its layout wins "
                            'over layout; 4: the wearer hears speech and ignores the suit); 0 = from layout '
                            '(suit: 1, arm: 3)', low=0, high=4)
        repetition = declare(self, 'repetition', 0, "with scene_file: the trial's repetition (its random "
                             'streams, as the headless trial)', low=0, high=9999)
        self.press_confirm = declare(self, 'press_confirm', False, 'with scene_file: press the confirm key as '
                                     "the headless protocol's wearer does (a study participant)")
        self.press_uplink = declare(self, 'press_uplink', False, "with press_confirm: press through the headset's "
                                    'uplink (a confirm datagram stamped on the gaze clock, as the clicker) '
                                    'instead of publishing confirm')
        self.press_id = 0
        self._repeats: list[tuple[float, bytes]] = []     # (when, datagram) still to send
        display_bind = declare(self, 'display_bind_address', '127.0.0.1',
                               "where the simulated headset's display listens", read_only=True)
        display_port = declare(self, 'display_port', 0, "the simulated headset's display port (display "
                               'messages and clock pings; 0 = none)', '-', 0, 65535, read_only=True)
        if len(laws) != 12:
            raise ValueError(f'parameter laws needs 12 numbers (a, b, c for 4 directions), got {len(laws)}')
        self.channel_map = ChannelMap.load(resolve(channel_map_file, 'hardware/channel_map.yaml'))
        self.channel_map.to_directions(np.zeros(len(self.channel_map.channels)), self.layout)  # validates layout
        self.dt = 1.0 / rate
        self.scene_side: SceneSide | None = None
        if scene_file:
            scene = load_scene_file(scene_file)
            if condition == 0:
                condition = 3 if self.layout == 'arm' else 1
            cond = condition_of(condition)
            if cond.layout is not None and cond.layout != self.layout:
                self.get_logger().info(f'condition {cond.number} feels the {cond.layout} layout (parameter layout '
                                       f'{self.layout!r} ignored)')
                self.layout = cond.layout
            self.scene, self.wearer_index = scene, wearer_index
            self.scene_side = SceneSide(scene, wearer_index, cond.number, self.dt, self.layout, repetition)
            self.key = KeyPress(scene.protocol, self.dt)
            elsewhere = [f'{n} in {REALISED_ELSEWHERE[n]}' for n in scene.effect_names if n in REALISED_ELSEWHERE]
            self.get_logger().info(
                f'scene {scene.name} ({scene.source}): wearer {self.scene_side.spec.name} (index {wearer_index}), '
                f'condition {cond.number}, {rate:g} steps/s, run key {self.scene_side.run_key}; effects applied '
                f'here: {", ".join(self.scene_side.applied_effects()) or "none"}'
                + (f'; realised elsewhere: {", ".join(elsewhere)}' if elsewhere else ''))
        elif condition == 4:
            raise ValueError('parameter condition: 4 (speech) needs scene_file; the simple wearer does not hear')
        else:
            self.wearer = SimulatedWearer([PowerLaw(*laws[i:i + 3]) for i in range(0, 12, 3)], tau_s=tau,
                                          pull_memory_s=memory)
        self.pressures = np.zeros(4)
        self.pressures_received = -float('inf')
        self.active = ''
        #: Steps at the front since the last target ended (None: one is active or none ended yet).
        self.front_steps: int | None = None
        self.calibrating = False     # a live calibration's step pulls: go with the suit (Algorithm 1)
        self.calibration_rest = False   # its vented rest: face the front, as its prompt asks
        self.target: tuple[float, float] | None = None   # active target (yaw, pitch) from the eye, degrees
        self.seq = 0
        self.last_step = self.start = time.monotonic()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        if self.address[0] in ('localhost', '127.0.0.1') or self.address[0].startswith('127.'):
            # Sending alone would bind the socket to 0.0.0.0: reachable from the network.
            self.sock.bind(('127.0.0.1', 0))
        self.confirm_pub = self.create_publisher(Header, CONFIRM, EVENT_QOS)
        self.add_on_set_parameters_callback(self.on_set_parameters)
        self.view = display_wire.DisplayView()
        self.view_pub = self.create_publisher(String, HEADSET_VIEW, EVENT_QOS)
        self._display_sock = None
        self._stop = threading.Event()
        if display_port:
            self._display_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            try:
                self._display_sock.bind((display_bind, display_port))
            except OSError as exc:
                self._display_sock.close()
                raise OSError(f"cannot listen on {display_bind}:{display_port} (parameters 'display_bind_address', "
                              f"'display_port'): {exc}") from None
            self._display_sock.settimeout(0.1)
            self._display_thread = threading.Thread(target=self._display_loop, name='headset_display', daemon=True)
            self._display_thread.start()
        self.create_subscription(Float64MultiArray, MEASURED_PRESSURE, self.on_pressure, COMMAND_QOS)
        # Every change in turn (LATCHED_ALL_QOS): the wearer turns back to the front at each ''.
        self.create_subscription(String, ACTIVE_TARGET, self.on_active_target, LATCHED_ALL_QOS)
        self.create_subscription(String, CALIBRATION_STATE, self.on_calibration_state, LATCHED_QOS)
        if self.scene_side is not None:
            self.create_subscription(PointStamped, TARGET, self.on_target, LATCHED_QOS)
            if self.scene_side.cond.speech:
                self.create_subscription(String, SPEECH, self.on_speech, EVENT_QOS)
            self.create_timer(self.dt, self.scene_step)
        else:
            self.create_timer(self.dt, self.step)

    def on_set_parameters(self, params) -> SetParametersResult:
        """condition / repetition at run time (a study session): the scene's wearer side anew."""
        changed = {p.name: p.value for p in params if p.name in ('condition', 'repetition')}
        if not changed or self.scene_side is None:
            return SetParametersResult(successful=True)
        old = self.scene_side
        number = changed.get('condition', old.cond.number)
        repetition = changed.get('repetition', old.run_key[2])
        try:
            cond = condition_of(number or 1)
            side = SceneSide(self.scene, self.wearer_index, cond.number, self.dt, cond.layout or 'suit',
                             repetition)
        except ValueError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        side.seq = old.seq    # gaze_bridge drops a sequence number that goes back
        self.layout = side.layout
        self.scene_side = side
        self.start = time.monotonic()
        if self.active:
            side.present()
            self.key.present(side.t, self.target)   # on the new side's clock (its t starts at 0)
        if side.cond.speech and not old.cond.speech:
            self.create_subscription(String, SPEECH, self.on_speech, EVENT_QOS)
        self.get_logger().info(f'condition {cond.number}, repetition {repetition}: the wearer side starts afresh')
        return SetParametersResult(successful=True)

    def press(self) -> None:
        if not self.press_uplink:
            self.confirm_pub.publish(Header(stamp=self.get_clock().now().to_msg(), frame_id='wearer_sim'))
            return
        # The step the key was pressed in, on the clock of the gaze stamps (send()).
        datagram = encode_confirm(self.press_id, self.start + self.scene_side.t)
        self.press_id = (self.press_id + 1) % 2 ** 32
        now = time.monotonic()
        self._repeats += [(now + k * CONFIRM_REPEAT_S, datagram) for k in range(1, CONFIRM_REPEATS)]
        self._send_raw(datagram)

    def _send_raw(self, datagram: bytes) -> None:
        try:
            self.sock.sendto(datagram, self.address)
        except OSError as exc:  # the bridge not there yet is no reason to stop
            self.get_logger().warn(f'cannot send to the bridge: {exc}', throttle_duration_sec=5.0)

    def on_pressure(self, msg: Float64MultiArray) -> None:
        if len(msg.data) != len(self.channel_map.channels):
            return
        self.pressures = self.channel_map.to_directions(np.nan_to_num(np.asarray(msg.data)), self.layout)
        self.pressures_received = time.monotonic()

    def on_calibration_state(self, msg: String) -> None:
        # While a calibration step pulls, the wearer goes where the suit pulls, as a person being
        # calibrated does; in its vented rests they face the front whatever return_to_front says
        # ("Face front and rest": the controller checks that they came back before the next
        # direction); otherwise, with return_to_front, they face the front when no target is active.
        try:
            phase = calibration_state.decode(msg.data).phase
        except calibration_state.CalibrationStateError:
            phase = calibration_state.IDLE
        self.calibrating = phase == calibration_state.APPLY
        rest = phase == calibration_state.REST
        if rest and not self.calibration_rest and self.scene_side is not None:
            self.scene_side.withdraw()      # the torso's goal is the front again (the engine's go_front)
        self.calibration_rest = rest

    def on_active_target(self, msg: String) -> None:
        if msg.data == self.active:
            return
        self.active = msg.data
        self.target = None          # the new target's position comes on `target`
        side = self.scene_side
        if not self.active:
            if side is not None:
                self.key.withdraw()
            if self.return_to_front:
                self.front_steps = 0
                if side is not None:
                    side.withdraw()
            return
        if self.front_steps == 0:
            # The gap between two targets passed while this process was not scheduled ('' and the
            # next target came together): the wearer, who faces the front in every gap, is put
            # there at once; following from the last target's posture would read the new pull
            # from the wrong place.
            self.get_logger().warning(f"target '{self.active}' came before a step at the front since the last "
                                      'one (this process was late): the wearer faces the front at once',
                                      throttle_duration_sec=10.0)
            (side.wearer if side is not None else self.wearer).face_front()
        self.front_steps = None
        if side is not None:
            side.present()
            self.key.present(side.t, None)

    def on_target(self, msg: PointStamped) -> None:
        if not self.active:
            return
        rel = (msg.point.x, msg.point.y, msg.point.z - self.eye_height)
        try:
            yaw = azimuth_deg(rel)
            pitch = elevation_deg(rel)
        except GeometryError:
            return
        self.target = (yaw if yaw is not None else 0.0, pitch)   # straight up or down: any yaw
        self.key.target = self.target

    def on_speech(self, msg: String) -> None:
        # Not gated on active_target: the phrase may overtake it (another publisher); the
        # wearer acts on it only while following a target, and forgets it at the front.
        self.scene_side.hear_phrase(msg.data)

    def felt(self, now: float) -> np.ndarray:
        return self.pressures if now - self.pressures_received <= PRESSURE_TIMEOUT_S else np.zeros(4)

    def step(self) -> None:
        """The simple wearer: SimulatedWearer on the measured time step."""
        now = time.monotonic()
        dt, self.last_step = now - self.last_step, now
        if self.calibration_rest or (self.return_to_front and not self.active and not self.calibrating):
            gaze = self.wearer.return_to_front(dt)
            if self.front_steps is not None:
                self.front_steps += 1
        else:
            gaze = self.wearer.step(self.felt(now), dt)
        self.send(self.seq, now, gaze, gaze)
        self.seq = (self.seq + 1) % 2 ** 32

    def scene_step(self) -> None:
        """The scene's wearer: simulation steps of dt, as many as the wall clock says are due."""
        now = time.monotonic()
        if self._repeats:
            for _, datagram in [r for r in self._repeats if r[0] <= now]:
                self._send_raw(datagram)
            self._repeats = [r for r in self._repeats if r[0] > now]
        side = self.scene_side
        # Whole steps only (floor): a step whose time has not come yet would go out stamped in the
        # future, which gaze_bridge clips to its arrival, and the stream's frames would look uneven.
        # A tick that comes before its step moves the steps onto the ticks (less than a frame, and
        # the stamps stay increasing), so each sample leaves at its capture time, not a frame late.
        lead = self.start + (side.step_index + 1) * self.dt - now
        if 0.0 < lead < self.dt:
            self.start -= lead + TICK_MARGIN_S
        due = int((now - self.start) // self.dt) - side.step_index
        if due > MAX_CATCH_UP_STEPS:        # a stall: do not replay it
            due = MAX_CATCH_UP_STEPS
            self.start = now - (side.step_index + due) * self.dt
        follow = not self.calibration_rest and (bool(self.active) or self.calibrating or not self.return_to_front)
        if not follow and self.front_steps is not None:
            self.front_steps += due
        felt = self.felt(now)
        for _ in range(due):
            sample = side.step(felt, follow, self.target if self.active else None)
            pressed = self.press_confirm and self.key.stepped(side.t, side.wearer)
            if sample is None:
                if pressed:
                    self.press()
                continue     # lost (datagram_loss) or still on its way (datagram_latency)
            seq, t_emitted, yaw, pitch = sample
            # The tracker's gaze (with its noise) on the wire; the head pose is the true posture.
            self.send(seq % 2 ** 32, self.start + t_emitted, gaze_from_angles(yaw, pitch),
                      gaze_from_angles(*side.sent_true_gaze))
            # The press after the sample that decided it: the session reads the gaze at the press.
            if pressed or (self.press_confirm and self.key.sent(side.t, yaw, pitch)):
                self.press()

    def send(self, seq: int, stamp: float, gaze, head_direction) -> None:
        head = ros_to_unity_quaternion(ray_orientation(head_direction))
        origin = (0.0, self.eye_height, 0.0)   # Unity: y up
        datagram = encode_datagram(seq, stamp, origin, ros_to_unity_point(gaze), origin, head, True)
        try:
            self.sock.sendto(datagram, self.address)
        except OSError as exc:  # the bridge not there yet is no reason to stop
            self.get_logger().warn(f'cannot send gaze: {exc}', throttle_duration_sec=5.0)

    def _display_loop(self) -> None:
        """The headset's receive side: answer pings at once, show display messages."""
        sock = self._display_sock
        while not self._stop.is_set():
            try:
                data, _ = sock.recvfrom(MAX_DATAGRAM_BYTES + 1)
            except (socket.timeout, OSError):
                continue
            t2 = time.monotonic()
            echo = answer_ping(data, t2, time.monotonic())
            if echo is not None:
                try:
                    self.sock.sendto(echo, self.address)
                except OSError:
                    pass   # the bridge gone: the next ping tries again
                continue
            try:
                seen = self.view.apply(display_wire.decode(data))
            except WireFormatError as exc:
                self.get_logger().warn(f'display datagram dropped: {exc}', throttle_duration_sec=5.0)
                continue
            for line in seen:
                self.view_pub.publish(String(data=line))

    def safe_shutdown(self) -> None:
        self._stop.set()
        if self._display_sock is not None:
            self._display_thread.join(1.0)
            self._display_sock.close()
        self.sock.close()


def main(args=None) -> int:
    return run(WearerSim, args)


if __name__ == '__main__':
    sys.exit(main())
