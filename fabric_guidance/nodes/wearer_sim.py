"""wearer_sim: a simulated wearer in the loop, sending gaze the way the HoloLens does.

It feels the regulators' measured pressures (measured_pressure, from the PLC), turns torso and
gaze, and sends gaze datagrams (wire format v1, Unity frame) over UDP to gaze_bridge. With
return_to_front it turns back to the front while no target is active, as the paper's wearers
did between targets.

Two wearers:

- scene_file '' (default): fabric_guidance.sim.wearer.SimulatedWearer with the parameters
  `laws` and `tau_s`: deterministic, no noise, no delay (what `make demo` runs).
- scene_file set: wearer `wearer_index` of the scene's population (sim.population.sample_wearer),
  a sim.wearer.SceneWearer with the scene's body_dynamics if listed, and the scene's
  wearer-side effects (sim.effects) applied every timer tick, in the order of the headless
  engine (sim.engine.ClosedLoop.step):

      measured_pressure (the mock PLC realises regulator_lag)
        -> per-direction mean (ChannelMap.to_directions, the condition's layout)
        -> [pressure] suit_hysteresis -> [percept] weber_perception -> [delay] reaction_delay
        -> SceneWearer.feel -> SceneWearer.move (visual capture of the active target)
        -> gaze -> [gaze] gaze_noise, datagram_loss (not sent), datagram_latency (sent later)
        -> UDP datagram
      condition 4: speech -> [speech] speech_latency -> engine.parse_phrase
        -> [delay] reaction_delay -> SceneWearer.hear

  The simulation steps at dt = 1/gaze_rate_hz locked to the wall clock (a late timer tick runs
  the steps it missed, up to MAX_CATCH_UP_STEPS), one datagram per step at most. The effects
  are started with the engine's seeding, RunContext(dt, scene seed, wearer_index,
  engine.trial_run(condition, 0)), so the same scene file gives the same effect parameters and
  random streams (datagram seq k carries the k-th gaze_noise draw). The graph runs in real time on DDS, UDP and Modbus,
  so a run is not bit-identical with the headless engine's. regulator_lag is not applied
  here: the mock PLC's regulator_tau_s is the regulator (fabric-guidance demo --scene sets it
  from the scene).

Subscribes  measured_pressure (Float64MultiArray, kPa), active_target (String); with a scene
            also target (PointStamped: visual capture) and speech (String, condition 4)
Sends       UDP gaze datagrams to bridge_host:bridge_port
"""
from __future__ import annotations

from pathlib import Path
import socket
import sys
import time

import numpy as np
from geometry_msgs.msg import PointStamped
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray, String

from ..core import ChannelMap, PowerLaw, condition as condition_of, ray_orientation
from ..core.gaze_wire import encode_datagram, ros_to_unity_point, ros_to_unity_quaternion
from ..core.geometry import GeometryError, azimuth_deg, elevation_deg
from ..paths import resolve, share_dir
from ..sim.wearer import SimulatedWearer, gaze_from_angles
from ..interface import ACTIVE_TARGET, MEASURED_PRESSURE, SPEECH, TARGET
from .parameters import declare
from .qos import COMMAND_QOS, EVENT_QOS, LATCHED_QOS
from .spin import run

#: Measured pressures older than this are not felt any more (the PLC link is gone) [s].
PRESSURE_TIMEOUT_S = 0.5
#: With a scene, simulation steps run locked to the wall clock: a late tick runs the steps it
#: missed, up to this many; a longer stall (the process was not scheduled) is not replayed.
MAX_CATCH_UP_STEPS = 5
#: Effects the node does not apply because another part of the graph realises them.
REALISED_ELSEWHERE = {'regulator_lag': 'mock_plc (regulator_tau_s)'}
_FRONT = (0.0, 0.0)


def load_scene_file(value: str):
    """A scene from a path (relative: to the working directory, else to the package share)
    or the name of one of config/scenes/."""
    from ..sim.scene import load_scene
    path = Path(value).expanduser()
    if not path.is_absolute() and not path.exists() and (share_dir() / path).exists():
        path = share_dir() / path
    return load_scene(path if path.suffix in ('.yaml', '.yml') or path.exists() else value)


