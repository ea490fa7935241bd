"""`fabric-guidance tradeoff --out DIR`: what accuracy costs in time, knob by knob.

Sweeps every knob of the package that buys accuracy with time, on the scene simulator
(fabric_guidance.sim: the paper's protocols on simulated wearers calibrated by Algorithm 1,
with the realistic effects of config/scenes/paper-accuracy.yaml and paper-speed.yaml), and
writes for each knob value the accuracy and the time it costs, with their spread:

  acceptance_tolerance  speed protocol: the true gaze error when a target counts (deg) against
                        the time to find a target (s, from its appearance to the count).
  gain                  Eq. 5's G. Accuracy protocol: guidance error (deg) against the time to
                        the key press (s); speed protocol: error when a target counts against
                        the time to find it.
  calibration_points    Algorithm 1's pressure steps per direction. The calibration time
                        (simulated seconds Algorithm 1 ran: about 4 x (rest + steps x dwell))
                        against the accuracy protocol's guidance error, and against the fitted
                        law's angle error versus the wearer's true law
                        (sim.population.law_angle_error_deg, per direction).
  control_rate          how often Eq. 5 runs (Hz). Accuracy protocol: guidance error against the
                        time to the key press. Eq. 5 adds G*(f(theta_t) - f(theta)) once per
                        control step, so the rate scales the law's effective gain per second
                        (G x rate); the grid stops at the scene's 60 Hz gaze rate, which the
                        scene files do not let the control rate exceed.
  fit_tolerance         the Levenberg-Marquardt fit's xtol = ftol (core.power_law.fit_power_law,
                        CalibrationProcedure's fit_tolerance). The points Algorithm 1 recorded
                        for each wearer at the scene's settings are refitted at each tolerance:
                        the fitted law's angle error (against the true law, and against the
                        fully converged fit) against the fit's measured wall time (ms per fit).

Guidance error of an accuracy trial: hypot of the horizontal and vertical absolute errors of the
true gaze at the key press (the paper reports the two separately). Spread: mean, SD (ddof 1),
10th and 90th percentiles over trials (accuracy protocol), found targets (speed protocol),
wearer x direction (calibration law) or fits. Every knob value runs on the same wearers and the
same targets (the simulator's common random numbers), so two values are compared on paired
samples where the samples pair up.

Outputs in DIR: tradeoff.csv (one row per knob value and curve: knob, value, accuracy_metric,
accuracy_mean/sd/p10/p90, time_metric, time_mean/sd/p10/p90, n (accuracy samples), n_time (time
samples), note: timeouts, targets found per trial, censored waits, excluded wearers, function
evaluations per fit), tradeoff.md (the table, a reading of each curve generated from the
numbers by the rules of read_curve(), the plots), <knob>.png (accuracy against time: mean, +-SD bars, p10-p90 shading, each point labelled with
its value, the Pareto front drawn). The markdown table is printed; progress goes to stderr,
one line per knob value.

Also runs alone: python -m fabric_guidance.experiments.tradeoff --out DIR [--quick]
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass, field, replace
import math
import multiprocessing
import os
from pathlib import Path
import sys
import time
from typing import Callable, Sequence

import numpy as np
import pandas as pd

from .. import subcommand
from ..core.feedback import RATE_THRESHOLD_DPS
from ..core.geometry import DIRECTIONS
from ..core.power_law import CalibrationFitError, fit_power_law
from ..sim.engine import CALIBRATION_RUN, ClosedLoop, package_channel_map, trial_run
from ..sim.population import CalibrationOutcome, law_angle_error_deg, law_error_kpa, sample_wearer
from ..sim.protocols import _targets, accuracy_trial, speed_loop
from ..sim.scene import AccuracyProtocol, Scene, SpeedProtocol, load_scene
from .report import image_path, md_table

PROG = 'fabric-guidance tradeoff'
HELP = 'sweep the knobs that buy accuracy with time; table, plots and a reading of the curves'

#: The scenes both the sweep and the sensitivity analysis run on by default: the one place to
#: switch them (e.g. to the fitted scenes).
DEFAULT_SPEED_SCENE = 'paper-fitted-speed'
DEFAULT_ACCURACY_SCENE = 'paper-fitted-accuracy'

KNOBS = ('acceptance_tolerance', 'gain', 'calibration_points', 'control_rate', 'rate_threshold',
         'fit_tolerance')
#: The paper's conditions drawn on the plane, at the package defaults.
PLANE_CONDITIONS = (1, 2, 3, 4)
CONDITION_LABELS = {1: '1 suit, adjusted', 2: '2 suit, fixed', 3: '3 arm band, adjusted',
                    4: '4 speech'}

DEFAULT_GRIDS = {
    'acceptance_tolerance': (2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0),
    'gain': (0.0, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5),
    'calibration_points': (3, 4, 5, 6, 8, 10, 12, 15, 20),
    'control_rate': (5.0, 10.0, 15.0, 20.0, 30.0, 45.0, 60.0),
    'rate_threshold': (3.0, 7.0, RATE_THRESHOLD_DPS, 30.0, 60.0, 120.0),
    'fit_tolerance': (1e-2, 1e-3, 1e-4, 1e-6, 1e-8, 1e-10, 1e-12),
}
QUICK_GRIDS = {
    'acceptance_tolerance': (2.0, 5.0, 10.0),
    'gain': (0.0, 0.05, 0.5),
    'calibration_points': (3, 10, 20),
    'control_rate': (5.0, 30.0, 60.0),
    'rate_threshold': (3.0, RATE_THRESHOLD_DPS, 60.0),
    'fit_tolerance': (1e-2, 1e-6, 1e-10),
}
#: The value the package runs with, and where it comes from.
REFERENCE = {'acceptance_tolerance': (5.0, 'the paper'), 'gain': (0.05, 'the paper'),
             'calibration_points': (10, 'the paper'), 'control_rate': (30.0, 'node default'),
             'rate_threshold': (RATE_THRESHOLD_DPS, 'core default'),
             'fit_tolerance': (1e-10, 'core default'),
             # not a knob: the plane's conditions have no package value to mark
             'condition': (math.nan, '')}
KNOB_TITLES = {'acceptance_tolerance': 'acceptance tolerance (deg)', 'gain': 'adjustment gain G (Eq. 5)',
               'calibration_points': 'calibration points per direction (Algorithm 1)',
               'control_rate': 'control rate (Hz)',
               'rate_threshold': 'rate threshold of the feedback law (deg/s)',
               'fit_tolerance': 'fit tolerance (LM xtol = ftol)',
               'condition': 'the paper\'s condition'}
KNOB_SYMBOLS = {'acceptance_tolerance': 'tolerance', 'gain': 'G', 'calibration_points': 'points',
                'control_rate': 'rate', 'rate_threshold': 'threshold', 'fit_tolerance': 'tol',
                'condition': 'condition'}
METRICS = {
    'guidance_error_deg': ('guidance error (deg, accuracy protocol)', 'deg'),
    'error_at_count_deg': ('gaze error when a target counts (deg, speed protocol)', 'deg'),
    'law_angle_error_deg': ('fitted law angle error vs true law (deg)', 'deg'),
    'fit_vs_converged_deg': ('fitted law angle error vs converged fit (deg)', 'deg'),
    'time_to_key_press_s': ('time to the key press (s)', 's'),
    'time_to_find_s': ('time to find a target (s)', 's'),
    'calibration_time_s': ('calibration time (s)', 's'),
    'fit_time_ms': ('fit wall time (ms per fit)', 'ms'),
}
CSV_COLUMNS = ('knob', 'value', 'accuracy_metric', 'accuracy_mean', 'accuracy_sd', 'accuracy_p10', 'accuracy_p90',
               'accuracy_se', 'time_metric', 'time_mean', 'time_sd', 'time_p10', 'time_p90',
               'time_se', 'n',
               'n_time', 'wearers', 'plane', 'note')
#: Changes below this fraction of the curve's level are called flat whatever the noise: too small
#: to matter (5 %).
FLAT_FRACTION = 0.05
#: On the front, accuracy still to gain below this fraction of the front's range counts as bought.
KNEE_FRACTION = 0.10


# ---------------------------------------------------------------------------------------------
# Settings


@dataclass(frozen=True)
class Settings:
    subjects: int = 10                  # the first N wearers of each scene's population
    repetitions: int = 10               # accuracy-protocol trials per wearer and value (the paper: 10)
    speed_repetitions: int = 3          # 40 s speed-protocol trials per wearer and value
    condition: int = 1                  # the paper's condition 1: suit, adjusted
    workers: int = 2
    accuracy_scene: str = DEFAULT_ACCURACY_SCENE
    speed_scene: str = DEFAULT_SPEED_SCENE
    knobs: tuple[str, ...] = KNOBS
    grids: dict = field(default_factory=lambda: dict(DEFAULT_GRIDS))
    fit_repeats: int = 15               # timed calls per fit and tolerance (the fastest is kept)
    trial_s: float | None = None        # speed trials' length; None: the scene's (the paper: 40 s)
    quick: bool = False
    plane: bool = True                  # run conditions 1-4 and both protocols per knob value


def quick_settings(**changes) -> Settings:
    """A tiny sweep (2 wearers, 3 values per knob, short trials) for tests and a first look."""
    base = dict(subjects=2, repetitions=2, speed_repetitions=1, grids=dict(QUICK_GRIDS), fit_repeats=3,
                trial_s=20.0, quick=True)
    base.update(changes)
    return Settings(**base)


def _as_protocol(scene: Scene, kind: str) -> Scene:
    """The scene with a protocol of `kind`: its own, or that protocol's defaults (the paper's)."""
    if scene.protocol.kind == kind:
        return scene
    return scene.replace(protocol=AccuracyProtocol() if kind == 'accuracy' else SpeedProtocol(),
                         repetitions=scene.repetitions)


def base_scenes(settings: Settings) -> tuple[Scene, Scene]:
    """(accuracy scene, speed scene) restricted to the sweep's condition and repetitions."""
    acc = _as_protocol(load_scene(settings.accuracy_scene), 'accuracy')
    spd = _as_protocol(load_scene(settings.speed_scene), 'speed')
    # The plane puts one protocol's time against the other's error: both run on the same
    # wearers (the speed scene's seed and population; common random numbers), which also lets
    # the two share every calibration when the scenes list the same effects.
    acc = acc.replace(seed=spd.seed, population=spd.population)
    acc = acc.replace(conditions=(settings.condition,), repetitions=settings.repetitions)
    spd = spd.replace(conditions=(settings.condition,), repetitions=settings.speed_repetitions)
    if settings.trial_s is not None:
        spd = spd.replace(protocol=replace(spd.protocol, trial_s=float(settings.trial_s)))
    for s in (acc, spd):
        if not 1 <= settings.subjects <= s.population.subjects:
            raise ValueError(f'--subjects must be within 1..{s.population.subjects} (scene {s.name}), '
                             f'got {settings.subjects}')
    return acc, spd


