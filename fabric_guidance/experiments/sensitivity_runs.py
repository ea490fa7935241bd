"""The runs of `fabric-guidance sensitivity` (sensitivity.py): the assumed parameters of the
scenes, each set low and high, both protocols run again on the same wearers, and the headline
figures of every run with the baseline's spread over seeds."""
from __future__ import annotations

from dataclasses import dataclass, field, fields
import math
import time
from typing import Callable

import numpy as np
import pandas as pd
from scipy import stats as ss

from ..sim.effects import REGISTRY
from ..sim.engine import package_channel_map
from ..sim.population import calibrate_wearer, sample_wearer
from ..sim.protocols import accuracy_trial, speed_trial
from ..sim.scene import Scene
from ..workers import WorkerPool
from .fit_wearer import FITTED_PARAMS
from .tradeoff import DEFAULT_ACCURACY_SCENE, DEFAULT_SPEED_SCENE, calibration_key, t_interval
from .tradeoff.settings import paired_scenes


#: (effect, parameter) pairs measured or fitted, so not assumptions: never swept. The medians that
#: fit-wearer fits to the paper's speed table are here, and the arm_spread it profiles; extend it
#: (or pass --exclude, or give the scene a `measured`/`fitted` list) once a value is measured.
MEASURED: set[tuple[str, str]] = set(FITTED_PARAMS) | {('population', 'arm_spread')}
#: Scene attributes that may list measured or fitted parameters as 'effect.parameter'.
SCENE_MEASURED_KEYS = ('measured', 'fitted')
#: Where a scene's value is 0, x0.5 and x2 stay 0: the high side takes this value instead
#: (by unit; else the effect class's default when positive, else FALLBACK_SMALL).
SMALL_BY_UNIT = {'s': 0.05, 'deg': 1.0, 'kPa': 5.0, '-': 0.05, '(log) -': 0.1}
FALLBACK_SMALL = 0.1

HEADLINES = ('c1_targets', 'c1_minus_c2', 'c4_targets', 'c1_error_deg', 'c4_error_deg')
HEADLINE_TITLES = {'c1_targets': 'condition 1: targets per 40 s',
                   'c1_minus_c2': 'condition 1 minus 2: targets per 40 s',
                   'c4_targets': 'condition 4 (speech): targets per 40 s',
                   'c1_error_deg': 'condition 1: key-press error (deg)',
                   'c4_error_deg': 'condition 4: key-press error (deg)'}
SPEED_CONDITIONS = (1, 2, 4)
ACCURACY_CONDITIONS = (1, 4)
#: A move is beyond noise when it exceeds the half-width of this prediction interval of one
#: seed's figure from the baseline's k seeds: t(0.975, k-1) x sqrt(1 + 1/k) seed SDs
#: (SensitivityResult.noise_sds; 4.97 for 3 seeds, 3.04 for 5, near 2 for many).
CONFIDENCE = 0.95


# ---------------------------------------------------------------------------------------------
# Settings


@dataclass(frozen=True)
class Settings:
    subjects: int = 10
    repetitions: int = 5                # accuracy trials per wearer and condition
    speed_repetitions: int = 2          # 40 s speed trials per wearer and condition
    low: float = 0.5                    # factor on the scene's value
    high: float = 2.0
    seeds: int = 3                      # baseline runs with seed, seed+1, ... (the noise)
    workers: int = 2
    speed_scene: str = DEFAULT_SPEED_SCENE
    accuracy_scene: str = DEFAULT_ACCURACY_SCENE
    parameters: tuple[str, ...] = ()    # a subset of the parameter keys; () = every one
    exclude: tuple[str, ...] = ()
    trial_s: float | None = None        # None: the scene's (the paper's 40 s)
    quick: bool = False


def quick_settings(**changes) -> Settings:
    base = dict(subjects=2, repetitions=2, speed_repetitions=1, seeds=2, trial_s=20.0, quick=True)
    base.update(changes)
    return Settings(**base)