class SceneSide:
    """The wearer side of a scene's closed loop, one step per call, without ROS: what
    sim.engine.ClosedLoop.step does from the command onward, minus regulator_lag (the PLC's).

    step(pressures, follow, target) takes the measured pressure per direction (left, right,
    down, up, kPa), whether the wearer follows the guidance (a target is active) or returns to
    the front, and the active target's (yaw, pitch) from the eye (degrees) or None; it returns
    the gaze sample to send, (seq, t, yaw, pitch), or None when datagram_loss / latency hold it.
    `sent_true_gaze` is then the wearer's true (yaw, pitch) when that sample was taken (the
    head pose of its datagram).
    """

    def __init__(self, scene, wearer_index: int, condition: int, dt: float, layout: str | None = None):
        from ..sim.effects import RunContext, by_stage
        from ..sim.engine import trial_run
        from ..sim.population import sample_wearer
        from ..sim.wearer import SceneWearer, Senses
        n = scene.population.subjects
        if not 0 <= wearer_index < n:
            raise ValueError(f'parameter wearer_index: the scene {scene.name} has wearers 0..{n - 1}, '
                             f'got {wearer_index}')
        spec = sample_wearer(scene, wearer_index)
        if spec.error:
            raise ValueError(f'wearer {wearer_index} of scene {scene.name} is not usable: {spec.error}')
        self.scene, self.spec, self.dt = scene, spec, float(dt)
        self.cond = condition_of(condition)
        self.layout = layout or self.cond.layout or 'suit'
        self.run_key = trial_run(self.cond.number, 0)
        ctx = RunContext(self.dt, scene.seed, int(wearer_index), self.run_key)
        self.effects = [s.build() for s in scene.effects]
        for e in self.effects:
            e.start(ctx)
        stages = by_stage(self.effects)
        self.gaze_fx = [e.gaze for e in stages['gaze']]
        body = stages['body'][0] if stages['body'] else None
        self.wearer = SceneWearer(spec.suit_laws, spec.arm_laws, scene.controller.p_max_kpa, body)
        self.wearer.set_layout(self.layout)
        self.haptic = self.cond.haptic
        self.senses = Senses(stages, self.haptic, skip=REALISED_ELSEWHERE)
        # The speed protocol's targets are objects the wearer can see (visual capture); the
        # accuracy protocol's are angles with nothing to see (engine: present(visible=False)).
        self.visible = scene.protocol.kind == 'speed'
        self.step_index = 0
        self.seq = 0
        self._true: dict[int, tuple[float, float]] = {}   # seq -> true gaze, until sent or dropped
        self.sent_true_gaze = (0.0, 0.0)

    @property
    def t(self) -> float:
        return self.step_index * self.dt

    def applied_effects(self) -> list[str]:
        """The scene's effects this side applies (the others are realised elsewhere or unused)."""
        out = []
        for e in self.effects:
            if e.name in REALISED_ELSEWHERE:
                continue
            if e.stage in ('pressure', 'percept') and not self.haptic:
                continue
            if e.stage == 'speech' and not self.cond.speech:
                continue
            out.append(e.name)
        return out

    def present(self) -> None:
        """A new target became active: follow the guidance from here (engine.present)."""
        self.wearer.acting = False

    def withdraw(self) -> None:
        """No target: return to the front, forget a phrase not yet heard (engine.withdraw)."""
        self.senses.forget()
        self.wearer.go_front()

    def hear_phrase(self, text: str) -> None:
        """Condition 4's phrase was spoken now; the wearer has heard it after speech_latency."""
        self.senses.say(self.t, text)

    @property
    def heard_phrases(self) -> list[str]:
        return self.senses.heard_phrases

    def step(self, pressures, follow: bool, target: tuple[float, float] | None):
        wearer = self.wearer
        self.senses.step(self.t, [float(x) for x in pressures], wearer, follow)
        if follow:
            wearer.move(target if self.visible else None)
        else:
            wearer.move(_FRONT if self.visible else None)
        self.step_index += 1
        self.seq += 1
        sample = (self.seq, self.t, wearer.gaze_yaw, wearer.gaze_pitch)
        self._true[self.seq] = sample[2:]
        for fx in self.gaze_fx:
            sample = fx(self.t, sample)
        if sample is not None:
            self.sent_true_gaze = self._true[sample[0]]
            self._true = {k: v for k, v in self._true.items() if k > sample[0]}
        elif len(self._true) > 1000:   # a long loss burst: forget the oldest
            self._true = dict(list(self._true.items())[-100:])
        return sample


