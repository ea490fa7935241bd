"""Simulated wearers: SimulatedWearer (the ROS wearer_sim node, worked_example.py) and
SceneWearer (the scene simulator, engine.py).

SimulatedWearer reads the suit's pressure per direction (left, right, down, up), interprets
it through their own power law (their sensitivity, which the calibration has to discover) as
an angle to turn, and turns torso and gaze toward it as a first-order lag. The turn is
relative to the posture they held when the suit started pulling (the anchor); while they feel
nothing (every pressure below their threshold c) they hold still. A pause shorter than
pull_memory_s (a link vent of a few tenths of a second) is the same pull interrupted: when
it comes back they go on counting from the anchor, not from where the pause found them
(which would read the whole pull again as a further turn). After a longer pause the next pull
counts from where they are. Gaze = torso (no separate eye or head movement in this model). No
noise and no delays.

SceneWearer is the same wearer without a built-in lag and without the pull memory (a pause
re-anchors it at once; its cue effects decide what it makes of a pull): the effects a scene
calls for (effects.py: perception, reaction delay, body dynamics with visual capture) are
composed around it by engine.py.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..core.feedback import PAPER_P_MAX
from ..core.geometry import DIRECTIONS
from ..core.power_law import PowerLaw
from ..core.speech import parse_phrase


def gaze_from_angles(yaw_deg: float, pitch_deg: float) -> np.ndarray:
    """Unit gaze direction in REP 103 from yaw (positive left) and pitch (positive up)."""
    y, p = math.radians(yaw_deg), math.radians(pitch_deg)
    return np.array([math.cos(p) * math.cos(y), math.cos(p) * math.sin(y), math.sin(p)])


#: How long a pause in the pull the simple wearer still takes for the same pull, s. An
#: assumption: longer than a lost Modbus request's vent and resume (0.2-0.5 s), shorter than
#: Algorithm 1's rest (3 s), so calibration is unchanged.
PULL_MEMORY_S = 1.0


class SimulatedWearer:
    def __init__(self, laws: Sequence[PowerLaw], tau_s: float = 0.4, p_max: float = PAPER_P_MAX,
                 yaw_deg: float = 0.0, pitch_deg: float = 0.0, pull_memory_s: float = PULL_MEMORY_S):
        if len(laws) != len(DIRECTIONS):
            raise ValueError(f'need one power law per direction {DIRECTIONS}')
        if not (math.isfinite(tau_s) and tau_s > 0):
            raise ValueError(f'tau_s must be finite and > 0, got {tau_s}')
        if not (math.isfinite(pull_memory_s) and pull_memory_s >= 0):
            raise ValueError(f'pull_memory_s must be finite and >= 0, got {pull_memory_s}')
        self.laws, self.tau_s, self.p_max = list(laws), tau_s, p_max
        self.pull_memory_s = pull_memory_s
        self.yaw, self.pitch = yaw_deg, pitch_deg
        self._anchor: tuple[float, float] | None = None
        self._unfelt_s = 0.0      # how long nothing has been felt since the last pull

    @property
    def gaze(self) -> np.ndarray:
        return gaze_from_angles(self.yaw, self.pitch)

    def face_front(self) -> None:
        """Be back at the starting posture at once."""
        self.yaw = self.pitch = 0.0
        self._anchor = None
        self._unfelt_s = 0.0

    def return_to_front(self, dt: float) -> np.ndarray:
        """Turn back toward the front on one's own, ignoring the suit, as the paper's wearers
        did between targets; same dynamics as a guided turn."""
        self._anchor = None
        alpha = 1.0 - math.exp(-max(dt, 0.0) / self.tau_s)
        self.yaw -= alpha * self.yaw
        self.pitch -= alpha * self.pitch
        return self.gaze

    def perceived_angles(self, pressures: Sequence[float]) -> np.ndarray:
        """The angle each direction's pressure means to this wearer, degrees."""
        return np.array([law.theta(p, self.p_max) for law, p in zip(self.laws, pressures)])

    def step(self, pressures: Sequence[float], dt: float) -> np.ndarray:
        """Advance dt seconds under direction pressures (kPa); return the new gaze."""
        p = np.nan_to_num(np.asarray(pressures, dtype=float), nan=0.0)
        perceived = self.perceived_angles(p)
        if not np.any(perceived > 0):
            # Nothing felt (every pressure below the wearer's threshold c): hold still; once the
            # pause outlasts the pull's memory, the next pull counts from here.
            self._unfelt_s += max(dt, 0.0)
            if self._unfelt_s >= self.pull_memory_s:
                self._anchor = None
            return self.gaze
        self._unfelt_s = 0.0
        if self._anchor is None:
            self._anchor = (self.yaw, self.pitch)
        left, right, down, up = perceived
        goal_yaw = self._anchor[0] + left - right
        goal_pitch = float(np.clip(self._anchor[1] + up - down, -89.0, 89.0))
        alpha = 1.0 - math.exp(-max(dt, 0.0) / self.tau_s)
        self.yaw += alpha * (goal_yaw - self.yaw)
        self.pitch += alpha * (goal_pitch - self.pitch)
        return self.gaze