def check_settings(s: Settings) -> None:
    for name in ('subjects', 'repetitions', 'speed_repetitions', 'seeds', 'workers'):
        v = getattr(s, name)
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise ValueError(f'--{name.replace("_", "-")} must be a whole number >= 1, got {v!r}')
    for name in ('low', 'high'):
        v = getattr(s, name)
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ValueError(f'--{name} must be a positive factor, got {v!r}')
    if not s.low < 1.0 < s.high:
        raise ValueError(f'--low must be below 1 and --high above 1 (factors on the scene value), '
                         f'got {s.low:g} and {s.high:g}')
    if s.trial_s is not None and not (math.isfinite(s.trial_s) and s.trial_s > 0):
        raise ValueError(f'trial length must be positive, got {s.trial_s!r}')


# ---------------------------------------------------------------------------------------------
# Scenes and parameters


def load_scenes(s: Settings) -> tuple[Scene, Scene]:
    """(speed scene, accuracy scene) on the same wearers: the accuracy scene takes the speed
    scene's seed and population (as the trade-off's plane)."""
    return paired_scenes(s.speed_scene, s.accuracy_scene, SPEED_CONDITIONS, ACCURACY_CONDITIONS,
                         s.speed_repetitions, s.repetitions, s.trial_s, s.subjects)


@dataclass(frozen=True)
class Parameter:
    """One assumed parameter: key 'effect.name', 'population.spread.a', 'population.arm_spread'
    or 'protocol.dwell_s'; its value in the scenes where it applies, unit and valid range."""

    key: str
    unit: str
    value: float                    # the speed scene's (or, if only there, the accuracy scene's)
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    default: float | None = None    # the effect class's default
    scenes: tuple[str, ...] = ()    # 'speed', 'accuracy': where it is applied

    def values(self, low: float, high: float) -> tuple[float | None, float | None]:
        """(low value, high value), clipped to the valid range; None: that side is the scene's
        value itself (a zero has no lower multiple) or outside the range."""
        return self._side(self.value, low), self._side(self.value, high)

    def _side(self, base: float, factor: float) -> float | None:
        if base == 0.0:
            if factor < 1.0:
                return None
            small = self.default if self.default else SMALL_BY_UNIT.get(self.unit, FALLBACK_SMALL)
            v = float(small)
        else:
            v = base * factor
        if self.hi is not None:
            v = min(v, self.hi)
        if self.lo is not None and (v <= self.lo if self.lo_open else v < self.lo):
            return None
        return None if math.isclose(v, base, rel_tol=1e-12, abs_tol=1e-15) else v


def _scene_marked(scene: Scene) -> set[str]:
    out = set()
    for key in SCENE_MEASURED_KEYS:
        items = getattr(scene, key, None) or ()
        for item in items:
            out.add(item if isinstance(item, str) else '.'.join(map(str, item)))
    return out


def _effect_value(scene: Scene, effect: str, name: str):
    spec = scene.effect(effect)
    return spec.params_dict.get(name, REGISTRY[effect].parameters()[name][0])