class WearerSim(Node):
    def __init__(self):
        super().__init__('wearer_sim')
        self.address = (declare(self, 'bridge_host', '127.0.0.1', 'where gaze_bridge listens'),
                        declare(self, 'bridge_port', 5005, 'gaze_bridge UDP port', low=1, high=65535))
        rate = declare(self, 'gaze_rate_hz', 60.0, 'gaze datagrams per second (with a scene: simulation steps '
                       'per second)', 'Hz', low=1.0, high=2000.0)
        tau = declare(self, 'tau_s', 0.4, 'torso/gaze time constant (simple wearer only)', 's', low=0.01, high=10.0)
        self.layout = declare(self, 'layout', 'suit', 'which channels the wearer feels: suit or arm')
        laws = declare(self, 'laws', [20.0, 0.65, 25.0, 22.0, 0.62, 20.0, 40.0, 0.55, 30.0, 38.0, 0.58, 35.0],
                       "the wearer's own power law a, b, c per direction (left, right, down, up); simple wearer "
                       'only')
        self.eye_height = declare(self, 'eye_height_m', 1.2, 'gaze origin above the immersive origin', 'm',
                                  low=0.0, high=3.0)
        self.return_to_front = declare(self, 'return_to_front', True,
                                       'turn back to the front while no target is active (the speed protocol)')
        channel_map_file = declare(self, 'channel_map_file', '', "channel map (YAML); '' = the package's")
        scene_file = declare(self, 'scene_file', '', "scene (YAML path, or a name of config/scenes/): the wearer "
                             "and the wearer-side effects of the scene; '' = the simple deterministic wearer")
        wearer_index = declare(self, 'wearer_index', 0, "with scene_file: which wearer of the scene's population",
                               low=0, high=9999)
        condition = declare(self, 'condition', 0, "with scene_file: the paper's condition 1-4 (its layout wins "
                            'over layout; 4: the wearer hears speech and ignores the suit); 0 = from layout '
                            '(suit: 1, arm: 3)', low=0, high=4)
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
            self.scene_side = SceneSide(scene, wearer_index, cond.number, self.dt, self.layout)
            elsewhere = [f'{n} in {REALISED_ELSEWHERE[n]}' for n in scene.effect_names if n in REALISED_ELSEWHERE]
            self.get_logger().info(
                f'scene {scene.name} ({scene.source}): wearer {self.scene_side.spec.name} (index {wearer_index}), '
                f'condition {cond.number}, {rate:g} steps/s, run key {self.scene_side.run_key}; effects applied '
                f'here: {", ".join(self.scene_side.applied_effects()) or "none"}'
                + (f'; realised elsewhere: {", ".join(elsewhere)}' if elsewhere else ''))
        elif condition == 4:
            raise ValueError('parameter condition: 4 (speech) needs scene_file; the simple wearer does not hear')
        else:
            self.wearer = SimulatedWearer([PowerLaw(*laws[i:i + 3]) for i in range(0, 12, 3)], tau_s=tau)
        self.pressures = np.zeros(4)
        self.pressures_received = -float('inf')
        self.active = ''
        self.target: tuple[float, float] | None = None   # active target (yaw, pitch) from the eye, degrees
        self.seq = 0
        self.last_step = self.start = time.monotonic()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        if self.address[0] in ('localhost', '127.0.0.1') or self.address[0].startswith('127.'):
            # Sending alone would bind the socket to 0.0.0.0: reachable from the network.
            self.sock.bind(('127.0.0.1', 0))
        self.create_subscription(Float64MultiArray, MEASURED_PRESSURE, self.on_pressure, COMMAND_QOS)
        self.create_subscription(String, ACTIVE_TARGET, self.on_active_target, LATCHED_QOS)
        if self.scene_side is not None:
            self.create_subscription(PointStamped, TARGET, self.on_target, LATCHED_QOS)
            if self.scene_side.cond.speech:
                self.create_subscription(String, SPEECH, self.on_speech, EVENT_QOS)
            self.create_timer(self.dt, self.scene_step)
        else:
            self.create_timer(self.dt, self.step)

    def on_pressure(self, msg: Float64MultiArray) -> None:
        if len(msg.data) != len(self.channel_map.channels):
            return
        self.pressures = self.channel_map.to_directions(np.nan_to_num(np.asarray(msg.data)), self.layout)
        self.pressures_received = time.monotonic()

    def on_active_target(self, msg: String) -> None:
        if msg.data == self.active:
            return
        self.active = msg.data
        self.target = None          # the new target's position comes on `target`
        side = self.scene_side
        if side is not None:
            if self.active:
                side.present()
            elif self.return_to_front:
                side.withdraw()

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
        if self.return_to_front and not self.active:
            gaze = self.wearer.return_to_front(dt)
        else:
            gaze = self.wearer.step(self.felt(now), dt)
        self.send(self.seq, now, gaze, gaze)
        self.seq = (self.seq + 1) % 2 ** 32

    def scene_step(self) -> None:
        """The scene's wearer: simulation steps of dt, as many as the wall clock says are due."""
        now = time.monotonic()
        side = self.scene_side
        due = int(round((now - self.start) / self.dt)) - side.step_index
        if due > MAX_CATCH_UP_STEPS:        # a stall: do not replay it
            due = MAX_CATCH_UP_STEPS
            self.start = now - (side.step_index + due) * self.dt
        follow = bool(self.active) or not self.return_to_front
        felt = self.felt(now)
        for _ in range(due):
            sample = side.step(felt, follow, self.target if self.active else None)
            if sample is None:
                continue     # lost (datagram_loss) or still on its way (datagram_latency)
            seq, t_emitted, yaw, pitch = sample
            # The tracker's gaze (with its noise) on the wire; the head pose is the true posture.
            self.send(seq % 2 ** 32, self.start + t_emitted, gaze_from_angles(yaw, pitch),
                      gaze_from_angles(*side.sent_true_gaze))

    def send(self, seq: int, stamp: float, gaze, head_direction) -> None:
        head = ros_to_unity_quaternion(ray_orientation(head_direction))
        origin = (0.0, self.eye_height, 0.0)   # Unity: y up
        datagram = encode_datagram(seq, stamp, origin, ros_to_unity_point(gaze), origin, head, True)
        try:
            self.sock.sendto(datagram, self.address)
        except OSError as exc:  # the bridge not there yet is no reason to stop
            self.get_logger().warn(f'cannot send gaze: {exc}', throttle_duration_sec=5.0)

    def safe_shutdown(self) -> None:
        self.sock.close()


def main(args=None) -> int:
    return run(WearerSim, args)


if __name__ == '__main__':
    sys.exit(main())
