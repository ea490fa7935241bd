"""The closed loop of a scene: controller -> channel map -> effects -> wearer -> gaze -> effects
-> controller, at a fixed step, with the core's classes as the nodes use them.

One ClosedLoop is one run: Algorithm 1 on a wearer (calibration), or a protocol's trial in one
condition. It steps at the scene's sim_rate_hz; the controller (or the calibration procedure,
or condition 4's speech) acts at control_rate_hz on the last gaze sample it received, as the
pressure_controller node does:

- no valid gaze for gaze_timeout_s: vent (the node's why_not_guide); guidance restarts from the
  gaze at the next fresh sample (GuidanceController.update begins from it);
- a new target: vent, and the next control step begins from the gaze at that moment; in
  condition 4 the phrase (core.speech.phrase) is spoken once, from that gaze;
- calibration: CalibrationProcedure.tick(t, last gaze if fresh), failing when the gaze went
  stale, as the node does.

The command per direction goes through core.channels.ChannelMap.to_channels (the command
vector) and to_directions (the mean each direction's muscles exert, what the wearer feels),
for the condition's layout; then the scene's effects (fabric_guidance.sim.effects) in their
places. Only the listed effects are built; with none the wearer is ideal.

A run is a pure function of (scene, wearer, run key): the same inputs give bit-identical
outputs in any process, whatever ran before.

Speed: the loop is plain float arithmetic. The feedback law is the core's (the FeedbackLaw
objects of a GuidanceController, begun and vented through it) stepped with the angles from the
initial gaze computed here from yaw/pitch instead of from vectors (test_sim_engine checks that
this gives GuidanceController.update's pressures), and the fitted power laws are evaluated with
scalar math (FastPowerLaw). The acceptance test is core.task.AcceptanceTracker's rule on the
haversine form of the angle.
"""
from __future__ import annotations

from dataclasses import asdict
from functools import lru_cache
import math
from typing import Sequence

from ..core.calibration import ACCEPT_ALL, APPLY, Calibration, CalibrationProcedure, DONE, FAILED
from ..core.channels import ChannelMap
from ..core.conditions import condition as condition_of
from ..core.control_step import build_controller
from ..core.feedback import REST, GuidanceController, step_directions
from ..core.geometry import DIRECTIONS, wrap_deg
from ..core.power_law import CalibrationFitError, PowerLaw
from ..core.speech import phrase
from ..paths import config_path
from .effects import RunContext, start_effects
from .wearer import (PITCH_LIMIT_DEG, SEAT_LIMITS, YAW_LIMIT_DEG, SceneWearer, Senses,  # noqa: F401
                     angle_between_deg, gaze_from_angles, haversine)

#: Seconds of simulated time before a run starts: the gaze stream, its loss and latency state
#: settle with the wearer at rest, facing front (the HoloLens streams before a trial begins).
WARMUP_S = 1.0

_FRONT = (0.0, 0.0)

#: Run keys: what seeds a run's random streams besides the scene seed, wearer and effect name.
CALIBRATION_RUN = (1,)


def trial_run(condition: int, repetition: int) -> tuple[int, int, int]:
    return (2, int(condition), int(repetition))


@lru_cache(maxsize=4)
def package_channel_map(path: str | None = None) -> ChannelMap:
    """The package's channel map (config/hardware/channel_map.yaml), loaded once per process."""
    return ChannelMap.load(path or config_path('hardware/channel_map.yaml'))


class FastPowerLaw(PowerLaw):
    """A PowerLaw whose pressure() of a Python float is scalar math (the same formula);
    anything else goes to PowerLaw. Used for the controller's fitted laws."""

    @classmethod
    def of(cls, law: PowerLaw) -> 'FastPowerLaw':
        return cls(law.a, law.b, law.c)

    def pressure(self, theta):
        if type(theta) is float:
            t = 0.0 if theta < 0.0 else (180.0 if theta > 180.0 else theta)
            if t == t:
                return self.a * t ** self.b + self.c
        return PowerLaw.pressure(self, theta)


def scene_controller(ctl, mode: str, calibration: Calibration, *, use_wearer_gain: bool = False,
                     follow_target: bool = False) -> GuidanceController:
    """The controller the node builds (core.control_step.build_controller, the one builder) from
    a scene's controller section, with fast scalar power laws. The simulator steps Eq. 5 itself
    (no GuidanceController.update), so it has no no-progress vent: stall_timeout_s never."""
    values = {**asdict(ctl), 'stall_timeout_s': None, 'use_wearer_gain': use_wearer_gain,
              'follow_moving_target': follow_target}
    return build_controller(values, mode, calibration, FastPowerLaw.of)