def assumed_parameters(spd: Scene, acc: Scene, exclude=()) -> list[Parameter]:
    """Every assumed parameter of the two scenes, in a stable order: the effects the scenes list
    (REGISTRY order of first listing), their parameters, then spread, arm_spread, dwell_s.
    Optional parameters left unset (None) have no value to vary and are left out."""
    skip = {f'{e}.{p}' for e,
            p in MEASURED} | set(exclude) | _scene_marked(spd) | _scene_marked(acc)
    out: list[Parameter] = []
    names = list(dict.fromkeys(spd.effect_names + acc.effect_names))
    for effect in names:
        cls = REGISTRY[effect]
        where = tuple(k for k, sc in (('speed', spd), ('accuracy',
                                                       acc)) if sc.effect(effect) is not None)
        primary = spd if 'speed' in where else acc
        for f in fields(cls):
            key = f'{effect}.{f.name}'
            value = _effect_value(primary, effect, f.name)
            if key in skip or value is None or isinstance(value, bool):
                continue
            meta = f.metadata
            default = f.default if isinstance(f.default, (int, float)) and f.default else None
            out.append(Parameter(key, meta.get('unit', ''), float(value), meta.get('lo'),
                                 meta.get('hi'),
                                 bool(meta.get('lo_open')), default, where))
    for k, coef in enumerate('abc'):
        key = f'population.spread.{coef}'
        if key not in skip:
            out.append(Parameter(key, '(log) -', float(spd.population.spread[k]), 0.0, 3.0,
                                 scenes=('speed', 'accuracy')))
    if 'population.arm_spread' not in skip:
        out.append(Parameter('population.arm_spread', '(log) -', float(spd.population.arm_spread),
                             0.0, 3.0,
                             scenes=('speed', 'accuracy')))
    if 'protocol.dwell_s' not in skip:
        out.append(Parameter('protocol.dwell_s', 's', float(spd.protocol.dwell_s), 0.0, None,
                             scenes=('speed',)))
    return out


def _scale(base: float, value: float, reference: float) -> float:
    """The value for a scene whose own value is `base`, when the reference scene's `reference`
    goes to `value`: the same factor (the same value where either is 0)."""
    if reference == 0.0 or base == 0.0:
        return value
    return base * value / reference


def apply(scene: Scene, kind: str, p: Parameter, value: float) -> Scene:
    """The scene with parameter p at `value` (an effect's scaled to this scene's own value), or
    unchanged when p does not apply to this kind of scene."""
    if kind not in p.scenes:
        return scene
    group, _, name = p.key.partition('.')
    if group not in ('population', 'protocol'):
        value = _scale(float(_effect_value(scene, group, name)), value, p.value)
    return scene.with_value(p.key, value)


# ---------------------------------------------------------------------------------------------
# Runs


def _wearer_job(args):
    """One wearer of one run: calibrated once (shared by both protocols when their calibration
    is the same), then the speed and accuracy trials. Per condition: targets per 40 s (mean over
    trials) and key-press errors (mean over trials)."""
    spd, acc, subject = args
    package_channel_map()
    wearer = sample_wearer(spd, subject)
    cal = calibrate_wearer(spd, wearer)
    if not cal.ok:
        return subject, None, cal.error
    if calibration_key(acc) == calibration_key(spd):
        acc_cal = cal
    else:
        acc_cal = calibrate_wearer(acc, sample_wearer(acc, subject))
        if not acc_cal.ok:
            return subject, None, acc_cal.error
    per40 = 40.0 / spd.protocol.trial_s
    out = {}
    for c in spd.conditions:
        n = [speed_trial(spd, wearer, cal.calibration, c,
                         r)['identified'] for r in range(spd.repetitions)]
        out[f'targets_{c}'] = per40 * float(np.mean(n))
    acc_wearer = sample_wearer(acc, subject)
    for c in acc.conditions:
        errs = []
        for r in range(acc.repetitions):
            t = accuracy_trial(acc, acc_wearer, acc_cal.calibration, c, r)
            errs.append(math.hypot(t['h_error_deg'], t['v_error_deg']))
        out[f'error_{c}'] = float(np.mean(errs))
    return subject, out, None


def headlines(per_wearer: dict[int, dict]) -> dict[str, float]:
    """The five figures: means over the wearers (each wearer's mean over their trials)."""
    ok = [v for v in per_wearer.values() if v is not None]
    if not ok:
        return {h: math.nan for h in HEADLINES}
    m = lambda k: float(np.mean([v[k] for v in ok]))  # noqa: E731
    return {'c1_targets': m('targets_1'), 'c1_minus_c2': m('targets_1') - m('targets_2'),
            'c4_targets': m('targets_4'), 'c1_error_deg': m('error_1'),
            'c4_error_deg': m('error_4')}


