"""The wearer side of a scene's closed loop as the ROS graph runs it (nodes/wearer_sim.py with
scene_file), without ROS: wearer `wearer_index` of the scene's population
(sim.population.sample_wearer), a sim.wearer.SceneWearer with the scene's body_dynamics if
listed, and the scene's wearer-side effects (sim.effects) applied every step, in the order of
the headless engine (sim.engine.ClosedLoop.step):

    measured_pressure (the mock PLC realises regulator_lag)
      -> per-direction mean (ChannelMap.to_directions, the condition's layout)
      -> [pressure] suit_hysteresis -> [percept] weber_perception -> [delay] reaction_delay
      -> SceneWearer.feel -> SceneWearer.move (visual capture of the active target)
      -> gaze -> [gaze] gaze_noise, datagram_loss (not sent), datagram_latency (sent later)
      -> UDP datagram
    condition 4: speech -> [speech] speech_latency -> core.speech.parse_phrase
      -> [delay] reaction_delay -> SceneWearer.hear

The effects are started with the engine's seeding, RunContext(dt, scene seed, wearer_index,
engine.trial_run(condition, 0)), so the same scene file gives the same effect parameters and
random streams (datagram seq k carries the k-th gaze_noise draw). The graph runs in real time
on DDS, UDP and Modbus, so a run is not bit-identical with the headless engine's.
regulator_lag is not applied here: the mock PLC's regulator_tau_s is the regulator
(fabric-guidance demo --scene sets it from the scene). hololens_view is headless only.
"""
from __future__ import annotations

import math
from pathlib import Path

from ..core import condition as condition_of
from ..paths import share_dir
from .effects import RunContext, start_effects
from .engine import trial_run
from .population import sample_wearer
from .scene import load_scene
from .wearer import SceneWearer, Senses, hav_limit, haversine

#: Effects the node does not apply because another part of the graph realises them.
REALISED_ELSEWHERE = {'regulator_lag': 'mock_plc (regulator_tau_s)'}
#: Effects the graph does not realise at all: the simulated wearer has no HoloLens display to
#: search (the headless engine's visual search and key confirmation).
HEADLESS_ONLY = frozenset({'hololens_view'})
#: Where the demo report lists the effects the graph does not realise.
HEADLESS_ONLY_LABEL = 'headless only (not realised in the graph)'
#: Stages that act on the suit's or the arm's pressure: nothing to act on when speech guides.
HAPTIC_STAGES = ('pressure', 'percept', 'cue')
#: effect_place() of an effect the condition does not use.
UNUSED = 'unused'


def effect_place(name: str, stage: str, cond) -> str:
    """Where the graph realises the effect `name` (of `stage`) in condition `cond`: the node of
    REALISED_ELSEWHERE, HEADLESS_ONLY_LABEL, UNUSED, or 'wearer_sim'."""
    if name in REALISED_ELSEWHERE:
        return REALISED_ELSEWHERE[name]
    if name in HEADLESS_ONLY:
        return HEADLESS_ONLY_LABEL
    if (stage in HAPTIC_STAGES and not cond.haptic) or (stage == 'speech' and not cond.speech):
        return UNUSED
    return 'wearer_sim'


_FRONT = (0.0, 0.0)