def check_settings(settings: Settings, acc: Scene) -> None:
    unknown = [k for k in settings.knobs if k not in KNOBS]
    if unknown or not settings.knobs:
        raise ValueError(f'unknown knob(s) {unknown}; valid: {", ".join(KNOBS)}')
    if settings.condition not in (1, 2, 3):
        raise ValueError(f'condition must be 1, 2 or 3 (a haptic condition), got {settings.condition}')
    for name, n in (('repetitions', settings.repetitions), ('speed repetitions', settings.speed_repetitions),
                    ('workers', settings.workers), ('fit repeats', settings.fit_repeats)):
        if not (isinstance(n, int) and n >= 1):
            raise ValueError(f'{name} must be a whole number >= 1, got {n!r}')
    g = settings.grids
    checks = {
        'acceptance_tolerance': lambda v: 0 < v <= 180, 'gain': lambda v: 0 <= v <= 10,
        'calibration_points': lambda v: float(v).is_integer() and 3 <= v <= 50,
        'control_rate': lambda v: 0 < v <= acc.sim_rate_hz, 'fit_tolerance': lambda v: 1e-15 < v < 1,
        'rate_threshold': lambda v: 0 < v <= 1000,
    }
    for k in settings.knobs:
        values = g.get(k, ())
        if not values:
            raise ValueError(f'knob {k}: empty grid')
        bad = [v for v in values if not (isinstance(v, (int, float)) and math.isfinite(v) and checks[k](v))]
        if bad:
            extra = f' (the control rate cannot exceed the scene\'s sim_rate_hz {acc.sim_rate_hz:g})' \
                if k == 'control_rate' else ''
            raise ValueError(f'knob {k}: values out of range: {bad}{extra}')


# ---------------------------------------------------------------------------------------------
# Simulation jobs (top level: they run in worker processes)


def calibration_key(scene: Scene) -> Scene:
    """What a wearer's calibration depends on: the scene without its protocol, conditions,
    repetitions and gain (Algorithm 1 runs without the feedback law)."""
    return scene.replace(name='calibration', protocol=AccuracyProtocol(), conditions=(1,), repetitions=1,
                         controller=replace(scene.controller, gain=0.0), source='<calibration>')


def calibrate_measured(scene: Scene, subject: int) -> tuple[CalibrationOutcome, float]:
    """Algorithm 1 on wearer `subject` as sim.engine.run_calibration runs it, with the
    simulated seconds it took (0 for an `exact` calibration)."""
    package_channel_map()
    wearer = sample_wearer(scene, subject)
    if wearer.error:
        return CalibrationOutcome(subject, wearer.name, None, wearer.error), math.nan
    if scene.calibration.exact:
        from ..core.calibration import Calibration
        cal, took = Calibration.from_laws(wearer.name, wearer.suit_laws, scene.controller.p_max_kpa), 0.0
    else:
        loop = ClosedLoop(scene, wearer, CALIBRATION_RUN)
        loop.warm_up()
        t0 = loop.t
        try:
            cal = loop.calibrate(wearer.name)
        except ValueError as exc:
            return CalibrationOutcome(subject, wearer.name, None, f'calibration failed: {exc}'), loop.t - t0
        took = loop.t - t0
    p_max = scene.controller.p_max_kpa
    kpa = {d: law_error_kpa(t, f) for d, t, f in zip(DIRECTIONS, wearer.suit_laws, cal.laws)}
    deg = {d: law_angle_error_deg(t, f, p_max) for d, t, f in zip(DIRECTIONS, wearer.suit_laws, cal.laws)}
    return CalibrationOutcome(subject, wearer.name, cal, None, kpa, deg), took


def speed_trial_detail(scene: Scene, wearer, calibration, cond: int, repetition: int) -> dict:
    """sim.protocols.speed_trial with its detail: for every target found the time to find it
    and the true and tracked gaze error when it counted, and how long the last target had
    waited when the trial ended unfound (None: it was found)."""
    loop = ClosedLoop(scene, wearer, trial_run(cond, repetition), cond, calibration)
    loop.warm_up()
    detail = speed_loop(loop, _targets(scene, wearer.index, repetition), scene.protocol)
    return dict(identified=len(detail['finds']), **detail)


def _calibration_job(args):
    scene, subject = args
    return subject, calibrate_measured(scene, subject)


def _trial_job(args):
    """All trials of one wearer at one knob value: a list of sample dicts."""
    scene, subject, calibration, kind = args
    package_channel_map()
    wearer = sample_wearer(scene, subject)
    cond = scene.conditions[0]
    out = []
    for rep in range(scene.repetitions):
        if kind == 'accuracy':
            r = accuracy_trial(scene, wearer, calibration, cond, rep)
            out.append(dict(subject=subject, rep=rep, error=math.hypot(r['h_error_deg'], r['v_error_deg']),
                            time=r['time_s'], timed_out=bool(r['timed_out'])))
        else:
            r = speed_trial_detail(scene, wearer, calibration, cond, rep)
            for i, (t_find, err, tracked) in enumerate(r['finds']):
                out.append(dict(subject=subject, rep=rep, find=i, error=err, tracked=tracked, time=t_find))
            out.append(dict(subject=subject, rep=rep, find=-1, identified=r['identified'],
                            presented=r['presented'], unfound_s=r['unfound_s']))
    return subject, out


class _Runner:
    """Runs jobs in a process pool (or in this process for one worker) and keeps every wearer's
    calibration per calibration setting, so a knob that does not change Algorithm 1 reuses it."""

    def __init__(self, workers: int, subjects: int):
        self.subjects = list(range(subjects))
        self.pool = None
        if workers > 1 and subjects > 1:
            methods = multiprocessing.get_all_start_methods()
            ctx = multiprocessing.get_context('fork' if 'fork' in methods else 'spawn')
            self.pool = ctx.Pool(min(workers, subjects))
        self.calibrations: dict[Scene, dict[int, tuple[CalibrationOutcome, float]]] = {}

    def map(self, fn, jobs):
        if self.pool is None:
            return [fn(j) for j in jobs]
        return self.pool.map(fn, jobs, chunksize=1)

    def close(self):
        if self.pool is not None:
            self.pool.close()
            self.pool.join()

    def calibrate(self, scene: Scene) -> dict[int, tuple[CalibrationOutcome, float]]:
        key = calibration_key(scene)
        if key not in self.calibrations:
            self.calibrations[key] = dict(self.map(_calibration_job, [(key, i) for i in self.subjects]))
        return self.calibrations[key]

    def trials(self, scene: Scene, kind: str, cals: dict | None = None
               ) -> tuple[list[dict], dict[int, tuple[CalibrationOutcome, float]]]:
        """Every wearer's trials of `kind` on `scene`, with Algorithm 1's calibrations of the
        scene, or `cals` (subject -> (outcome, seconds)) when given."""
        cals = self.calibrate(scene) if cals is None else cals
        jobs = [(scene, i, cals[i][0].calibration, kind) for i in self.subjects if cals[i][0].ok]
        samples = []
        for _, out in sorted(self.map(_trial_job, jobs), key=lambda x: x[0]):
            samples.extend(out)
        return samples, cals


# ---------------------------------------------------------------------------------------------
# Rows and curves