def haversine(yaw1: float, pitch1: float, yaw2: float, pitch2: float) -> float:
    """hav of the angle between two gaze directions given as yaw/pitch (degrees): sin^2 of half
    the angle. Monotonic in the angle, so comparing it with hav_limit(limit) is comparing the
    angle with the limit, without the inverse trigonometry."""
    s_p = math.sin(0.008726646259971648 * (pitch2 - pitch1))      # pi / 360
    s_y = math.sin(0.008726646259971648 * (yaw2 - yaw1))
    h = s_p * s_p + math.cos(0.017453292519943295 * pitch1) * math.cos(0.017453292519943295 * pitch2) * s_y * s_y
    return 0.0 if h < 0.0 else (1.0 if h > 1.0 else h)


def hav_limit(limit_deg: float) -> float:
    """haversine() of an angle of limit_deg degrees."""
    s = math.sin(math.radians(limit_deg) / 2.0)
    return s * s


def angle_between_deg(yaw1: float, pitch1: float, yaw2: float, pitch2: float) -> float:
    """The full angle between two gaze directions given as yaw/pitch (degrees), in [0, 180]:
    the haversine form, exact near 0 (core.task.angular_error_deg on the vectors gives the
    same number; test_sim_engine checks it)."""
    return math.degrees(2.0 * math.asin(math.sqrt(haversine(yaw1, pitch1, yaw2, pitch2))))


#: The wearer cannot look beyond straight up or down (as SimulatedWearer).
PITCH_LIMIT_DEG = 89.0
#: Nor turn further than this to either side while seated: trunk rotation (about 40-50 deg)
#: plus neck rotation (about 70-80 deg). An assumption of that order; it keeps a very
#: sensitive wearer from turning round through 180 deg, where the angles wrap.
YAW_LIMIT_DEG = 120.0
#: The seat's limits for the goals taken from the touch (hololens_view.edge_deg narrows them).
SEAT_LIMITS = (YAW_LIMIT_DEG, PITCH_LIMIT_DEG)


def _clip(x: float, limit: float) -> float:
    return limit if x > limit else (-limit if x < -limit else x)