@dataclass
class Run:
    parameter: str          # '' for a baseline
    side: str               # 'baseline', 'low', 'high'
    value: float | None     # the value run (the speed scene's; None for a baseline)
    seed: int
    figures: dict
    excluded: list = field(default_factory=list)
    wall_s: float = 0.0


@dataclass
class SensitivityResult:
    settings: Settings
    parameters: list[Parameter]
    baselines: list[Run]
    runs: list[Run]
    scenes: tuple[Scene, Scene]
    wall_s: float = 0.0

    @property
    def baseline(self) -> dict:
        return self.baselines[0].figures

    def seed_sd(self) -> dict:
        """SD (ddof 1) of each figure over the baseline seeds; nan with one seed."""
        out = {}
        for h in HEADLINES:
            vals = [b.figures[h] for b in self.baselines]
            out[h] = float(np.std(vals, ddof=1)) if len(vals) > 1 else math.nan
        return out

    def seed_interval(self) -> dict:
        """Per figure (mean, lo, hi, k): the baseline's mean over its k seeds with the 95 % t
        interval of that mean (lo = hi = nan with one seed: no interval)."""
        return {h: t_interval([b.figures[h] for b in self.baselines], CONFIDENCE) for h in HEADLINES}

    def noise_sds(self) -> float:
        """How many seed SDs a move must exceed to be beyond noise: the half-width of the 95 %
        prediction interval of one more seed's figure, t(0.975, k-1) x sqrt(1 + 1/k), from the k
        baseline seeds; nan with one seed (no interval: no move is called beyond noise)."""
        k = len(self.baselines)
        if k < 2:
            return math.nan
        return float(ss.t.ppf(0.5 + CONFIDENCE / 2, k - 1) * math.sqrt(1.0 + 1.0 / k))

    def noise(self, h: str, sd: dict | None = None) -> float:
        """The half-width of that prediction interval for figure h (its units)."""
        return self.noise_sds() * self.scale(h, sd)

    def beyond(self, run: 'Run', sd: dict | None = None) -> list[str]:
        """The figures a run moves beyond noise (none with one seed)."""
        base = self.baseline
        return [h for h in HEADLINES if math.isfinite(run.figures[h] - base[h])
                and abs(run.figures[h] - base[h]) > self.noise(h, sd)]

    def frame(self) -> pd.DataFrame:
        """One row per run (the baselines first, one per seed), then the baseline's mean over the
        seeds and its 95 % interval (side seeds_mean, seeds_lo, seeds_hi)."""
        params = {p.key: p for p in self.parameters}
        base = self.baseline
        sd = self.seed_sd()
        recs = []
        for r in self.baselines + self.runs:
            p = params.get(r.parameter)
            rec = dict(parameter=r.parameter or 'baseline', side=r.side, unit=p.unit if p else '',
                       scene_value=p.value if p else math.nan,
                       value=r.value if r.value is not None else math.nan, seed=r.seed)
            for h in HEADLINES:
                rec[h] = r.figures[h]
            for h in HEADLINES:
                rec[f'd_{h}'] = r.figures[h] - base[h] if r.side != 'baseline' else math.nan
            rec['excluded'] = len(r.excluded)
            rec['seeds'] = len(self.baselines)
            rec['beyond_noise'] = ','.join(self.beyond(r, sd)) if r.side != 'baseline' else ''
            recs.append(rec)
        iv = self.seed_interval()
        for side, j in (('seeds_mean', 0), ('seeds_lo', 1), ('seeds_hi', 2)):
            rec = dict(parameter='baseline', side=side, unit='', scene_value=math.nan, value=math.nan,
                       seed=math.nan)
            rec.update({h: iv[h][j] for h in HEADLINES})
            rec.update({f'd_{h}': math.nan for h in HEADLINES})
            rec.update(excluded=math.nan, seeds=len(self.baselines), beyond_noise='')
            recs.append(rec)
        return pd.DataFrame(recs)

    def resolution(self, h: str) -> float:
        """The smallest change a figure can show: one target in one trial of one wearer (targets)
        or 0.01 deg (errors); the floor of the noise when the seeds happen to agree."""
        s, spd = self.settings, self.scenes[0]
        if h.endswith('_deg'):
            return 0.01
        return 40.0 / spd.protocol.trial_s / (s.subjects * s.speed_repetitions)

    def scale(self, h: str, sd: dict | None = None) -> float:
        sd = self.seed_sd() if sd is None else sd
        v = sd[h]
        return max(v, self.resolution(h)) if math.isfinite(v) else self.resolution(h)

    def ranking(self) -> list[tuple[str, float, str]]:
        """(parameter, largest |move| in seed SDs over the figures, that figure), largest first.
        A seed SD below the figure's resolution (seeds that happen to agree, or one seed) is
        replaced by the resolution."""
        sd = self.seed_sd()
        base = self.baseline
        best: dict[str, tuple[float, str]] = {}
        for r in self.runs:
            for h in HEADLINES:
                z = abs(r.figures[h] - base[h]) / self.scale(h, sd)
                if not math.isfinite(z):
                    continue
                if z > best.get(r.parameter, (-1.0, ''))[0]:
                    best[r.parameter] = (z, h)
        order = [p.key for p in self.parameters if p.key in best]
        return sorted(((k, *best[k]) for k in order), key=lambda x: -x[1])