@dataclass
class Row:
    """One knob value on one curve: the accuracy and time samples (pandas Series indexed by a
    pairing key: the same key at two values is the same wearer, trial, direction...)."""

    knob: str
    value: float
    accuracy_metric: str
    time_metric: str
    accuracy: pd.Series
    time: pd.Series
    note: str = ''
    #: what makes the numbers of this value less than they seem (timeouts, censored waits,
    #: excluded wearers), short, for the reading
    caveat: str = ''
    #: a point of the one plane (time to find a target against guidance error)
    plane: bool = False

    @property
    def curve(self) -> tuple[str, str, str]:
        return self.knob, self.accuracy_metric, self.time_metric

    def stats(self, which: str) -> dict:
        s = (self.accuracy if which == 'accuracy' else self.time).to_numpy(float)
        n = int(s.size)
        if n == 0:
            return dict(mean=math.nan, sd=math.nan, p10=math.nan, p90=math.nan, n=0, se=math.nan)
        sd = float(np.std(s, ddof=1)) if n > 1 else 0.0
        return dict(mean=float(np.mean(s)), sd=sd, p10=float(np.percentile(s, 10)),
                    p90=float(np.percentile(s, 90)), n=n, se=sd / math.sqrt(n))

    def wearer_se(self, which: str) -> tuple[float, int]:
        """(SE of the mean over wearers, wearers): the SD of the per-wearer means over sqrt of
        their number. Trials of one wearer are not independent; wearers are."""
        s = self.accuracy if which == 'accuracy' else self.time
        if not len(s) or 'subject' not in (s.index.names or ()):
            return math.nan, 0
        means = s.groupby(level='subject').mean().to_numpy(float)
        if means.size < 2:
            return 0.0, int(means.size)
        return float(np.std(means, ddof=1) / math.sqrt(means.size)), int(means.size)

    def as_record(self) -> dict:
        a, t = self.stats('accuracy'), self.stats('time')
        a_se, wearers = self.wearer_se('accuracy')
        t_se, _ = self.wearer_se('time')
        return dict(knob=self.knob, value=self.value, accuracy_metric=self.accuracy_metric,
                    accuracy_mean=a['mean'], accuracy_sd=a['sd'], accuracy_p10=a['p10'], accuracy_p90=a['p90'],
                    accuracy_se=a_se, time_metric=self.time_metric, time_mean=t['mean'],
                    time_sd=t['sd'],
                    time_p10=t['p10'], time_p90=t['p90'], time_se=t_se, n=a['n'], n_time=t['n'],
                    wearers=wearers, plane=self.plane, note=self.note)


def _series(samples: Sequence[dict], value: str, keys: Sequence[str]) -> pd.Series:
    if not samples:
        return pd.Series([], dtype=float)
    index = pd.MultiIndex.from_tuples([tuple(s[k] for k in keys) for s in samples], names=list(keys))
    return pd.Series([float(s[value]) for s in samples], index=index, dtype=float)


def _exclusion_note(cals: dict) -> str:
    bad = [o for o, _ in cals.values() if not o.ok]
    if not bad:
        return ''
    reasons = sorted({(o.error or '').replace('calibration failed: ', '', 1).strip()[:120] for o in bad})
    return f'{len(bad)} of {len(cals)} wearers excluded (calibration failed: {"; ".join(reasons)})'


def _join(*parts: str) -> str:
    return '; '.join(p for p in parts if p)


def accuracy_rows(knob: str, value, samples: list[dict], cals: dict, timeout_s: float | None = None) -> Row:
    acc = _series(samples, 'error', ('subject', 'rep'))
    tim = _series(samples, 'time', ('subject', 'rep'))
    timed_out = sum(s['timed_out'] for s in samples)
    note = _join(f'{timed_out} of {len(samples)} trials timed out' if timed_out else '', _exclusion_note(cals))
    caveat = ''
    if samples and timed_out >= 0.05 * len(samples):
        caveat = (f'{100 * timed_out / len(samples):.0f} % of trials timed out (the wearer never settled; their time '
                  f'is the {timeout_s:g} s timeout)' if timeout_s else f'{timed_out} trials timed out')
    return Row(knob, value, 'guidance_error_deg', 'time_to_key_press_s', acc, tim, note,
               _join(caveat, _exclusion_caveat(cals)))


def _exclusion_caveat(cals: dict) -> str:
    bad = sum(1 for o, _ in cals.values() if not o.ok)
    return f'{bad} of {len(cals)} wearers excluded (calibration failed)' if bad else ''


def speed_row(knob: str, value, samples: list[dict], cals: dict) -> Row:
    finds = [s for s in samples if s['find'] >= 0]
    trials = [s for s in samples if s['find'] < 0]
    acc = _series(finds, 'error', ('subject', 'rep', 'find'))
    tim = _series(finds, 'time', ('subject', 'rep', 'find'))
    per_trial = np.mean([s['identified'] for s in trials]) if trials else 0.0
    # The wait of a target still unfound at the end of a trial is not a time to find (censored):
    # say so when it is longer than 90 % of the finds took, where leaving it out flatters the mean.
    p90 = np.percentile([s['time'] for s in finds], 90) if finds else 0.0
    long_waits = [s['unfound_s'] for s in trials if s['unfound_s'] is not None and s['unfound_s'] > p90]
    censored = caveat = ''
    if long_waits:
        censored = (f'{len(long_waits)} of {len(trials)} trials ended on a target unfound for longer than 90 % of '
                    f'the finds took (up to {max(long_waits):.1f} s; not in the times)')
    # A target the wearer is stuck on (waiting 5 times as long as a typical find) is a caveat.
    stuck = [w for w in long_waits if w > 5.0 * float(np.median([s['time'] for s in finds]))]
    if stuck:
        caveat = (f'{len(stuck)}/{len(trials)} trials ended stuck on a target for up to {max(stuck):.0f} s '
                  '(not in the times)')
    note = _join(f'{per_trial:.1f} targets found per trial', censored, _exclusion_note(cals))
    return Row(knob, value, 'error_at_count_deg', 'time_to_find_s', acc, tim, note,
               _join(caveat, _exclusion_caveat(cals)))


def plane_row(knob: str, value, acc_samples: list[dict], spd_samples: list[dict], cals: dict,
              note: str = '', timeout_s: float | None = None) -> Row:
    """A point of the plane: the accuracy protocol's guidance error at the key press against
    the speed protocol's time to find a target, on the same wearers."""
    guidance = accuracy_rows(knob, value, acc_samples, cals, timeout_s)
    speed = speed_row(knob, value, spd_samples, cals)
    return Row(knob, value, 'guidance_error_deg', 'time_to_find_s', guidance.accuracy, speed.time,
               _join(note, speed.note.split('; ')[0], guidance.note),
               _join(guidance.caveat, speed.caveat), plane=True)


def _wearer_time(cals: dict, keys: Sequence[str] = ('subject',)) -> pd.Series:
    ok = [(o.subject, took) for o, took in cals.values() if o.ok]
    return pd.Series([t for _, t in ok], index=pd.MultiIndex.from_tuples([(s,) for s, _ in ok], names=list(keys)),
                     dtype=float) if ok else pd.Series([], dtype=float)


def calibration_rows(value, samples: list[dict], cals: dict, timeout_s: float | None = None) -> list[Row]:
    guidance = accuracy_rows('calibration_points', value, samples, cals, timeout_s)
    guidance.time_metric = 'calibration_time_s'
    guidance.time = _wearer_time(cals)
    law = [dict(subject=o.subject, direction=d, error=o.angle_error_deg[d])
           for o, _ in cals.values() if o.ok for d in DIRECTIONS]
    law_row = Row('calibration_points', value, 'law_angle_error_deg', 'calibration_time_s',
                  _series(law, 'error', ('subject', 'direction')), _wearer_time(cals), _exclusion_note(cals),
                  _exclusion_caveat(cals))
    return [guidance, law_row]


def fit_tolerance_rows(grid: Sequence[float], cals: dict, scene: Scene, repeats: int) -> list[Row]:
    """Refit each wearer's recorded Algorithm 1 points at every tolerance: law errors and the
    measured wall time per fit (the fastest of `repeats` calls, tolerances interleaved: the
    least disturbed by other processes)."""
    p_max = scene.controller.p_max_kpa
    converged_tol = min(min(grid), 1e-12)
    fits = []   # (subject, direction, true law, angles, pressures, converged law)
    for o, _ in cals.values():
        if not o.ok:
            continue
        wearer = sample_wearer(scene, o.subject)
        for k, d in enumerate(DIRECTIONS):
            dc = o.calibration.directions[d]
            angles, pressures = np.array(dc.angles), np.array(dc.pressures)
            conv = fit_power_law(angles, pressures, p_max, xtol=converged_tol, ftol=converged_tol).law
            fits.append((o.subject, d, wearer.suit_laws[k], angles, pressures, conv))
    timings = {(tol, i): [] for tol in grid for i in range(len(fits))}
    results: dict[tuple, object] = {}
    for _ in range(repeats):
        for tol in grid:
            for i, (_, _, _, angles, pressures, _) in enumerate(fits):
                start = time.perf_counter()
                try:
                    report = fit_power_law(angles, pressures, p_max, xtol=tol, ftol=tol)
                except CalibrationFitError as exc:
                    report = exc
                timings[(tol, i)].append(time.perf_counter() - start)
                results[(tol, i)] = report
    rows = []
    for tol in grid:
        true_err, conv_err, ms, nfev = [], [], [], []
        failed = 0
        for i, (subject, d, true_law, _, _, conv) in enumerate(fits):
            report = results[(tol, i)]
            if isinstance(report, CalibrationFitError):
                failed += 1
                continue
            key = dict(subject=subject, direction=d)
            true_err.append(dict(key, error=law_angle_error_deg(true_law, report.law, p_max)))
            conv_err.append(dict(key, error=law_angle_error_deg(conv, report.law, p_max)))
            ms.append(dict(key, time=1e3 * float(np.min(timings[(tol, i)]))))
            nfev.append(report.nfev)
        note = _join(f'{np.mean(nfev):.1f} function evaluations per fit' if nfev else '',
                     f'{failed} fits failed' if failed else '', _exclusion_note(cals))
        keys = ('subject', 'direction')
        t = _series(ms, 'time', keys)
        rows.append(Row('fit_tolerance', tol, 'law_angle_error_deg', 'fit_time_ms', _series(true_err, 'error', keys),
                        t, note))
        rows.append(Row('fit_tolerance', tol, 'fit_vs_converged_deg', 'fit_time_ms', _series(conv_err, 'error', keys),
                        t, note))
    return rows