def load_scene_file(value: str):
    """A scene from a path (relative: to the working directory, else to the package share)
    or the name of one of config/scenes/."""
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

    def __init__(self, scene, wearer_index: int, condition: int, dt: float,
                 layout: str | None = None, repetition: int = 0):
        n = scene.population.subjects
        if not 0 <= wearer_index < n:
            raise ValueError(f'parameter wearer_index: the scene {scene.name} has wearers '
                             f'0..{n - 1}, got {wearer_index}')
        spec = sample_wearer(scene, wearer_index)
        if spec.error:
            raise ValueError(f'wearer {wearer_index} of scene {scene.name} is not usable: '
                             f'{spec.error}')
        self.scene, self.spec, self.dt = scene, spec, float(dt)
        self.cond = condition_of(condition)
        self.layout = layout or self.cond.layout or 'suit'
        self.run_key = trial_run(self.cond.number, int(repetition))   # the headless trial's streams
        ctx = RunContext(self.dt, scene.seed, int(wearer_index), self.run_key)
        self.effects, stages = start_effects(scene.effects, ctx, spec.effect_params)
        self.gaze_fx = [e.gaze for e in stages['gaze']]
        body = stages['body'][0] if stages['body'] else None
        self.wearer = SceneWearer(spec.suit_laws, spec.arm_laws, scene.controller.p_max_kpa, body)
        self.wearer.set_layout(self.layout)
        self.haptic = self.cond.haptic
        self.senses = Senses(stages, self.haptic, skip=REALISED_ELSEWHERE)
        # Senses.seen (the cue effects' re-reads) from visual capture, as the engine sets it
        # without hololens_view (headless only): the target inside the central field.
        self._track_seen = self.senses._cue_on
        self._central_hav = body.central_field_hav if body is not None else 0.0
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
        return [e.name for e in self.effects if effect_place(e.name, e.stage, self.cond) == 'wearer_sim']

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
            capture = target if self.visible else None
            if capture is not None and self._track_seen:
                gy, gp = wearer.torso_yaw + wearer.head_yaw, wearer.torso_pitch + wearer.head_pitch
                hav = haversine(gy, gp, capture[0], capture[1])
                self.senses.seen = self._central_hav > 0.0 and hav <= self._central_hav
            elif self._track_seen:
                self.senses.seen = False
            wearer.move(capture)
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


#: A press the target outlives by this much was refused: press again [s].
REPRESS_S = 1.0


class KeyPress:
    """When the simulated participant presses the confirm key, by the headless model's rule
    (sim.protocols), one press per target:

    speed: the tracked gaze (the samples sent) has stayed within acceptance_deg of the target
        for dwell_s (speed_loop's rule; hololens_view's confirm delay is headless only);
    accuracy: once the wearer has acted on the guidance and their true gaze has moved slower
        than settle_speed_dps for settle_s, or at timeout_s (accuracy_trial's rule).

    present() when a target appears; sent(t, yaw, pitch) with each gaze sample sent and
    stepped(t, wearer) after each step; each returns True once: press now. A target still there
    REPRESS_S after a press (the session refused it: a stale or gapped gaze at the press) is
    pressed for again by the same rule, as a person presses again.
    """

    def __init__(self, protocol, dt: float):
        self.protocol, self.dt = protocol, float(dt)
        self.speed = protocol.kind == 'speed'
        self.target: tuple[float, float] | None = None
        self.pressed = True      # nothing to press for until a target appears
        self._pressed_at: float | None = None    # while the target is still there
        self._since = None
        self._appeared = 0.0
        self._prev = None

    def present(self, t: float, target: tuple[float, float] | None) -> None:
        """A target appeared at t (target: its (yaw, pitch) once known)."""
        self.target, self.pressed, self._since, self._appeared, self._prev = target, False, None, t, None
        self._pressed_at = None

    def withdraw(self) -> None:
        self.pressed, self._pressed_at = True, None

    def _press(self, t: float) -> bool:
        self.pressed, self._pressed_at = True, t
        return True

    def _rearm(self, t: float) -> None:
        if self.pressed and self._pressed_at is not None and t - self._pressed_at >= REPRESS_S:
            self.pressed, self._pressed_at, self._since = False, None, None

    def sent(self, t: float, yaw: float, pitch: float) -> bool:
        self._rearm(t)
        if not self.speed or self.pressed or self.target is None:
            return False
        proto = self.protocol
        if haversine(yaw, pitch, *self.target) > hav_limit(proto.acceptance_deg):
            self._since = None
            return False
        self._since = t if self._since is None else self._since
        return t - self._since >= proto.dwell_s and self._press(t)

    def stepped(self, t: float, wearer) -> bool:
        if not self.speed:
            self._rearm(t)
        if self.speed or self.pressed:
            return False
        proto = self.protocol
        gy, gp = wearer.torso_yaw + wearer.head_yaw, wearer.torso_pitch + wearer.head_pitch
        prev, self._prev = self._prev, (gy, gp)
        if t - self._appeared >= proto.timeout_s - 1e-9 and self._pressed_at is None:
            return self._press(t)
        if prev is None:
            return False
        moved = math.hypot((gy - prev[0]) * math.cos(math.radians(gp)), gp - prev[1])
        if not wearer.acting or moved >= proto.settle_speed_dps * self.dt:
            self._since = None
            return False
        self._since = t if self._since is None else self._since
        return t - self._since >= proto.settle_s - 1e-9 and self._press(t)
