"""Beyond the paper, in simulation: the two open points of its Discussion.

1. Per-wearer adjustment gain ("the adjustment gain that maximized the adjustment effect
   differed among the subjects, and the performance of the proposed system may be further
   improved by adjusting the adjustment gain of each user"). Each simulated wearer is calibrated
   by Algorithm 1, then their own G is chosen on TUNING speed trials (condition 1, every G of a
   grid; the best mean of identified targets, ties broken by the shorter mean time to find,
   then by the G nearest the paper's 0.05) and stored in their calibration
   (core.calibration.Calibration.with_gain). EVALUATION speed trials, whose targets and random
   streams are disjoint from the tuning trials', then compare condition 1 with the paper's
   G = 0.05 and with the wearer's own G, as the pressure_controller node runs it with
   use_wearer_gain. The evaluation trials are the paper-speed protocol's own condition-1 trials
   (same target stream and run keys as protocols.speed_trial): the paper-G arm is exactly what
   `python -m fabric_guidance.sim.protocols paper-speed` records for condition 1. Every G of the
   grid is also run on the evaluation trials, which gives the oracle: the G that would have
   been best on the evaluation trials themselves (an optimistic upper bound, for reference).

2. Moving targets ("the proposed system cannot be directly applied to the directional guidance
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

All of it runs on ClosedLoop through BeyondLoop, a subclass that (a) builds the controller as
the node does, with the wearer's own gain when asked and follow_target, and (b) gives the
controller the target of the moment at every control step (move_target(): the node receives
the target's position on every message). With a static target, and with the paper's
defaults, BeyondLoop runs exactly as ClosedLoop (test_beyond checks both).

Random numbers: a trial is a pure function of (scene, wearer, phase, repetition, and its
settings); arms compared with each other share targets and effect streams (common random
numbers), so they differ only by the controller.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math
import multiprocessing
import time
from typing import Callable, Iterable, Sequence

import numpy as np

from ..core.calibration import Calibration
from ..core.feedback import PAPER_GAIN
from ..core.geometry import wrap_deg
from .effects import generator
from .engine import ClosedLoop, FastPowerLaw, package_channel_map, scene_controller, trial_run
from .population import calibrate_wearer, sample_wearer, subject_indices
from .protocols import draw_target, speed_loop, speed_measures, target_stream
from .scene import Scene
from .wearer import angle_between_deg, hav_limit, haversine

#: The G grid of the tuning: 0 to 0.5 in steps of 0.05 (the paper's 0.05 is on it).
GAIN_GRID: tuple[float, ...] = tuple(round(0.05 * i, 2) for i in range(11))
#: The condition the gain and the moving-target laws are studied in (suit, adjusted).
CONDITION = 1
#: The moving-target laws compared (see the module docstring).
LAWS = ('paper', 'live', 'follow')
#: Scenarios of the moving-target study: the target visible (visual capture) or not.
SCENARIOS = ('seen', 'unseen')

# Run-key stages of this module (engine.trial_run uses stage 2, engine.CALIBRATION_RUN stage 1).
_TUNING_STAGE = 11
_MOVING_STAGE = 12


# ---------------------------------------------------------------------------------------------
# The closed loop with the two options


class BeyondLoop(ClosedLoop):
    """ClosedLoop whose controller is built as the pressure_controller node builds it and is
    given the target of the moment at each control step.

    use_wearer_gain: G is the calibration's adjustment_gain when it has one (the node's
    use_wearer_gain), else the scene's. follow_target: core.feedback's follow_target (the node's
    follow_moving_target). live_target: the controller reads the current target (moved with
    move_target()) at every control step, as the node does; False is the engine's (and the
    paper's) law, theta_t taken once when guidance begins. Default: live exactly when
    follow_target.
    """

    def __init__(self, scene, wearer, run: Sequence[int], condition: int | None = None,
                 calibration: Calibration | None = None, *, use_wearer_gain: bool = False,
                 follow_target: bool = False, live_target: bool | None = None, channel_map=None):
        super().__init__(scene, wearer, run, condition, calibration, channel_map)
        self.follow_target = bool(follow_target)
        self.live_target = self.follow_target if live_target is None else bool(live_target)
        ctl = scene.controller
        self.gain = ctl.gain
        if use_wearer_gain and calibration is not None and calibration.adjustment_gain is not None:
            self.gain = calibration.adjustment_gain
        if self.controller is not None:
            # As ClosedLoop builds it (and as the node does), with the gain and the option.
            self.controller = scene_controller(ctl, self.cond.mode, calibration, self.gain,
                                               self.follow_target)

    def move_target(self, yaw: float, pitch: float) -> None:
        """The active target is now at (yaw, pitch): no vent, no new guidance (the node's
        on_target for the target it is already guiding to). The eyes see it there at once."""
        if self.target is None:
            raise RuntimeError('move_target() needs an active target: present() one first')
        self.target = (float(yaw), float(pitch))

    def _control(self, t: float) -> None:
        if not self.live_target or self.procedure is not None:
            super()._control(t)
            return
        gaze = self._guidance_gaze(t)
        if gaze is None:
            return
        gy, gp, _ = gaze
        y0, p0 = self._g0
        # GuidanceController.update's angles, from g0, with the target of this moment; every
        # direction is stepped (a direction whose theta_t is <= 0 resets, as in update()).
        ht = wrap_deg(self.target[0] - y0)
        vt = self.target[1] - p0
        self._theta_t = (ht, -ht, -vt, vt)
        h = wrap_deg(gy - y0)
        v = gp - p0
        d0, d1, d2, d3 = self.controller.directions
        self._set_command((d0.step(ht, h, t), d1.step(-ht, -h, t), d2.step(-vt, -v, t), d3.step(vt, v, t)))


# ---------------------------------------------------------------------------------------------
# Trial keys: what seeds a trial's targets and effect streams


@dataclass(frozen=True)
class TrialKey:
    """phase 'evaluation': the paper-speed protocol's own condition-1 trial of that repetition
    (protocols' target stream, engine.trial_run); 'tuning': a stream of its own and run stage
    11; 'moving': its own stream and stage 12."""

    phase: str
    repetition: int

    def __post_init__(self):
        if self.phase not in ('tuning', 'evaluation', 'moving'):
            raise ValueError(f'unknown phase {self.phase!r}')
        if not (isinstance(self.repetition, (int, np.integer)) and self.repetition >= 0):
            raise ValueError(f'repetition must be a whole number >= 0, got {self.repetition!r}')

    @property
    def run(self) -> tuple[int, ...]:
        if self.phase == 'evaluation':
            return trial_run(CONDITION, self.repetition)
        if self.phase == 'tuning':
            return (_TUNING_STAGE, CONDITION, int(self.repetition))
        return (_MOVING_STAGE, CONDITION, int(self.repetition))

    @property
    def target_stream(self) -> tuple[str, tuple[int, ...]]:
        """(stream name, key) of the targets generator (with the scene seed and the wearer)."""
        if self.phase == 'evaluation':
            return ('targets', (int(self.repetition),))          # protocols.target_stream
        return (f'beyond-{self.phase}-targets', (int(self.repetition),))

    def targets(self, scene: Scene, subject: int) -> np.random.Generator:
        if self.phase == 'evaluation':
            return target_stream(scene, subject, self.repetition)
        name, key = self.target_stream
        return generator(scene.seed, name, subject, key)


def tuning_keys(reps: int) -> list[TrialKey]:
    return [TrialKey('tuning', r) for r in range(reps)]


def evaluation_keys(reps: int) -> list[TrialKey]:
    return [TrialKey('evaluation', r) for r in range(reps)]


# ---------------------------------------------------------------------------------------------
# 1. Per-wearer gain


def speed_trial(scene: Scene, wearer, calibration: Calibration, key: TrialKey, gain: float | None = None) -> dict:
    """One speed trial (condition 1) as protocols.speed_trial runs it, with G = gain (None: the
    scene's) carried in the calibration and used as the node's use_wearer_gain does."""
    proto = scene.protocol
    if proto.kind != 'speed':
        raise ValueError(f'the gain study needs a speed scene, got {proto.kind!r}')
    cal = calibration.with_gain(gain) if gain is not None else calibration
    loop = BeyondLoop(scene, wearer, key.run, CONDITION, cal, use_wearer_gain=gain is not None)
    loop.warm_up()
    return speed_measures(speed_loop(loop, key.targets(scene, wearer.index), proto))


def gain_means(rows: Iterable[dict]) -> dict[float, tuple[float, float]]:
    """gain -> (mean identified, mean of the trials' mean time to find; inf when none found)."""
    by_gain: dict[float, list[dict]] = {}
    for r in rows:
        by_gain.setdefault(float(r['gain']), []).append(r)
    out = {}
    for g, rs in by_gain.items():
        ident = math.fsum(r['identified'] for r in rs) / len(rs)
        finds = [r['mean_find_s'] for r in rs if r['mean_find_s'] is not None]
        out[g] = (ident, math.fsum(finds) / len(finds) if finds else math.inf)
    return out


def choose_gain(means: dict[float, tuple[float, float]], paper_gain: float = PAPER_GAIN) -> float:
    """The best G: most identified targets, then the shorter time to find, then the G nearest
    the paper's, then the smaller."""
    if not means:
        raise ValueError('no gain to choose from')
    return min(means, key=lambda g: (-means[g][0], means[g][1], abs(g - paper_gain), g))


def tune_gain(scene: Scene, wearer, calibration: Calibration, grid: Sequence[float] = GAIN_GRID,
              reps: int = 4) -> tuple[float, list[dict]]:
    """The wearer's own G from `reps` tuning trials per G of the grid; (G, the trial rows)."""
    rows = run_gain_grid(scene, wearer, calibration, grid, tuning_keys(reps))
    return choose_gain(gain_means(rows), scene.controller.gain), rows


def run_gain_grid(scene: Scene, wearer, calibration: Calibration, grid: Sequence[float],
                  keys: Sequence[TrialKey]) -> list[dict]:
    rows = []
    for g in grid:
        for key in keys:
            rows.append(dict(subject=wearer.index, wearer=wearer.name, phase=key.phase, gain=float(g),
                             repetition=key.repetition, **speed_trial(scene, wearer, calibration, key, g)))
    return rows


# ---------------------------------------------------------------------------------------------
# 2. Moving targets


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
        return (_fold(self.yaw0 + d * math.cos(a), self.half_h), _fold(self.pitch0 + d * math.sin(a), self.half_v))


def draw_motion(scene: Scene, subject: int, key: TrialKey, speed_dps: float) -> TargetMotion:
    """The moving target of a trial: start as a speed-protocol target, a uniform random
    heading; the same start and heading for every law and speed (common random numbers)."""
    rng = key.targets(scene, subject)
    yaw0, pitch0 = draw_target(rng, scene.protocol)
    heading = float(rng.uniform(0.0, 360.0))
    return TargetMotion(yaw0, pitch0, float(speed_dps), heading, scene.protocol.horizontal_deg,
                        scene.protocol.vertical_deg)


def moving_trial(scene: Scene, wearer, calibration: Calibration, law: str, speed_dps: float, key: TrialKey,
                 duration_s: float = 15.0, seen: bool = True) -> dict:
    """One moving-target trial under `law` (LAWS); the measures as a dict."""
    if law not in LAWS:
        raise ValueError(f'law must be one of {LAWS}, got {law!r}')
    proto = scene.protocol
    motion = draw_motion(scene, wearer.index, key, speed_dps)
    loop = BeyondLoop(scene, wearer, key.run, CONDITION, calibration, follow_target=law == 'follow',
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
                found=find_s is not None, find_s=find_s if find_s is not None else float(duration_s),
                tracking_error_deg=math.fsum(errors) / len(errors),
                late_error_deg=math.fsum(errors[half:]) / len(errors[half:]))


# ---------------------------------------------------------------------------------------------
# The whole study


@dataclass(frozen=True)
class BeyondSettings:
    grid: tuple[float, ...] = GAIN_GRID
    tuning_reps: int = 4             # tuning speed trials per G
    evaluation_reps: int = 6         # the paper: six speed trials per condition
    speeds_dps: tuple[float, ...] = (5.0, 10.0, 20.0)
    moving_reps: int = 6
    moving_s: float = 15.0
    scenarios: tuple[str, ...] = SCENARIOS

    def __post_init__(self):
        if not self.grid or any(not (math.isfinite(g) and g >= 0) for g in self.grid):
            raise ValueError(f'grid must hold finite gains >= 0, got {self.grid}')
        for name in ('tuning_reps', 'evaluation_reps', 'moving_reps'):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 1):
                raise ValueError(f'{name} must be a whole number >= 1, got {v!r}')
        if not self.speeds_dps or any(not (math.isfinite(s) and s >= 0) for s in self.speeds_dps):
            raise ValueError(f'speeds_dps must hold finite speeds >= 0, got {self.speeds_dps}')
        if not (math.isfinite(self.moving_s) and self.moving_s > 0):
            raise ValueError(f'moving_s must be > 0, got {self.moving_s}')
        unknown = [s for s in self.scenarios if s not in SCENARIOS]
        if unknown or not self.scenarios:
            raise ValueError(f'scenarios must be a non-empty subset of {SCENARIOS}, got {self.scenarios}')


#: A short run for tests and a first look.
QUICK = BeyondSettings(grid=(0.0, 0.05, 0.2, 0.5), tuning_reps=2, evaluation_reps=2, speeds_dps=(10.0, 20.0),
                       moving_reps=2, moving_s=8.0)


@dataclass
class WearerResult:
    subject: int
    wearer: str
    error: str | None = None
    tuned_gain: float | None = None
    oracle_gain: float | None = None
    gain_rows: list = field(default_factory=list)      # tuning and evaluation grid trials
    moving_rows: list = field(default_factory=list)
    sim_s: float = 0.0


def run_wearer(scene: Scene, subject: int, settings: BeyondSettings = BeyondSettings()) -> WearerResult:
    """Calibrate one wearer by Algorithm 1, tune their G, run the evaluation grid and the
    moving-target trials. A pure function of (scene, subject, settings)."""
    package_channel_map()
    wearer = sample_wearer(scene, subject)
    outcome = calibrate_wearer(scene, wearer)
    res = WearerResult(subject, wearer.name)
    if not outcome.ok:
        res.error = outcome.error
        return res
    cal = outcome.calibration
    grid = tuple(settings.grid)
    if scene.controller.gain not in grid:
        grid = tuple(sorted(grid + (scene.controller.gain,)))
    trial_s = 1.0 + scene.protocol.trial_s
    res.tuned_gain, tuning = tune_gain(scene, wearer, cal, grid, settings.tuning_reps)
    evaluation = run_gain_grid(scene, wearer, cal, grid, evaluation_keys(settings.evaluation_reps))
    res.oracle_gain = choose_gain(gain_means(evaluation), scene.controller.gain)
    res.gain_rows = tuning + evaluation
    res.sim_s += trial_s * len(res.gain_rows)
    for scenario in settings.scenarios:
        for speed in settings.speeds_dps:
            for r in range(settings.moving_reps):
                key = TrialKey('moving', r)
                for law in LAWS:
                    m = moving_trial(scene, wearer, cal, law, speed, key, settings.moving_s, scenario == 'seen')
                    res.moving_rows.append(dict(subject=subject, wearer=wearer.name, scenario=scenario,
                                                speed_dps=float(speed), law=law, repetition=r, **m))
                    res.sim_s += 1.0 + settings.moving_s
    return res


def _job(args):
    scene, subject, settings = args
    return run_wearer(scene, subject, settings)


def _context():
    methods = multiprocessing.get_all_start_methods()
    return multiprocessing.get_context('fork' if 'fork' in methods else 'spawn')


@dataclass
class BeyondResults:
    scene: Scene
    settings: BeyondSettings
    wearers: list                # WearerResult, by subject
    wall_s: float = 0.0

    @property
    def included(self) -> list:
        return [w for w in self.wearers if w.error is None]

    @property
    def exclusions(self) -> list:
        return [(w.wearer, w.error) for w in self.wearers if w.error is not None]

    @property
    def sim_s(self) -> float:
        return sum(w.sim_s for w in self.wearers)

    def gain_grid_frame(self):
        """Every tuning and evaluation trial of the grid, one row per trial."""
        import pandas as pd
        return pd.DataFrame([r for w in self.included for r in w.gain_rows])

    def gain_choice_frame(self):
        """Per wearer: the tuned and oracle G and the evaluation means at the paper's, the own
        and the oracle G."""
        import pandas as pd
        paper = self.scene.controller.gain
        rows = []
        for w in self.included:
            tune = gain_means(r for r in w.gain_rows if r['phase'] == 'tuning')
            ev = gain_means(r for r in w.gain_rows if r['phase'] == 'evaluation')
            rows.append(dict(subject=w.subject, wearer=w.wearer, tuned_gain=w.tuned_gain, oracle_gain=w.oracle_gain,
                             tuning_identified_at_tuned=tune[w.tuned_gain][0],
                             tuning_identified_at_paper=tune[paper][0],
                             identified_paper_gain=ev[paper][0], identified_own_gain=ev[w.tuned_gain][0],
                             identified_oracle_gain=ev[w.oracle_gain][0]))
        return pd.DataFrame(rows)

    def gain_trials_frame(self, names: dict | None = None):
        """The evaluation trials of the compared arms, one row per trial: condition = the arm
        ('paper', 'own', 'oracle' or their names), for experiments.stats.analyze_trials."""
        import pandas as pd
        names = names or {'paper': 'paper', 'own': 'own', 'oracle': 'oracle'}
        paper = self.scene.controller.gain
        rows = []
        for w in self.included:
            ev = [r for r in w.gain_rows if r['phase'] == 'evaluation']
            for arm, g in (('paper', paper), ('own', w.tuned_gain), ('oracle', w.oracle_gain)):
                for r in ev:
                    if r['gain'] == g:
                        rows.append({**r, 'condition': names[arm]})
        return pd.DataFrame(rows)

    def moving_frame(self):
        import pandas as pd
        return pd.DataFrame([r for w in self.included for r in w.moving_rows])


def run_beyond(scene: Scene, subjects: Iterable[int] | int | None = None,
               settings: BeyondSettings = BeyondSettings(), workers: int = 2,
               progress: Callable[[int, int, int], None] | None = None) -> BeyondResults:
    """Both studies on the scene's wearers (all, the first n, or these indices), in parallel
    over wearers. Deterministic: the same for any number of workers."""
    if scene.protocol.kind != 'speed':
        raise ValueError(f'run_beyond needs a speed scene (paper-speed), got a {scene.protocol.kind} scene')
    if not isinstance(workers, int) or workers < 1:
        raise ValueError(f'workers must be a whole number >= 1, got {workers!r}')
    indices = subject_indices(scene, subjects)
    start = time.perf_counter()
    jobs = [(scene, i, settings) for i in indices]
    results: dict[int, WearerResult] = {}
    if workers == 1 or len(jobs) == 1:
        for done, job in enumerate(jobs, start=1):
            res = _job(job)
            results[res.subject] = res
            if progress is not None:
                progress(done, len(jobs), res.subject)
    else:
        with _context().Pool(min(workers, len(jobs))) as pool:
            for done, res in enumerate(pool.imap_unordered(_job, jobs), start=1):
                results[res.subject] = res
                if progress is not None:
                    progress(done, len(jobs), res.subject)
    return BeyondResults(scene, settings, [results[i] for i in indices], time.perf_counter() - start)


__all__ = ['BeyondLoop', 'BeyondResults', 'BeyondSettings', 'CONDITION', 'GAIN_GRID', 'LAWS', 'QUICK', 'SCENARIOS',
           'TargetMotion', 'TrialKey', 'WearerResult', 'choose_gain', 'draw_motion', 'evaluation_keys', 'gain_means',
           'moving_trial', 'run_beyond', 'run_gain_grid', 'run_wearer', 'speed_trial', 'tune_gain', 'tuning_keys']