# ---------------------------------------------------------------------------------------------
# The sweep


def _fmt(x: float) -> str:
    if x is None or not math.isfinite(x):
        return 'n/a'
    if x != 0 and (abs(x) < 1e-3 or abs(x) >= 1e5):
        return f'{x:.2e}'
    return f'{x:.3g}'


def _summary(row: Row) -> str:
    a, t = row.stats('accuracy'), row.stats('time')
    au, tu = METRICS[row.accuracy_metric][1], METRICS[row.time_metric][1]
    short = row.accuracy_metric.replace('_deg', '').replace('_', ' ')
    tshort = row.time_metric.rsplit('_', 1)[0].replace('_', ' ')
    return (f'{short} {_fmt(a["mean"])} +- {_fmt(a["sd"])} {au}, {tshort} {_fmt(t["mean"])} +- {_fmt(t["sd"])} {tu} '
            f'(n={a["n"]})')


@dataclass
class SweepResult:
    settings: Settings
    rows: list[Row]
    wall_s: float
    knob_wall_s: dict
    scenes: tuple[Scene, Scene]
    readings: dict = field(default_factory=dict)

    def frame(self) -> pd.DataFrame:
        recs = [r.as_record() for r in self.rows if r.stats('accuracy')['n'] and r.stats('time')['n']]
        return pd.DataFrame(recs, columns=list(CSV_COLUMNS))

    def curves(self) -> dict[tuple[str, str, str], list[Row]]:
        out: dict = {}
        for r in self.rows:
            out.setdefault(r.curve, []).append(r)
        return out


def refit_calibrations(cals: dict, tol: float, p_max: float) -> dict:
    """Each wearer's calibration with every direction's law refitted from Algorithm 1's
    recorded points at xtol = ftol = tol (a wearer whose fit fails at tol is excluded)."""
    from dataclasses import replace as dc_replace
    out = {}
    for subject, (o, took) in cals.items():
        if not o.ok:
            out[subject] = (o, took)
            continue
        dirs = {}
        try:
            for d, dc in o.calibration.directions.items():
                law = fit_power_law(np.array(dc.angles), np.array(dc.pressures), p_max, xtol=tol,
                                    ftol=tol).law
                dirs[d] = dc_replace(dc, law=law)
        except CalibrationFitError as exc:
            out[subject] = (CalibrationOutcome(subject, o.wearer, None,
                                               f'calibration failed: refit at {tol:g}: '
                                               f'{exc}'), took)
            continue
        out[subject] = (dc_replace(o, calibration=dc_replace(o.calibration, directions=dirs)),
                        took)
    return out


def run_sweep(settings: Settings, progress: Callable[[str], None] | None = None) -> SweepResult:
    """Run every knob of settings.knobs over its grid, and (settings.plane) conditions 1-4 and
    the plane's point of every knob value; progress(line) once per knob value or condition."""
    say = progress or (lambda line: None)
    acc, spd = base_scenes(settings)
    check_settings(settings, acc)
    start = time.perf_counter()
    runner = _Runner(settings.workers, settings.subjects)
    rows: list[Row] = []
    knob_wall = {}
    timeout = acc.protocol.timeout_s
    try:
        if settings.plane:
            k_start = time.perf_counter()
            for i, cond in enumerate(PLANE_CONDITIONS, start=1):
                v_start = time.perf_counter()
                a_samples, cals = runner.trials(acc.replace(conditions=(cond,)), 'accuracy')
                s_samples, _ = runner.trials(spd.replace(conditions=(cond,)), 'speed')
                row = plane_row('condition', cond, a_samples, s_samples, cals,
                                CONDITION_LABELS[cond], timeout)
                rows.append(row)
                say(f'[condition {i}/{len(PLANE_CONDITIONS)}] {CONDITION_LABELS[cond]}: '
                    f'{_summary(row)} '
                    f'({time.perf_counter() - v_start:.1f} s)')
            knob_wall['condition'] = time.perf_counter() - k_start
        for knob in settings.knobs:
            k_start = time.perf_counter()
            grid = list(settings.grids[knob])
            if knob == 'fit_tolerance':
                v_start = time.perf_counter()
                cals = runner.calibrate(acc)
                new = fit_tolerance_rows(grid, cals, acc, settings.fit_repeats)
                rows += new
                per_value = (time.perf_counter() - v_start) / len(grid)
                for i, tol in enumerate(grid, start=1):
                    v_start = time.perf_counter()
                    r = [x for x in new if x.value == tol]
                    if settings.plane:
                        refit = refit_calibrations(cals, tol, acc.controller.p_max_kpa)
                        ms = r[0].stats('time')['mean']
                        pr = plane_row(knob, tol, runner.trials(acc, 'accuracy', refit)[0],
                                       runner.trials(spd, 'speed', refit)[0], refit,
                                       f'{_fmt(ms)} ms per fit', timeout)
                        rows.append(pr)
                        r.append(pr)
                    say(f'[{knob} {i}/{len(grid)}] {KNOB_SYMBOLS[knob]} = {tol:g}: '
                        + '; '.join(_summary(x) for x in r)
                        + f' ({per_value + time.perf_counter() - v_start:.1f} s)')
                knob_wall[knob] = time.perf_counter() - k_start
                continue
            for i, value in enumerate(grid, start=1):
                v_start = time.perf_counter()
                new: list[Row] = []
                a_samples = s_samples = None
                if knob == 'acceptance_tolerance':
                    scene = spd.replace(protocol=replace(spd.protocol, acceptance_deg=float(value)))
                    row = speed_row(knob, value, *runner.trials(scene, 'speed'))
                    # The accuracy protocol has no tolerance: on the plane, the error when a
                    # target counts stands in for the guidance error.
                    row.plane = settings.plane
                    new.append(row)
                elif knob in ('gain', 'rate_threshold'):
                    field_name = 'gain' if knob == 'gain' else 'rate_threshold_dps'
                    for base, kind in ((acc, 'accuracy'), (spd, 'speed')):
                        scene = base.replace(controller=replace(base.controller,
                                                                **{field_name: float(value)}))
                        samples, cals = runner.trials(scene, kind)
                        if kind == 'accuracy':
                            a_samples = samples
                            new.append(accuracy_rows(knob, value, samples, cals, timeout))
                        else:
                            s_samples = samples
                            new.append(speed_row(knob, value, samples, cals))
                elif knob == 'calibration_points':
                    scene = acc.replace(calibration=replace(acc.calibration, steps=int(value)))
                    a_samples, cals = runner.trials(scene, 'accuracy')
                    new += calibration_rows(int(value), a_samples, cals, timeout)
                    if settings.plane:
                        s_samples, _ = runner.trials(
                            spd.replace(calibration=replace(spd.calibration, steps=int(value))),
                            'speed')
                elif knob == 'control_rate':
                    scene = acc.replace(controller=replace(acc.controller, control_rate_hz=float(value)))
                    a_samples, cals = runner.trials(scene, 'accuracy')
                    row = accuracy_rows(knob, value, a_samples, cals, timeout)
                    row.note = _join(f'G x rate = {scene.controller.gain * float(value):.3g} per s', row.note)
                    new.append(row)
                    if settings.plane:
                        s_samples, _ = runner.trials(
                            spd.replace(controller=replace(spd.controller,
                                                           control_rate_hz=float(value))), 'speed')
                if settings.plane and a_samples is not None and s_samples is not None:
                    cost = ''
                    if knob == 'calibration_points':
                        cost = f'{_fmt(new[0].stats("time")["mean"])} s calibration'
                    new.append(plane_row(knob, value, a_samples, s_samples, cals, cost, timeout))
                rows += new
                say(f'[{knob} {i}/{len(grid)}] {KNOB_SYMBOLS[knob]} = {value:g}: '
                    + '; '.join(_summary(x) for x in new) + f' ({time.perf_counter() - v_start:.1f} s)')
            knob_wall[knob] = time.perf_counter() - k_start
    finally:
        runner.close()
    return SweepResult(settings, rows, time.perf_counter() - start, knob_wall, (acc, spd))


# ---------------------------------------------------------------------------------------------
# Reading the curves