def yaw_pitch(direction) -> tuple[float, float]:
    """(yaw, pitch) in degrees of a direction vector (the inverse of gaze_from_angles)."""
    x, y, z = (float(c) for c in direction)
    return math.degrees(math.atan2(y, x)), math.degrees(math.atan2(z, math.hypot(x, y)))


class ClosedLoop:
    """One run of the scene's closed loop for one wearer.

    wearer: anything with index, suit_laws and arm_laws (population.WearerSpec). condition:
    1-4 for a trial (with `calibration`, the fitted laws the controller uses), None for
    Algorithm 1 (run_calibration). run: the run key that seeds the effects' streams.

    Drive it with present()/withdraw() and step(); read t, the wearer's true gaze
    (wearer.gaze_yaw/gaze_pitch) and the controller's last sample (measured_yaw/pitch,
    new_sample: one arrived this step, received_t).
    """

    def __init__(self, scene, wearer, run: Sequence[int], condition: int | None = None,
                 calibration: Calibration | None = None, channel_map: ChannelMap | None = None):
        self.scene = scene
        self.dt = 1.0 / scene.sim_rate_hz
        self.run_key = tuple(int(x) for x in run)
        ctx = RunContext(self.dt, scene.seed, int(wearer.index), self.run_key)
        self.effects, stages = start_effects(scene.effects, ctx, getattr(wearer, 'effect_params', None))
        self._gaze_fx = [e.gaze for e in stages['gaze']]
        body = stages['body'][0] if stages['body'] else None

        ctl = scene.controller
        self.cmap = channel_map or package_channel_map()
        self.p_max = ctl.p_max_kpa
        self.timeout = ctl.gaze_timeout_s
        self.control_dt = 1.0 / ctl.control_rate_hz
        self.cond = condition_of(condition) if condition is not None else None
        self.layout = (self.cond.layout if self.cond is not None else 'suit') or 'suit'
        self._haptic = self.cond is None or self.cond.haptic     # calibration drives the suit too
        self.senses = Senses(stages, self._haptic, cue=self.cond is not None)
        self.wearer = SceneWearer(wearer.suit_laws, wearer.arm_laws, self.p_max, body)
        self.wearer.set_layout(self.layout)
        # hololens_view: the target is captured only once seen on the display and found among
        # the dummies; the key press counts only after confirm_s (key_ready_t).
        self.view = stages['view'][0] if stages['view'] else None
        self._track_seen = self.senses._cue_on
        self._central_hav = body.central_field_hav if body is not None else 0.0
        self._prev_torso = None

        self.controller: GuidanceController | None = None
        if self.cond is not None and self.cond.haptic:
            if calibration is None:
                raise ValueError(f'condition {self.cond.number} needs a calibration')
            self.controller = scene_controller(ctl, self.cond.mode, calibration)
        self.procedure: CalibrationProcedure | None = None

        # Clock: t = step * dt (never accumulated); control steps at k * control_dt.
        self.step_index = 0
        self.t = 0.0
        self._next_control = 0
        # The command the wearer's muscles receive, per direction (mean of its channels).
        self._cmd_key: tuple | None = None
        self.command = [0.0, 0.0, 0.0, 0.0]
        self.pressure = self.command          # what the suit exerts (after pressure effects)
        self.vented = True
        # Target state.
        self.target: tuple[float, float] | None = None     # yaw, pitch of the active target
        self.visible = False
        self.front_visible = False
        self.mode = 'front'                   # wearer: 'follow' the guidance, or 'front'
        self._g0: tuple[float, float] | None = None
        self._theta_t = (0.0, 0.0)            # target's signed (h, v) from g0, deg
        self.speech_due = False
        self.spoken: list[str] = []
        # Gaze stream: the controller's last sample (seq, t_emitted, yaw, pitch).
        self._seq = 0
        self.last_sample = (-1, 0.0, 0.0, 0.0)
        self.received_t = 0.0
        self.new_sample = False

    # ---- protocol interface -------------------------------------------------------------------
    @property
    def measured_yaw(self) -> float:
        return self.last_sample[2]

    @property
    def measured_pitch(self) -> float:
        return self.last_sample[3]

    @property
    def fresh(self) -> bool:
        return self.t - self.received_t <= self.timeout

    def warm_up(self, seconds: float = WARMUP_S) -> None:
        """Let the gaze stream run with the wearer at rest, facing front, no target."""
        end = self.step_index + int(round(seconds / self.dt))
        while self.step_index < end:
            self.step()

    def present(self, yaw: float, pitch: float, visible: bool) -> None:
        """A new active target at (yaw, pitch) from the front, degrees; the wearer follows the
        guidance. visible: the wearer can see it once it is in their central field."""
        self.target = (float(yaw), float(pitch))
        self.visible = bool(visible)
        self.mode = 'follow'
        self.wearer.acting = False
        self.senses.searching = self.visible
        if self.view is not None:
            proto = self.scene.protocol
            self.view.present(self.target if self.visible else None,
                              (proto.horizontal_deg, proto.vertical_deg))
            edge = self.view.edge_deg
            self.wearer.touch_limits = SEAT_LIMITS if edge is None or not self.visible else (
                min(proto.horizontal_deg + edge, YAW_LIMIT_DEG), min(proto.vertical_deg + edge, PITCH_LIMIT_DEG))
        self._vent()                           # the node vents on a new target
        self.speech_due = bool(self.cond is not None and self.cond.speech)

    def withdraw(self, front_visible: bool = True) -> None:
        """No active target: the suit vents and the wearer returns to the front on their own."""
        self.target = None
        self.speech_due = False
        self.senses.forget()
        self.mode = 'front'
        self.front_visible = front_visible
        self.wearer.go_front()
        self.wearer.touch_limits = SEAT_LIMITS
        if self.view is not None:
            self.view.present(None)
        self._vent()

    @property
    def key_ready_t(self) -> float:
        """The earliest time a key press on the active target counts: -inf without
        hololens_view, else confirm_s after the wearer found the target (inf before)."""
        return -math.inf if self.view is None else self.view.key_ready_t

    # ---- internals ----------------------------------------------------------------------------
    def _vent(self) -> None:
        if not self.vented:
            if self.controller is not None:
                self.controller.vent()
            self.vented = True
            self._g0 = None
        self._set_command((0.0, 0.0, 0.0, 0.0))

    def _set_command(self, direction_pressures: tuple) -> None:
        if direction_pressures == self._cmd_key:
            return
        self._cmd_key = direction_pressures
        cmap = self.cmap
        felt = cmap.to_directions(cmap.to_channels(direction_pressures, self.layout), self.layout)
        self.command = felt.tolist()

    def _guidance_gaze(self, t: float) -> tuple[float, float, bool] | None:
        """The part of a control step every guidance mode shares: speech when due, a vent when
        there is nothing to guide (None), else the gaze (yaw, pitch) and whether guidance to this
        target began now (g0 taken, every direction reset)."""
        fresh = t - self.received_t <= self.timeout
        if self.speech_due and fresh and self.target is not None:
            self._say(t)
        ctrl = self.controller
        if ctrl is None or self.target is None or not fresh:
            self._vent()
            return None
        _, _, gy, gp = self.last_sample
        began = self._g0 is None
        if began:
            ctrl.begin(gaze_from_angles(gy, gp))      # validates; resets every direction
            # g0 as GuidanceController.update takes it: the rest gaze (frame rest) or this gaze.
            self._g0 = yaw_pitch(ctrl.initial_gaze) if ctrl.frame == REST else (gy, gp)
            self.vented = False
        return gy, gp, began

    def _control(self, t: float) -> None:
        if self.procedure is not None:
            self._calibration_control(t, t - self.received_t <= self.timeout)
            return
        gaze = self._guidance_gaze(t)
        if gaze is None:
            return
        gy, gp, began = gaze
        ctrl = self.controller
        y0, p0 = self._g0
        if began:
            self._theta_t = (wrap_deg(self.target[0] - y0), self.target[1] - p0)
        self._set_command(step_directions(ctrl.directions, *self._theta_t, wrap_deg(gy - y0), gp - p0, t))

    def _say(self, t: float) -> None:
        self.speech_due = False
        _, _, gy, gp = self.last_sample
        text = phrase(wrap_deg(self.target[0] - gy), self.target[1] - gp)
        self.spoken.append(text)
        self.senses.say(t, text)

    def _calibration_control(self, t: float, fresh: bool) -> None:
        proc = self.procedure
        if not fresh and proc.phase not in (DONE, FAILED):
            proc.fail(f'the gaze stream stopped for more than {self.timeout} s')
        _, _, gy, gp = self.last_sample
        cmd = proc.tick(t, gaze_from_angles(gy, gp) if fresh else None)
        p = [0.0, 0.0, 0.0, 0.0]
        if cmd.direction is not None:
            p[DIRECTIONS.index(cmd.direction)] = cmd.pressure
        self._set_command(tuple(p))
        if cmd.phase == APPLY:
            if self.mode != 'follow':
                self.mode = 'follow'
        elif self.mode != 'front':
            self.mode = 'front'
            self.wearer.go_front()

    def step(self) -> None:
        """Advance one simulation step."""
        i = self.step_index
        t = i * self.dt
        self.t = t
        if t >= self._next_control * self.control_dt - 1e-9:
            self._next_control += 1
            self._control(t)
        # Command -> pressure the suit exerts -> what the wearer perceives (or hears).
        wearer = self.wearer
        follow = self.mode == 'follow'
        self.pressure = self.senses.step(t, self.command, wearer, follow)
        # The body moves; the eyes catch a visible target (or the front when returning).
        if follow:
            capture = self.target if self.visible else None
            if capture is not None and (self.view is not None or self._track_seen):
                gy, gp = wearer.torso_yaw + wearer.head_yaw, wearer.torso_pitch + wearer.head_pitch
                central = (self._central_hav > 0.0
                           and haversine(gy, gp, capture[0], capture[1]) <= self._central_hav)
                if self.view is not None:
                    still = False
                    prev = self._prev_torso
                    ty, tp = wearer.torso_yaw, wearer.torso_pitch
                    if prev is not None:
                        lim = self.view.still_dps * self.dt
                        still = (ty - prev[0]) ** 2 + (tp - prev[1]) ** 2 < lim * lim
                    self._prev_torso = (ty, tp)
                    if not self.view.update(t, gy, gp, central, still):
                        capture = None
                self.senses.seen = capture is not None and central
            elif self._track_seen:
                self.senses.seen = False
            wearer.move(capture)
        else:
            wearer.move(_FRONT if self.front_visible else None)
        # The gaze sample of the end of this step, through the gaze effects.
        i += 1
        self.step_index = i
        t = i * self.dt
        self.t = t
        self._seq = seq = self._seq + 1
        sample = (seq, t, wearer.torso_yaw + wearer.head_yaw, wearer.torso_pitch + wearer.head_pitch)
        for fx in self._gaze_fx:
            sample = fx(t, sample)
        if sample is not None and sample[0] > self.last_sample[0]:
            self.last_sample = sample
            self.received_t = t
            self.new_sample = True
        else:
            self.new_sample = False

    # ---- Algorithm 1 ----------------------------------------------------------------------------
    def calibrate(self, name: str) -> Calibration:
        """Run Algorithm 1 (core CalibrationProcedure) on this loop's wearer, with the scene's
        effects; the result, or CalibrationFitError with the reason."""
        cal = self.scene.calibration
        # Scenes keep every fit (their own min_r2 aside): the node's default refusal would
        # exclude 1 of 15 paper wearers (suit hysteresis: RMSE up to 39 kPa).
        self.procedure = CalibrationProcedure(name, p_max=self.p_max, steps=cal.steps, dwell_s=cal.dwell_s,
                                              rest_s=cal.rest_s, record_window_s=cal.window_s,
                                              min_r2=cal.min_r2, acceptance=ACCEPT_ALL)
        self.mode = 'front'
        self.front_visible = False
        limit = self.step_index + int(math.ceil((self.procedure.duration_s + 10.0) / self.dt))
        while self.procedure.phase not in (DONE, FAILED) and self.step_index < limit:
            self.step()
        proc, self.procedure = self.procedure, None
        self._set_command((0.0, 0.0, 0.0, 0.0))
        if proc.phase == FAILED:
            raise CalibrationFitError(proc.error)
        return proc.result()


def run_calibration(scene, wearer, name: str | None = None) -> Calibration:
    """Algorithm 1 on a simulated wearer with the scene's effects (or the wearer's true suit
    laws when the scene's calibration is `exact`). Raises CalibrationFitError with the reason
    when it fails."""
    name = name or getattr(wearer, 'name', f'wearer-{wearer.index}')
    if scene.calibration.exact:
        return Calibration.from_laws(name, wearer.suit_laws, scene.controller.p_max_kpa)
    loop = ClosedLoop(scene, wearer, CALIBRATION_RUN)
    loop.warm_up()
    return loop.calibrate(name)


__all__ = ['CALIBRATION_RUN', 'ClosedLoop', 'FastPowerLaw', 'scene_controller', 'yaw_pitch',
           'WARMUP_S', 'angle_between_deg', 'package_channel_map',
           'run_calibration', 'trial_run']
