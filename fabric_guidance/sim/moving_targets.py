"""Moving targets, in simulation: the second open point of the paper's Discussion.

Moving targets ("the proposed system cannot be directly applied to the directional guidance
of moving targets ... by developing an algorithm that adjusts the air pressure according to
the movement of the target"). A target starts where a speed-protocol target would (within
+-60 deg horizontally, +-30 deg vertically) and moves at a constant angular speed in a random
direction, measured in the paper's horizontal and vertical angles, reflected at the edges of
that range (it stays in the field of the experiment). Three laws, condition 1 (suit,
adjusted, the scene's G):

- paper:  Eq. 5 as the paper built it for static targets: theta_t is taken once, where the
          target was when guidance began, and the law runs on that.
- live:   Eq. 5 fed the moving target every control step without the shift
          (core.feedback follow_target=False): what the pressure_controller node does with
          follow_moving_target false. Here theta_t enters the increment and the sign of de/dt.
- follow: the same plus core.feedback's follow_target: a change of theta_t shifts the
          pressure by f(theta_t new) - f(theta_t old), so the feed-forward part follows the
          target.

The guidance runs for the whole trial (a tracking task, not the speed protocol's
find-and-return). Measured: the time until the tracked gaze has first stayed within the
protocol's acceptance angle of the (moving) target for its dwell, judged on each gaze sample
the controller receives as the target_selector node does (censored at the trial length when
never), and the tracking error, the angle between the true gaze and the target averaged over
every simulation step of the trial (and over its second half). Two scenarios: `seen` (the
target is visible: once in the central field the wearer's eyes catch it, as in the speed
protocol) and `unseen` (no visual capture: the suit alone guides, as in the accuracy
protocol).
"""
from __future__ import annotations

from dataclasses import dataclass
import math

from ..core.calibration import Calibration
from .node_loop import NodeLoop
from .protocols import draw_target
from .scene import Scene
from .study_trials import CONDITION, TrialKey
from .wearer import angle_between_deg, hav_limit, haversine

#: The moving-target laws compared (see the module docstring).
LAWS = ('paper', 'live', 'follow')
#: Scenarios of the moving-target study: the target visible (visual capture) or not.
SCENARIOS = ('seen', 'unseen')


def _fold(x: float, half: float) -> float:
    """x reflected into [-half, half] (a point bouncing between the walls)."""
    if half <= 0.0:
        return 0.0
    if -half <= x <= half:
        return x                    # exact inside: a static target stays where it was drawn
    y = math.fmod(x + half, 4.0 * half)
    if y < 0.0:
        y += 4.0 * half
    if y > 2.0 * half:
        y = 4.0 * half - y
    return y - half


@dataclass(frozen=True)
class TargetMotion:
    """A target starting at (yaw0, pitch0) moving at speed_dps in the direction heading_deg
    (0 = to the left, 90 = up) in the horizontal/vertical angles, reflected at +-half_h and
    +-half_v."""

    yaw0: float
    pitch0: float
    speed_dps: float
    heading_deg: float
    half_h: float
    half_v: float

    def at(self, s: float) -> tuple[float, float]:
        """Position s seconds after it appeared."""
        a = math.radians(self.heading_deg)
        d = self.speed_dps * s
        return (_fold(self.yaw0 + d * math.cos(a), self.half_h),
                _fold(self.pitch0 + d * math.sin(a), self.half_v))


def draw_motion(scene: Scene, subject: int, key: TrialKey, speed_dps: float) -> TargetMotion:
    """The moving target of a trial: start as a speed-protocol target, a uniform random
    heading; the same start and heading for every law and speed (common random numbers)."""
    rng = key.targets(scene, subject)
    yaw0, pitch0 = draw_target(rng, scene.protocol)
    heading = float(rng.uniform(0.0, 360.0))
    return TargetMotion(yaw0, pitch0, float(speed_dps), heading, scene.protocol.horizontal_deg,
                        scene.protocol.vertical_deg)


def moving_trial(scene: Scene, wearer, calibration: Calibration, law: str, speed_dps: float,
                 key: TrialKey, duration_s: float = 15.0, seen: bool = True) -> dict:
    """One moving-target trial under `law` (LAWS); the measures as a dict."""
    if law not in LAWS:
        raise ValueError(f'law must be one of {LAWS}, got {law!r}')
    proto = scene.protocol
    motion = draw_motion(scene, wearer.index, key, speed_dps)
    loop = NodeLoop(scene, wearer, key.run, CONDITION, calibration, follow_target=law == 'follow',
                    live_target=law != 'paper')
    loop.warm_up()
    w = loop.wearer
    t0 = loop.t
    loop.present(motion.yaw0, motion.pitch0, visible=seen)
    acc_hav, dwell = hav_limit(proto.acceptance_deg), proto.dwell_s
    n = int(round(duration_s / loop.dt))
    half = n // 2
    inside_since = None
    find_s = None
    errors = []
    for i in range(n):
        loop.step()
        # The world moves: from now on the eyes, the controller and the selector see it here.
        target = motion.at(loop.t - t0)
        loop.move_target(*target)
        errors.append(angle_between_deg(w.gaze_yaw, w.gaze_pitch, target[0], target[1]))
        if find_s is not None or not loop.new_sample:
            continue
        s = loop.last_sample
        if haversine(s[2], s[3], target[0], target[1]) > acc_hav:
            inside_since = None
            continue
        if inside_since is None:
            inside_since = loop.t
        if loop.t - inside_since >= dwell - 1e-9:
            find_s = loop.t - t0
    return dict(start_h_deg=motion.yaw0, start_v_deg=motion.pitch0, heading_deg=motion.heading_deg,
                found=find_s is not None,
                find_s=find_s if find_s is not None else float(duration_s),
                tracking_error_deg=math.fsum(errors) / len(errors),
                late_error_deg=math.fsum(errors[half:]) / len(errors[half:]))


__all__ = ['LAWS', 'SCENARIOS', 'TargetMotion', 'draw_motion', 'moving_trial']