def pareto_front(times: Sequence[float], accuracies: Sequence[float]) -> list[int]:
    """Indices of the points no other point dominates (lower is better on both axes: another
    point dominates when it is no slower and no less accurate, and better on one), by time."""
    pts = list(zip(times, accuracies))
    front = []
    for i, (t, a) in enumerate(pts):
        if not any(tj <= t and aj <= a and (tj < t or aj < a) for j, (tj, aj) in enumerate(pts) if j != i):
            front.append(i)
    return sorted(front, key=lambda i: (pts[i][0], pts[i][1]))


def diff_se(x: pd.Series, y: pd.Series) -> float:
    """Standard error of mean(x) - mean(y): paired on the common keys when at least 3 pair up
    (the same wearer, trial or direction at two knob values), else as independent samples."""
    common = x.index.intersection(y.index) if len(x) and len(y) else []
    if len(common) >= 3 and x.index.is_unique and y.index.is_unique:
        d = (x.loc[common] - y.loc[common]).to_numpy(float)
        return float(np.std(d, ddof=1) / math.sqrt(d.size))
    se = [float(np.std(s.to_numpy(float), ddof=1) / math.sqrt(len(s))) if len(s) > 1 else 0.0 for s in (x, y)]
    return math.hypot(*se)


def _value_text(knob: str, value) -> str:
    ref, source = REFERENCE[knob]
    text = f'{KNOB_SYMBOLS[knob]} = {value:.4g}'
    return text + (f' ({source})' if math.isclose(float(value), float(ref), rel_tol=1e-9) else '')


def _reference_phrase(knob: str) -> str:
    ref, source = REFERENCE[knob]
    owner = "The paper's value" if source == 'the paper' else f'The {source}'
    return f'{owner}, {KNOB_SYMBOLS[knob]} = {ref:g},'


def _flat_why(span: float, noise: float, means: list[float], unit: str) -> str:
    """Why a span counts as flat, in words."""
    if span <= noise:
        return f'{_fmt(span)} {unit}, within their noise (2 SE of the difference {_fmt(noise)} {unit})'
    level = abs(float(np.mean(means)))
    return (f'{_fmt(span)} {unit}, beyond 2 SE ({_fmt(noise)} {unit}) but under {FLAT_FRACTION:.0%} of their level '
            f'({_fmt(level)} {unit}): real but too small to matter')


def _span_is_flat(rows: list[Row], which: str, lo: int, hi: int, means: list[float]) -> tuple[bool, float, float]:
    span = abs(means[hi] - means[lo])
    series = [(r.accuracy if which == 'accuracy' else r.time) for r in rows]
    noise = 2.0 * diff_se(series[hi], series[lo])
    level = max(abs(float(np.mean(means))), 1e-12)
    return span <= max(noise, FLAT_FRACTION * level), span, noise


def read_curve(rows: list[Row]) -> str:
    """1-3 sentences on one curve, from its numbers alone (lower is better on both axes):

    1. what the curve spans: accuracy and time at the ends of the grid and the best accuracy;
    2. flat (the accuracy means span less than 2 SE of their paired difference, or 5 % of
       their level: the knob buys nothing that matters) or the Pareto front, and where more time
       stops buying accuracy: the fastest front point from which the most accurate front point
       is better by no more than 2 SE of their difference or 10 % of the front's accuracy range;
    3. noisy: when fewer than half of the neighbouring values differ by more than 2 SE; not
       monotone: when the differences beyond 2 SE change sign twice or more; and where the
       package's own value stands (on the front, dominated by which value, or, on a flat curve,
       what it costs against the fastest); and the caveats of single values (timeouts, targets
       never found, excluded wearers) that make their numbers less than they seem.
    """
    rows = [r for r in rows if r.stats('accuracy')['n'] and r.stats('time')['n']]
    if not rows:
        return 'No value produced a sample: nothing to read.'
    knob = rows[0].knob
    a_name, t_name = METRICS[rows[0].accuracy_metric][0], METRICS[rows[0].time_metric][0]
    au, tu = METRICS[rows[0].accuracy_metric][1], METRICS[rows[0].time_metric][1]
    a = [r.stats('accuracy')['mean'] for r in rows]
    t = [r.stats('time')['mean'] for r in rows]
    vals = [r.value for r in rows]
    best = int(np.argmin(a))
    worst = int(np.argmax(a))
    fastest, slowest = int(np.argmin(t)), int(np.argmax(t))
    pt = lambda i: f'{KNOB_SYMBOLS[knob]} = {vals[i]:g} ({_fmt(t[i])} {tu}, {_fmt(a[i])} {au})'  # noqa: E731
    s1 = (f'{a_name.capitalize()} goes from {_fmt(a[0])} {au} at {KNOB_SYMBOLS[knob]} = {vals[0]:g} to '
          f'{_fmt(a[-1])} {au} at {vals[-1]:g} (best {_fmt(a[best])} {au} at {vals[best]:g}), '
          'while the '
          f'{t_name.split(" (")[0]} goes from {_fmt(t[0])} to {_fmt(t[-1])} {tu}.')
    if len(rows) == 1:
        return s1
    a_flat, a_span, a_noise = _span_is_flat(rows, 'accuracy', best, worst, a)
    t_flat, t_span, t_noise = _span_is_flat(rows, 'time', fastest, slowest, t)
    front = pareto_front(t, a)
    if a_flat and t_flat:
        s2 = (f'Both accuracy and time are flat: the accuracy means span {_flat_why(a_span, a_noise, a, au)} and the '
              f'times {_flat_why(t_span, t_noise, t, tu)}, so this knob trades nothing that '
              'matters here.')
    elif a_flat:
        s2 = (f'Accuracy is flat: its means span {_flat_why(a_span, a_noise, a, au)}, so spending time on this knob '
              f'buys no accuracy that matters; the fastest value, {pt(fastest)}, is the one to '
              'pick.')
    elif t_flat:
        s2 = (f'Time is flat (the means span {_flat_why(t_span, t_noise, t, tu)}): accuracy comes free, '
              f'and {pt(best)} is the most accurate.')
    elif len(front) == 1:
        s2 = (f'{pt(front[0])} is both the fastest and the most accurate: nothing to trade, every other value '
              f'is dominated.')
    else:
        f_best = min(front, key=lambda i: a[i])
        f_range = a[front[0]] - a[f_best]
        knee = front[-1]
        for i in front:
            if a[i] - a[f_best] <= max(2.0 * diff_se(rows[i].accuracy, rows[f_best].accuracy),
                                       KNEE_FRACTION * f_range):
                knee = i
                break
        dominated = [i for i in range(len(rows)) if i not in front]
        s2 = (f'Pareto front (no other value both faster and more accurate): '
              f'{", ".join(pt(i) for i in front)}'
              + (f'; dominated: {", ".join(f"{vals[i]:g}" for i in dominated)}' if dominated else '') + '. ')
        if knee == front[-1]:
            s2 += (f'More time keeps buying accuracy up to the slowest front value, {KNOB_SYMBOLS[knob]} = '
                   f'{vals[knee]:g}.')
        else:
            gain = a[knee] - a[f_best]
            extra = t[front[-1]] - t[knee]
            s2 += (f'More time stops buying accuracy at {KNOB_SYMBOLS[knob]} = {vals[knee]:g}: the slower front '
                   f'values gain at most {_fmt(gain)} {au} (within 2 SE or {KNEE_FRACTION:.0%} '
                   'of the front\'s '
                   f'range) for up to {_fmt(extra)} {tu} more.')
    parts = []
    if not a_flat and len(rows) >= 3:
        diffs = [a[i + 1] - a[i] for i in range(len(rows) - 1)]
        real = [d for i, d in enumerate(diffs)
                if abs(d) > 2.0 * diff_se(rows[i + 1].accuracy, rows[i].accuracy)]
        reversals = sum(1 for d0, d1 in zip(real, real[1:]) if (d0 > 0) != (d1 > 0))
        rho = float(pd.Series([float(v) for v in vals]).corr(pd.Series(a), method='spearman'))
        if len(real) < len(diffs) / 2:
            parts.append(f'Noisy: only {len(real)} of {len(diffs)} neighbouring values differ by more than 2 SE, '
                         f'so read the trend (Spearman rho of value and accuracy {rho:+.2f}), '
                         'not the order of '
                         f'neighbours.')
        elif reversals >= 2:
            parts.append(f'Not monotone: along the grid the accuracy turns between better and worse {reversals} '
                         'times by more than 2 SE (Spearman rho of value and accuracy '
                         f'{rho:+.2f}), so it depends on '
                         f'this knob through something other than "more is better".')
    ref, source = REFERENCE[knob]
    ref_i = [i for i, v in enumerate(vals) if math.isclose(float(v), float(ref), rel_tol=1e-9)]
    if ref_i and not (a_flat and t_flat):
        i = ref_i[0]
        if a_flat:
            if i != fastest:
                parts.append(f'{_reference_phrase(knob)} costs {_fmt(t[i])} {tu} against {_fmt(t[fastest])} {tu} '
                             f'for the fastest.')
        elif i in front:
            parts.append(f'{_reference_phrase(knob)} is on the front.')
        else:
            by = [j for j in front if t[j] <= t[i] and a[j] <= a[i]]
            parts.append(f'{_reference_phrase(knob)} is dominated by '
                         f'{", ".join(f"{KNOB_SYMBOLS[knob]} = {vals[j]:g}" for j in by)}.')
    caveats = [f'{KNOB_SYMBOLS[knob]} = {r.value:g}: {r.caveat}' for r in rows if r.caveat]
    if caveats:
        parts.append('Caveats: ' + '; '.join(caveats) + '.')
    return ' '.join([s1, s2] + parts)