def run_sensitivity(settings: Settings,
                    progress: Callable[[str], None] | None = None) -> SensitivityResult:
    say = progress or (lambda line: None)
    check_settings(settings)
    spd, acc = load_scenes(settings)
    params = assumed_parameters(spd, acc, settings.exclude)
    if settings.parameters:
        known = {p.key for p in params}
        unknown = [k for k in settings.parameters if k not in known]
        if unknown:
            raise ValueError(f'--parameters: unknown or not swept {unknown}; '
                             f'valid: {", ".join(sorted(known))}')
        params = [p for p in params if p.key in settings.parameters]
    plan: list[tuple[str, str, float | None, int, Scene, Scene]] = []
    for k in range(settings.seeds):
        seed = spd.seed + k
        plan.append(('', 'baseline', None, seed, spd.replace(seed=seed), acc.replace(seed=seed)))
    for p in params:
        for side, v in zip(('low', 'high'), p.values(settings.low, settings.high)):
            if v is not None:
                plan.append((p.key, side, v, spd.seed, apply(spd, 'speed', p, v),
                             apply(acc, 'accuracy', p, v)))
    start = time.perf_counter()
    pool = WorkerPool(settings.workers, settings.subjects)
    baselines, runs = [], []
    try:
        for i, (key, side, v, seed, s_scene, a_scene) in enumerate(plan, start=1):
            t0 = time.perf_counter()
            results = pool.map(_wearer_job, [(s_scene, a_scene,
                                              j) for j in range(settings.subjects)])
            per = {subj: out for subj, out, _ in results}
            excluded = [f'S{subj + 1:02d}: {err}' for subj, out, err in results if out is None]
            run = Run(key, side, v, seed, headlines(per), excluded, time.perf_counter() - t0)
            (baselines if side == 'baseline' else runs).append(run)
            what = f'baseline seed {seed}' if side == 'baseline' else f'{key} {side} = {v:.4g}'
            figs = ', '.join(f'{h} {run.figures[h]:.3g}' for h in HEADLINES)
            say(f'[{i}/{len(plan)}] {what}: {figs}'
                + (f'; {len(excluded)} wearer(s) excluded' if excluded else '')
                + f' ({run.wall_s:.1f} s)')
    finally:
        pool.close()
    return SensitivityResult(settings, params, baselines, runs, (spd, acc),
                             time.perf_counter() - start)