class SceneWearer:
    """The wearer of the scene simulator (fabric_guidance.sim.engine): their own power law per
    direction and per layout, goals from percepts, and the posture that follows.

    Posture is torso yaw/pitch (degrees, yaw positive left, pitch positive up, REP 103) plus a
    head offset; the gaze is their sum. The engine drives it:

    - feel(percept): haptic conditions. Each direction's perceived pressure means an angle by the
      wearer's own inverse law (0 below their threshold c); the goal is the posture the pull
      began at (the anchor) plus those angles. Feeling nothing, they hold still and the next pull
      counts from there (as SimulatedWearer).
    - hear(h, v): condition 4. The goal is the gaze when the phrase is acted on plus the spoken
      angles.
    - go_front(): the speed protocol's return to the front (and Algorithm 1's rest), ignoring
      the suit.
    - move(dt, capture): without body dynamics the torso stands at the goal and the gaze is the
      torso's. With them (effects.BodyDynamics) the torso follows the goal as a first-order lag,
      and while a visible target (capture = its yaw, pitch) is inside the central visual field,
      head and eyes turn the gaze to it in the world with the faster lag (compensating the
      torso's own motion); otherwise they return to the torso's direction. Goals stay within
      YAW_LIMIT_DEG and PITCH_LIMIT_DEG.

    Scalar arithmetic throughout: it runs every simulation step.
    """

    def __init__(self, suit_laws: Sequence[PowerLaw], arm_laws: Sequence[PowerLaw] | None = None,
                 p_max: float = PAPER_P_MAX, body=None):
        if len(suit_laws) != len(DIRECTIONS) or (arm_laws is not None and len(arm_laws) != len(DIRECTIONS)):
            raise ValueError(f'need one power law per direction {DIRECTIONS}')
        self.p_max = float(p_max)
        self._inverse = {'suit': self._prepare(suit_laws), 'arm': self._prepare(arm_laws or suit_laws)}
        self.layout = 'suit'
        self.body = body
        #: effects.CueMisreading of the run, or None (the cue is read exactly); Senses sets it.
        self.cue = None
        #: How far the goals taken from the touch may go (deg): the seat's limits, or the
        #: objects' region plus hololens_view.edge_deg while a visible target is looked for.
        self.touch_limits = SEAT_LIMITS
        self.face_front()

    @staticmethod
    def _prepare(laws):
        return tuple((law.a, law.c, 1.0 / law.b) for law in laws)

    def set_layout(self, layout: str) -> None:
        if layout not in self._inverse:
            raise ValueError(f'unknown layout {layout!r}; the wearer has {sorted(self._inverse)}')
        self.layout = layout

    def face_front(self) -> None:
        self.torso_yaw = self.torso_pitch = 0.0
        self.head_yaw = self.head_pitch = 0.0
        self.goal_yaw = self.goal_pitch = 0.0
        self.anchor = None
        self.acting = False   # has acted on a guidance percept since the last reset_acting()
        self.new_read = False  # a cue was read this step (the first percept of a guidance)
        self._last_felt = None

    @property
    def gaze_yaw(self) -> float:
        return self.torso_yaw + self.head_yaw

    @property
    def gaze_pitch(self) -> float:
        return self.torso_pitch + self.head_pitch

    @property
    def gaze(self) -> np.ndarray:
        return gaze_from_angles(self.gaze_yaw, self.gaze_pitch)

    def perceived_angles(self, pressures: Sequence[float]) -> list[float]:
        """The angle each direction's (perceived) pressure means to this wearer, degrees."""
        out = [0.0, 0.0, 0.0, 0.0]
        p_max = self.p_max
        for k, (a, c, inv_b) in enumerate(self._inverse[self.layout]):
            p = pressures[k]
            if p > c:
                theta = ((p if p < p_max else p_max) - c) / a
                theta = theta ** inv_b
                out[k] = theta if theta < 180.0 else 180.0
        return out

    def feel(self, pressures: Sequence[float]) -> None:
        self._last_felt = pressures
        left, right, down, up = self.perceived_angles(pressures)
        if not (left > 0.0 or right > 0.0 or down > 0.0 or up > 0.0):
            self.anchor = None
            self.goal_yaw, self.goal_pitch = self.torso_yaw, self.torso_pitch
            return
        cue = self.cue
        if self.anchor is None:
            self.anchor = (self.torso_yaw, self.torso_pitch)
            if cue is not None:
                # The first percept of a guidance: the cue is read (and may be misread).
                cue.p = cue.arm_direction_p if self.layout == 'arm' else cue.direction_p
                cue.read()
                self.new_read = True
        self.acting = True
        lim_yaw, lim_pitch = self.touch_limits
        if cue is None or (cue.factor_h == 1.0 and cue.factor_v == 1.0):
            self.goal_yaw = _clip(self.anchor[0] + left - right, lim_yaw)
            self.goal_pitch = _clip(self.anchor[1] + up - down, lim_pitch)
        else:
            self.goal_yaw = _clip(self.anchor[0] + cue.factor_h * (left - right), lim_yaw)
            self.goal_pitch = _clip(self.anchor[1] + cue.factor_v * (up - down), lim_pitch)

    def feel_again(self) -> None:
        """The cue was read again: the goal follows the new reading of the last percept."""
        if self._last_felt is not None and self.anchor is not None:
            self.feel(self._last_felt)

    def hear(self, horizontal: float, vertical: float) -> None:
        self.anchor = None
        self.acting = True
        self.goal_yaw = _clip(self.gaze_yaw + horizontal, YAW_LIMIT_DEG)
        self.goal_pitch = _clip(self.gaze_pitch + vertical, PITCH_LIMIT_DEG)

    def go_front(self) -> None:
        self.anchor = None
        self.goal_yaw = self.goal_pitch = 0.0

    def move(self, capture: tuple[float, float] | None = None) -> None:
        body = self.body
        if body is None:
            self.torso_yaw, self.torso_pitch = self.goal_yaw, self.goal_pitch
            return
        gy, gp = self.torso_yaw + self.head_yaw, self.torso_pitch + self.head_pitch
        ta = body.torso_alpha
        self.torso_yaw += (self.goal_yaw - self.torso_yaw) * ta
        self.torso_pitch += (self.goal_pitch - self.torso_pitch) * ta
        ha = body.head_alpha
        if (capture is not None and body.central_field_deg > 0.0
                and haversine(gy, gp, capture[0], capture[1]) <= body.central_field_hav):
            # Visual capture: the gaze turns to the target in the world, whatever the torso does
            # (head and eyes compensate the torso's motion, as the vestibulo-ocular reflex does).
            gy += (capture[0] - gy) * ha
            gp += (capture[1] - gp) * ha
            self.head_yaw, self.head_pitch = gy - self.torso_yaw, gp - self.torso_pitch
        else:
            # Nothing to look at: head and eyes come back to the torso's direction.
            self.head_yaw -= self.head_yaw * ha
            self.head_pitch -= self.head_pitch * ha