def gain_rate_reading(result: SweepResult) -> str:
    """Eq. 5 adds G*(...) once per control step, so G x rate is the law's gain per second: where
    the gain and control-rate sweeps hit the same product, compare them (from the numbers)."""
    acc = result.scenes[0]
    g0, r0 = acc.controller.gain, acc.controller.control_rate_hz
    text = (f'Eq. 5 adds G*(f(theta_t) - f(theta)) once per control step, so the rate changes the law\'s effective '
            f'gain per second, G x rate ({g0:g} x {r0:g} Hz = {g0 * r0:g}/s in the scene).')
    curves = result.curves()
    gains = curves.get(('gain', 'guidance_error_deg', 'time_to_key_press_s'), [])
    rates = curves.get(('control_rate', 'guidance_error_deg', 'time_to_key_press_s'), [])
    pairs = [(g, r) for g in gains for r in rates
             if math.isclose(g.value * r0, g0 * r.value, rel_tol=1e-9)
             and not (math.isclose(g.value, g0) and math.isclose(r.value, r0))
             and g.stats('accuracy')['n'] and r.stats('accuracy')['n']]
    for g, r in pairs:
        ga, ra, gt, rt = g.stats('accuracy'), r.stats('accuracy'), g.stats('time'), r.stats('time')
        noise = 2.0 * diff_se(g.accuracy, r.accuracy)
        same = abs(ga['mean'] - ra['mean']) <= noise
        text += (f' At the same product {g.value * r0:g}/s, G = {g.value:g} at {r0:g} Hz gives {_fmt(ga["mean"])} deg '
                 f'in {_fmt(gt["mean"])} s and G = {g0:g} at {r.value:g} Hz {_fmt(ra["mean"])} '
                 'deg in '
                 f'{_fmt(rt["mean"])} s: the errors '
                 + (f'agree within 2 SE ({_fmt(noise)} deg), so rate and G act as one knob.' if same else
                    f'differ by more than 2 SE ({_fmt(noise)} deg): G x rate does not explain it '
                    'all.'))
    if not pairs:
        text += ' No value of the two grids gives the same product, so the sweeps cannot be compared point to point.'
    return text


# ---------------------------------------------------------------------------------------------
# Output


def plot_knob(curves: list[list[Row]], path: Path, dpi: int = 120) -> Path:
    """One panel per curve of a knob: accuracy (y) against time (x), means with +-SD bars, the
    p10-p90 box shaded, each point labelled with its value, the Pareto front dashed."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    fig = Figure(figsize=(6.4 * len(curves), 5.0), layout='constrained')
    canvas = FigureCanvasAgg(fig)
    labels = []     # (axes, knob, rows, x, y): placed once the layout is final
    for k, rows in enumerate(curves):
        rows = [r for r in rows if r.stats('accuracy')['n'] and r.stats('time')['n']]
        ax = fig.add_subplot(1, len(curves), k + 1)
        if not rows:
            ax.text(0.5, 0.5, 'no samples', ha='center', va='center', transform=ax.transAxes)
            continue
        knob = rows[0].knob
        A = [r.stats('accuracy') for r in rows]
        T = [r.stats('time') for r in rows]
        x = np.array([s['mean'] for s in T])
        y = np.array([s['mean'] for s in A])
        colour = f'C{k}'
        for s_t, s_a in zip(T, A):
            w, h = s_t['p90'] - s_t['p10'], s_a['p90'] - s_a['p10']
            if w > 0:
                ax.add_patch(Rectangle((s_t['p10'], s_a['p10']), w, h, color=colour, alpha=0.10, lw=0))
            else:
                ax.vlines(s_t['p10'], s_a['p10'], s_a['p90'], color=colour, alpha=0.25, lw=8)
        ax.plot(x, y, color='0.6', lw=0.8, zorder=2)
        ax.errorbar(x, y, xerr=[s['sd'] for s in T], yerr=[s['sd'] for s in A], fmt='none', ecolor=colour,
                    elinewidth=1.2, capsize=3, zorder=3)
        front = pareto_front(list(x), list(y))
        dom = [i for i in range(len(rows)) if i not in front]
        ax.scatter(x[front], y[front], s=42, color=colour, edgecolor='black', zorder=5, label='Pareto front')
        if dom:
            ax.scatter(x[dom], y[dom], s=42, facecolor='white', edgecolor=colour, linewidth=1.5, zorder=5,
                       label='dominated')
        ax.plot(x[front], y[front], color='black', ls='--', lw=1.0, zorder=4)
        labels.append((ax, knob, rows, x, y))
        ax.errorbar([], [], xerr=[], yerr=[], fmt='none', ecolor=colour, capsize=3, label='mean +- SD')
        ax.add_patch(Rectangle((0, 0), 0, 0, color=colour, alpha=0.2, lw=0, label='p10-p90'))
        if x.min() > 0 and x.max() / x.min() > 30:
            ax.set_xscale('log')
        if y.min() > 0 and y.max() / y.min() > 100:      # errors over orders of magnitude
            ax.set_yscale('log')
        ax.set_xlabel(METRICS[rows[0].time_metric][0])
        ax.set_ylabel(METRICS[rows[0].accuracy_metric][0])
        ax.set_title(f'{KNOB_TITLES[knob]}\n{METRICS[rows[0].accuracy_metric][0]}', fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc='best', framealpha=0.8)
    canvas.draw()
    renderer = canvas.get_renderer()
    for ax, knob, rows, x, y in labels:
        _label_points(ax, renderer, knob, rows, x, y)
    path = Path(path)
    fig.savefig(path, dpi=dpi, format='png')
    return path


def _label_points(ax, renderer, knob: str, rows: list[Row], x, y) -> None:
    """Each point's value, without overprinting: values at (nearly) the same place share one
    label ('G = 0, 0.01, 0.02'), and labels go where they overlap no other (_place_labels);
    a value that finds no place is named in a note in the corner."""
    pix = ax.transData.transform(np.column_stack([x, y]))
    groups: list[list[int]] = []
    for i in range(len(rows)):
        for g in groups:
            if np.hypot(*(pix[g[0]] - pix[i])) < 4.0:
                g.append(i)
                break
        else:
            groups.append([i])
    items = []
    for g in groups:
        text = _value_text(knob, rows[g[0]].value)
        if len(g) > 1:
            ref, source = REFERENCE[knob]
            values = ', '.join(f'{rows[i].value:.4g}' for i in g)
            text = f'{KNOB_SYMBOLS[knob]} = {values}'
            if any(math.isclose(float(rows[i].value), float(ref), rel_tol=1e-9) for i in g):
                text += f' ({source}: {ref:.4g})'
        items.append((x[g[0]], y[g[0]], text, 'black'))
    boxes = [ax.get_legend().get_window_extent(renderer)] if ax.get_legend() else []
    dropped = _place_labels(ax, renderer, items, boxes)
    if dropped:
        ax.text(0.01, 0.01, 'not labelled (no room): ' + '; '.join(dropped),
                transform=ax.transAxes, fontsize=7, va='bottom', ha='left', color='0.3')


def _is_plane_only(curve: tuple[str, str, str]) -> bool:
    """A curve that exists only for the plane (one protocol's error, the other's time)."""
    return curve[1] == 'guidance_error_deg' and curve[2] == 'time_to_find_s'


def plane_curves(result: 'SweepResult') -> dict[str, list[Row]]:
    """knob (or 'condition') -> its rows on the plane, in grid order."""
    out: dict[str, list[Row]] = {}
    for r in result.rows:
        if r.plane and r.stats('accuracy')['n'] and r.stats('time')['n']:
            out.setdefault(r.knob, []).append(r)
    return out


def _place_labels(ax, renderer, items, placed=None):
    """Annotate (x, y, text, colour) items at the first of a few offsets whose box overlaps no
    label placed before (greedy); a label that fits nowhere is left out (the legend names it)."""
    placed = [] if placed is None else placed
    offsets = [(7, 5, 'left', 'bottom'), (7, -5, 'left', 'top'), (-7, 5, 'right', 'bottom'),
               (-7, -5, 'right', 'top'), (0, 10, 'center', 'bottom'), (0, -10, 'center', 'top'),
               (14, 14, 'left', 'bottom'), (-14, -14, 'right', 'top'), (14, -16, 'left', 'top'),
               (-14, 16, 'right', 'bottom')]
    dropped = []
    for x, y, text, colour in items:
        for dx, dy, ha, va in offsets:
            ann = ax.annotate(text, (x, y), textcoords='offset points', xytext=(dx, dy), ha=ha,
                              va=va,
                              fontsize=7.5, color=colour, zorder=8,
                              bbox=dict(boxstyle='round,pad=0.15', fc='white', ec='none',
                                        alpha=0.8))
            box = ann.get_window_extent(renderer).padded(4.0)   # the label's white box and a gap
            inside = ax.get_window_extent(renderer).contains(box.x0, box.y0) and \
                ax.get_window_extent(renderer).contains(box.x1, box.y1)
            if inside and not any(box.overlaps(b) for b in placed):
                placed.append(box)
                break
            ann.remove()
        else:
            dropped.append(text)
    return dropped


def plot_plane(result: 'SweepResult', path: Path, dpi: int = 130) -> Path:
    """The one plane: x = mean time to find a target (speed protocol, s), y = guidance error
    at the key press (accuracy protocol, deg; acceptance tolerance: the error when a target
    counts). Conditions 1-4 at the package defaults, one polyline per knob through its values
    in the sweep's condition; whiskers +-1 SE over wearer means. Left: the whole plane; right:
    the same axes zoomed on the knobs other than the tolerance (they crowd round the condition
    point), where their end values are labelled."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.patches import Rectangle
    from matplotlib.transforms import Bbox

    curves = plane_curves(result)
    cond = result.settings.condition
    fig = Figure(figsize=(14.0, 8.6), layout='constrained')
    canvas = FigureCanvasAgg(fig)
    whole, zoom = fig.subplots(1, 2, width_ratios=(1.0, 1.0))

    def stats(rows):
        t = np.array([r.stats('time')['mean'] for r in rows])
        a = np.array([r.stats('accuracy')['mean'] for r in rows])
        tse = np.nan_to_num([r.wearer_se('time')[0] for r in rows])
        ase = np.nan_to_num([r.wearer_se('accuracy')[0] for r in rows])
        return t, a, tse, ase

    knobs = [k for k in KNOBS if k in curves]
    colours = {k: f'C{i}' for i, k in enumerate(knobs)}
    markers = {1: 'o', 2: 's', 3: '^', 4: 'D'}
    handles, labels = [], []
    for knob in knobs:
        style = ':' if knob == 'acceptance_tolerance' else '-'
        rows = curves[knob]
        ref, _ = REFERENCE[knob]
        label = (f'{KNOB_TITLES[knob]}: {rows[0].value:g} to {rows[-1].value:g} '
                 f'(package {ref:.3g})')
        if knob == 'acceptance_tolerance':
            label += ';\n   y = error when a target counts (speed protocol)'
        elif knob in ('calibration_points', 'fit_tolerance'):
            label += ';\n   own cost (calibration time / fit wall time) in the labels'
        handles.append(Line2D([], [], color=colours[knob], ls=style, marker='.', lw=1.6))
        labels.append(label)
    cond_rows = sorted(curves.get('condition', []), key=lambda r: r.value)
    for row in cond_rows:
        c = int(row.value)
        handles.insert(len(handles) - len(knobs),
                       Line2D([], [], ls='none', marker=markers.get(c, 'o'), ms=9, mec='black',
                              mfc='0.2' if c == cond else 'white'))
        labels.insert(len(labels) - len(knobs), f'condition {CONDITION_LABELS[c]}'
                      + (' (the knobs are swept here)' if c == cond else ''))

    for ax in (whole, zoom):
        for knob in knobs:
            x, y, xe, ye = stats(curves[knob])
            style = ':' if knob == 'acceptance_tolerance' else '-'
            ax.errorbar(x, y, xerr=xe, yerr=ye, fmt='none', ecolor=colours[knob], elinewidth=1.0,
                        capsize=2,
                        alpha=0.7, zorder=3)
            ax.plot(x, y, style, color=colours[knob], lw=1.6, marker='.', ms=7, zorder=4)
        # the sweep's own condition last and smaller: another at the same point stays visible
        for row in sorted(cond_rows, key=lambda r: int(r.value) == cond):
            c = int(row.value)
            x, y, xe, ye = stats([row])
            ax.errorbar(x, y, xerr=xe, yerr=ye, fmt='none', ecolor='black', elinewidth=1.2,
                        capsize=3, zorder=5)
            ax.scatter(x, y, s=60 if c == cond else 130, marker=markers.get(c, 'o'),
                       facecolor='0.2' if c == cond else 'white', edgecolor='black', linewidth=1.6,
                       zorder=7 if c == cond else 6)
        ax.set_xlabel('mean time to find a target (s, speed protocol)')
        ax.set_ylabel('guidance error at the key press (deg, accuracy protocol; hypot of h and v)')
        ax.grid(alpha=0.3, which='both')
    xs = np.concatenate([stats(v)[0] for v in curves.values()]) if curves else np.array([])
    ys = np.concatenate([stats(v)[1] for v in curves.values()]) if curves else np.array([])
    if xs.size and xs.min() > 0 and xs.max() / xs.min() > 4:
        whole.set_xscale('log')
    if ys.size and ys.min() > 0 and ys.max() / ys.min() > 30:
        whole.set_yscale('log')
    # the zoom: every knob but the tolerance, and the sweep's condition, with their whiskers
    near = [r for k in knobs if k != 'acceptance_tolerance' for r in curves[k]] + \
        [r for r in cond_rows if int(r.value) == cond]
    if near:
        x, y, xe, ye = stats(near)
        x0, x1, y0, y1 = (x - xe).min(), (x + xe).max(), (y - ye).min(), (y + ye).max()
        mx, my = 0.12 * ((x1 - x0) or 0.1), 0.12 * ((y1 - y0) or 0.1)
        zoom.set_xlim(x0 - mx, x1 + mx)
        zoom.set_ylim(y0 - my, y1 + my)
        whole.add_patch(Rectangle((x0 - mx, y0 - my), x1 - x0 + 2 * mx, y1 - y0 + 2 * my,
                                  fill=False,
                                  ec='0.4', ls='--', lw=0.8, zorder=2))
    s = result.settings
    whole.set_title('the whole plane (dashed box: the zoom on the right)', fontsize=10)
    zoom.set_title(f'zoom: the knobs swept in condition {cond} '
                   '(package values at the filled point)',
                   fontsize=10)
    fig.suptitle('What accuracy costs in time: conditions 1-4 at the package defaults and '
                 'every knob; '
                 f'{s.subjects} wearers, whiskers +-1 SE over wearer means; lower and to the '
                 'left is better',
                 fontsize=11)
    fig.legend(handles, labels, loc='outside lower center', ncol=2, fontsize=8.5, frameon=False)
    canvas.draw()
    renderer = canvas.get_renderer()

    def obstacles(ax, rows):
        out = []
        for row in rows:
            cx, cy = ax.transData.transform((row.stats('time')['mean'],
                                             row.stats('accuracy')['mean']))
            out.append(Bbox([[cx - 9, cy - 9], [cx + 9, cy + 9]]))
        return out

    tol = curves.get('acceptance_tolerance', [])
    if tol:
        x, y, _, _ = stats(tol)
        idx = sorted({0, len(tol) - 1} | {i for i, r in enumerate(tol)
                                           if math.isclose(float(r.value),
                                                           REFERENCE['acceptance_tolerance'][0])})
        items = [(x[i], y[i], f'tolerance {tol[i].value:g}'
                  + (' (package)' if i not in (0, len(tol) - 1) else ''),
                  colours['acceptance_tolerance'])
                 for i in idx]
        _place_labels(whole, renderer, items, obstacles(whole, cond_rows))
    items = []
    for knob in knobs:
        if knob == 'acceptance_tolerance':
            continue
        rows = curves[knob]
        x, y, _, _ = stats(rows)
        for i in sorted({0, len(rows) - 1}):
            text = f'{KNOB_SYMBOLS[knob]} {rows[i].value:g}'
            if knob in ('calibration_points', 'fit_tolerance'):
                text += f' ({rows[i].note.split("; ")[0]})'
            items.append((x[i], y[i], text, colours[knob]))
    _place_labels(zoom, renderer, items, obstacles(zoom,
                                                   [r for r in cond_rows if int(r.value) == cond]))
    path = Path(path)
    fig.savefig(path, dpi=dpi, format='png')
    return path


def plane_text(result: 'SweepResult') -> str:
    s = result.settings
    return ('x: the mean time to find a target in the speed protocol (s, found targets only); '
            'y: the guidance error of the true gaze at the accuracy protocol\'s key press (deg, '
            'hypot of h and v), before any visual capture. Acceptance tolerance, which the '
            'accuracy protocol does not use, has y = the error when a target counts (speed '
            'protocol). Conditions 1-4 at the package defaults; every knob swept in condition '
            f'{s.condition}, both protocols on the same {s.subjects} wearers (common random '
            'numbers). Spread: +-1 SE over wearer means (the columns SE). The package value of '
            f'each knob other than the tolerance is the condition-{s.condition} point itself.')


def plane_table(result: 'SweepResult') -> str:
    header = ['knob', 'value', 'y metric', 'y mean', 'y SE', 'time to find (s)', 'time SE',
              'wearers', 'note']
    rows = []
    curves = plane_curves(result)
    for knob in ('condition',) + tuple(k for k in KNOBS if k in curves):
        for r in curves.get(knob, []):
            rec = r.as_record()
            value = CONDITION_LABELS.get(int(r.value),
                                         f'{r.value:g}') if knob == 'condition' else f'{r.value:g}'
            rows.append([knob, value, r.accuracy_metric, _fmt(rec['accuracy_mean']),
                         _fmt(rec['accuracy_se']),
                         _fmt(rec['time_mean']), _fmt(rec['time_se']), rec['wearers'], r.note])
    return '\n'.join(md_table(header, rows, 'llrrrrrrl'))