class Senses:
    """What reaches a SceneWearer from the suit and from the speaker, one step at a time, in
    the order of sim.effects: the command through the pressure effects (what the suit exerts),
    then in the haptic conditions the percept effects and the reaction delay before the wearer
    feels it; in condition 4 the phrase after speech_latency, then the reaction delay, before
    the wearer hears it. The headless engine and the wearer_sim node both use it, so the two
    cannot drift apart.

    stages: effects.by_stage() of the run's started effects; skip: names of pressure effects
    realised elsewhere (the graph's mock PLC is the regulator); cue: False switches the cue
    effects off (Algorithm 1: a slow, supervised procedure, where the wearer is not misled).

    The cue effects (the wearer who can be wrong), in the haptic conditions while the wearer follows: the wearer
    reads the cue through cue_misreading; surface_resistance (suit only) makes them read it
    again with the right direction once a wrong move has built up enough resistance;
    relative_perception (suit only) makes them read it again, with the right direction, when
    the pressure rises; and after standing still for cue_misreading.reread_s without seeing the
    visible target they look for (`searching` and `seen`, set by the engine) they read it
    again. Every read restarts the resistance and the rise detection. A read of the arm band's
    cue (layout 'arm') holds the wearer still for cue_misreading.arm_read_s: they are not yet
    acting (the accuracy task's press waits) and the stand-still is no reason to read again. In the ROS graph
    (sim.scene_wearer.SceneSide) `seen` comes from visual capture alone: hololens_view is
    headless only.
    """

    def __init__(self, stages, haptic: bool, skip=(), cue: bool = True):
        self.pressure_fx = [e.pressure for e in stages['pressure'] if e.name not in skip]
        self.percept_fx = [e.percept for e in stages['percept']]
        self.delay = stages['delay'][0] if stages['delay'] else None
        self.speech = stages['speech'][0] if stages['speech'] else None
        self.haptic = haptic
        cue_fx = {e.name: e for e in stages.get('cue', ())}
        self.cue = cue_fx.get('cue_misreading')
        self.resistance = cue_fx.get('surface_resistance')
        self.relative = cue_fx.get('relative_perception')
        self._cue_on = haptic and bool(cue_fx) and cue
        self.seen = False          # the wearer sees the target (engine: visual capture)
        # The wearer looks for a visible object (speed task); with nothing to look for (the
        # accuracy task) standing still means "arrived", not "lost": no re-read.
        self.searching = True
        self._prev = None          # torso (yaw, pitch, t) of the last cue step
        self._still_s = 0.0
        self._stills = 0           # 'still' re-reads of this guidance
        self.rereads = {'resistance': 0, 'rise': 0, 'still': 0}
        self.pending: tuple[float, int, str] | None = None   # (time heard, number, text)
        self.heard: tuple[int, float, float] | None = None    # (number, h, v) of the last phrase heard
        self.heard_phrases: list[str] = []
        self._count = 0
        self._acted_on: int | None = None
        self._reads = self.cue.reads if self.cue is not None else 0   # reads seen by _read_hold
        self._reading_until = -math.inf
        if self.delay is not None:
            self.delay.reset((0.0, 0.0, 0.0, 0.0) if haptic else None)

    def reread(self, wearer: 'SceneWearer', why: str, correct: bool = False) -> None:
        """The wearer reads the cue again (why: resistance, rise or still)."""
        if why == 'still':
            self._stills += 1
        if self.cue is not None:
            boost = (1.0 + self.cue.still_gain) ** min(self._stills, 2) if self._stills else 1.0
            self.cue.read(correct_direction=correct, boost=boost)
        self.rereads[why] += 1
        self._restart()

    def _restart(self) -> None:
        self._still_s = 0.0
        if self.resistance is not None:
            self.resistance.impulse = 0.0
        if self.relative is not None:
            self.relative.restart()

    def _cue_step(self, t: float, exerted, wearer: 'SceneWearer') -> None:
        if wearer.new_read:
            wearer.new_read = False
            self._stills = 0
            self._restart()
        if wearer.anchor is None:          # nothing felt: no cue to read
            self._prev = None
            return
        ty, tp = wearer.torso_yaw, wearer.torso_pitch
        prev = self._prev
        self._prev = (ty, tp, t)
        if prev is None or t <= prev[2]:
            return
        dt = t - prev[2]
        vy, vp = (ty - prev[0]) / dt, (tp - prev[1]) / dt
        suit = wearer.layout == 'suit'
        resistance = self.resistance
        if suit and resistance is not None and resistance.accumulate(exerted, vy, vp, dt):
            self.reread(wearer, 'resistance', correct=True)
            wearer.feel_again()
            return
        if suit and self.relative is not None and self.relative.rise(exerted):
            self.reread(wearer, 'rise', correct=True)
            wearer.feel_again()
            return
        cue = self.cue
        if cue is None:
            return
        if not self.searching:
            return
        if vy * vy + vp * vp < cue.still_dps * cue.still_dps and not self.seen:
            self._still_s += dt
            if self._still_s >= cue.reread_s - 1e-9:
                self.reread(wearer, 'still')
                wearer.feel_again()
        else:
            self._still_s = 0.0

    def _read_hold(self, t: float, wearer: 'SceneWearer') -> None:
        """While the arm's cue is being read (arm_read_s after each read) the wearer stands still."""
        cue = self.cue
        if cue is None or cue.arm_read_s <= 0.0 or wearer.layout != 'arm':
            return
        if cue.reads != self._reads:      # read this step: the first percept or a re-read
            self._reads = cue.reads
            self._reading_until = t + cue.arm_read_s
        if t < self._reading_until - 1e-9 and wearer.anchor is not None:
            wearer.goal_yaw, wearer.goal_pitch = wearer.torso_yaw, wearer.torso_pitch
            wearer.acting = False
            self._still_s = 0.0

    def say(self, t: float, text: str) -> None:
        """Condition 4's phrase is spoken at t; the wearer hears it after speech_latency."""
        latency = self.speech.latency(text) if self.speech is not None else 0.0
        self._count += 1
        self.pending = (t + latency, self._count, text)

    def forget(self) -> None:
        """The target is gone: a phrase not yet heard is never heard."""
        self.pending = None

    def step(self, t: float, command, wearer: 'SceneWearer', follow: bool):
        """One step at time t under `command` (kPa per direction); the wearer feels or hears
        what reaches them when `follow`. Returns the pressure the suit exerts."""
        p = command
        for fx in self.pressure_fx:
            p = fx(p)
        exerted = p
        if self.haptic:
            for fx in self.percept_fx:
                p = fx(p)
            if self.delay is not None:
                p = self.delay.delay((p[0], p[1], p[2], p[3]))
            if follow:
                if self._cue_on:
                    wearer.cue = self.cue
                wearer.feel(p)
                if self._cue_on:
                    self._cue_step(t, exerted, wearer)
                    self._read_hold(t, wearer)
            elif self._cue_on:
                self._prev = None
            return exerted
        pending = self.pending
        if pending is not None and t >= pending[0] - 1e-9:
            self.pending = None
            self.heard = (pending[1],) + parse_phrase(pending[2])
            self.heard_phrases.append(pending[2])
        heard = self.heard
        if self.delay is not None:
            heard = self.delay.delay(heard)
        if heard is not None and heard[0] != self._acted_on and follow:
            self._acted_on = heard[0]
            wearer.hear(heard[1], heard[2])
        return exerted