def markdown_table(frame: pd.DataFrame) -> str:
    header = ['knob', 'value', 'accuracy metric', 'mean', 'SD', 'p10 to p90', 'time metric', 'mean', 'SD',
              'p10 to p90', 'n']
    rows = [[r.knob, f'{r.value:g}', r.accuracy_metric, _fmt(r.accuracy_mean), _fmt(r.accuracy_sd),
             f'{_fmt(r.accuracy_p10)} to {_fmt(r.accuracy_p90)}', r.time_metric, _fmt(r.time_mean), _fmt(r.time_sd),
             f'{_fmt(r.time_p10)} to {_fmt(r.time_p90)}', int(r.n)] for r in frame.itertuples()]
    return '\n'.join(md_table(header, rows, 'lrlrrrlrrrr'))


def write_outputs(result: SweepResult, out: Path) -> dict[str, Path]:
    """DIR/tradeoff.csv, DIR/<knob>.png, DIR/tradeoff.md; returns the paths by name."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    frame = result.frame()
    paths = {'csv': out / 'tradeoff.csv'}
    frame.to_csv(paths['csv'], index=False)
    curves = result.curves()
    readings = {c: read_curve(rows) for c, rows in curves.items()}
    for knob in result.settings.knobs:
        mine = [rows for c, rows in curves.items() if c[0] == knob and not _is_plane_only(c)]
        paths[knob] = plot_knob(mine, out / f'{knob}.png')
    if result.settings.plane:
        paths['plane'] = plot_plane(result, out / 'plane.png')
    s = result.settings
    acc, spd = result.scenes
    lines = ['# What accuracy costs in time', '',
             f'Scenes: `{acc.name}` (accuracy protocol, {s.repetitions} trials per wearer and '
             'value) and '
             f'`{spd.name}` (speed protocol, {s.speed_repetitions} trials of '
             f'{spd.protocol.trial_s:g} s per wearer '
             f'and value), with their effects: {", ".join(acc.effect_names) or "none"}. '
             f'The first {s.subjects} wearers of each population, condition {s.condition}, each '
             'calibrated by '
             f'Algorithm 1 in the simulation. Lower is better on both axes. '
             f'Sweep wall time {result.wall_s:.0f} s with {s.workers} worker(s)'
             + (' (--quick: tiny population and grids)' if s.quick else '') + '.', '',
             '## Grids', '']
    for knob in s.knobs:
        ref, source = REFERENCE[knob]
        lines.append(f'- {KNOB_TITLES[knob]}: {", ".join(f"{v:g}" for v in s.grids[knob])} '
                     f'({source}: {ref:g})')
    if s.plane:
        lines += ['', '## The plane', '', plane_text(result), '', plane_table(result), '',
                  f'![plane]({image_path(paths["plane"], out)})']
    lines += ['', '## Table', '', markdown_table(frame), '',
              'Guidance error: hypot of the horizontal and vertical absolute errors of the true '
              'gaze at the key '
              'press. Error when a target counts: the true gaze\'s angle to the target when the '
              'tracked gaze has '
              'stayed within the tolerance for the dwell. Time to find: from a target\'s '
              'appearance to its count '
              '(found targets only). Calibration time: simulated seconds Algorithm 1 ran. Fit '
              'wall time: the fastest '
              f'of {s.fit_repeats} calls of fit_power_law on the same points, on this machine '
              '(the Algorithm 1 '
              'points of the accuracy scene at its own settings, refitted). '
              'n: accuracy samples (trials, found targets, '
              'wearer x direction or fits). Spread: SD (ddof 1), p10-p90 over those samples.', '']
    notes = [(r.knob, r.value, r.note) for r in result.rows if r.note]
    if notes:
        lines += ['Notes per value:', '']
        seen = set()
        for knob, value, note in notes:
            if (knob, value, note) not in seen:
                seen.add((knob, value, note))
                lines.append(f'- {knob} {value:g}: {note}')
        lines.append('')
    lines += ['## Reading', '',
              'Generated from the numbers (rules in `fabric_guidance.experiments.tradeoff.read_curve`).', '']
    for (knob, am, tm), text in readings.items():
        lines.append(f'- **{knob}** ({am} against {tm}): {text}')
    if 'control_rate' in s.knobs:
        lines.append(f'- **control_rate and G**: {gain_rate_reading(result)}')
    lines += ['', '## Plots', '']
    for knob in s.knobs:
        lines += [f'![{knob}]({image_path(paths[knob], out)})', '']
    paths['md'] = out / 'tradeoff.md'
    paths['md'].write_text('\n'.join(lines).rstrip() + '\n')
    result.readings = readings
    return paths


# ---------------------------------------------------------------------------------------------
# Command line


def configure(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    parser.add_argument('--out', type=Path, required=True, metavar='DIR', help='folder for the table, report and plots')
    parser.add_argument('--subjects', type=int, default=None,
                        help=f'wearers per scene (default {Settings.subjects}; --quick 2)')
    parser.add_argument('--repetitions', type=int, default=None,
                        help=f'accuracy-protocol trials per wearer and value (default {Settings.repetitions}; '
                             '--quick 2)')
    parser.add_argument('--speed-repetitions', type=int, default=None,
                        help=f'speed-protocol trials per wearer and value (default {Settings.speed_repetitions}; '
                             '--quick 1)')
    parser.add_argument('--knobs', default=','.join(KNOBS), help=f'comma-separated subset of {",".join(KNOBS)}')
    parser.add_argument('--condition', type=int, default=1, choices=(1, 2, 3),
                        help='guidance condition (1 suit adjusted, 2 suit fixed, 3 arm adjusted)')
    parser.add_argument('--accuracy-scene', default=DEFAULT_ACCURACY_SCENE,
                        help='scene for the accuracy-protocol curves (a speed scene gets the accuracy protocol\'s '
                             'defaults)')
    parser.add_argument('--speed-scene', default=DEFAULT_SPEED_SCENE,
                        help='scene for the speed-protocol curves (an accuracy scene gets the speed protocol\'s '
                             'defaults)')
    parser.add_argument('--workers', type=int, default=min(2, os.cpu_count() or 1), help='processes')
    parser.add_argument('--quick', action='store_true',
                        help='a tiny sweep: 2 wearers, 3 values per knob, 20 s speed trials (seconds, for a check)')
    parser.add_argument('--no-plane', action='store_true',
                        help='only the per-knob curves: no conditions 1-4, no plane.png (faster)')
    return parser


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the `tradeoff` subcommand to an argparse subparsers object; dispatch to run(args)."""
    return subcommand.add(subparsers, 'tradeoff', HELP, __doc__, configure, run)


def settings_from_args(args: argparse.Namespace) -> Settings:
    base = quick_settings() if args.quick else Settings()
    changes = dict(condition=args.condition, workers=args.workers, accuracy_scene=args.accuracy_scene,
                   plane=not args.no_plane,
                   speed_scene=args.speed_scene,
                   knobs=tuple(k.strip() for k in args.knobs.split(',') if k.strip()))
    for name in ('subjects', 'repetitions', 'speed_repetitions'):
        if getattr(args, name) is not None:
            changes[name] = getattr(args, name)
    return replace(base, **changes)


def _error(message: str) -> None:
    print(f'{PROG}: error: {" ".join(str(message).split())}', file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    """0 done, 2 bad arguments or scene, 1 an output could not be written."""
    try:
        settings = settings_from_args(args)
        acc, _ = base_scenes(settings)
        check_settings(settings, acc)
    except (ValueError, OSError) as exc:
        _error(exc)
        return 2
    print(f'{PROG}: {len(settings.knobs)} knob(s), {settings.subjects} wearers, {settings.workers} worker(s)',
          file=sys.stderr, flush=True)
    result = run_sweep(settings, progress=lambda line: print(line, file=sys.stderr, flush=True))
    try:
        paths = write_outputs(result, args.out)
    except OSError as exc:
        _error(f'cannot write {exc.filename or args.out}: {exc.strerror or exc}')
        return 1
    print(markdown_table(result.frame()))
    print()
    for (knob, am, tm), text in result.readings.items():
        print(f'{knob} ({am} vs {tm}): {text}\n')
    print(f'sweep: {result.wall_s:.1f} s wall; ' + ', '.join(f'{k} {v:.1f} s' for k, v in result.knob_wall_s.items()))
    print(f'table: {paths["csv"]}\nreport: {paths["md"]}\nplots: '
          + ', '.join(str(paths[k]) for k in ('plane',) + settings.knobs if k in paths))
    return 0


def main(argv: list[str] | None = None) -> int:
    return subcommand.main(PROG, __doc__, configure, run, argv)


__all__ = ['DEFAULT_GRIDS', 'KNOBS', 'QUICK_GRIDS', 'Row', 'Settings', 'SweepResult', 'add_parser',
           'calibrate_measured',
           'diff_se', 'main', 'markdown_table', 'pareto_front', 'plot_knob', 'quick_settings', 'read_curve', 'run',
           'run_sweep', 'speed_trial_detail', 'write_outputs']


if __name__ == '__main__':
    sys.exit(main())
