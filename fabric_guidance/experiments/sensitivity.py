"""`fabric-guidance sensitivity --out DIR`: which headline figures rest on which assumptions.

Every *assumed* human parameter of the scenes (every parameter of every effect the scenes list,
the population's spread a/b/c and arm_spread, and the speed protocol's dwell_s) is set low and
high (default x0.5 and x2 of the scene's value; a value of 0 goes to a small positive value;
both clipped to the parameter's valid range) one at a time, and both protocols run again on the
same wearers with the same seed (common random numbers, so every difference is paired). For
each run the headline figures:

  c1_targets       condition 1: targets found per 40 s (speed protocol; mean over wearers)
  c1_minus_c2      condition 1 minus condition 2, targets per 40 s (the paper: 1 > 2)
  c4_targets       condition 4 (speech): targets per 40 s
  c1_error_deg     condition 1: error of the true gaze at the key press (accuracy protocol,
                   hypot of h and v; before any visual capture)
  c4_error_deg     condition 4: the same

The baseline is also run with further seeds (other wearers, targets and noise): the SD of a
figure over those seeds is the noise a move is compared with in the table (a move of less than
2 seed SDs is not a finding on this many wearers).

An effect the scenes do not list cannot matter and is not swept. A parameter the scene marks
as measured or fitted is not an assumption and is not swept either: the scene's `measured` or
`fitted` attribute (names `effect.parameter`) when the scene format offers one, the
module-level MEASURED set, and --exclude.

Outputs in DIR: sensitivity.csv (one row per parameter and side: parameter, unit, scene value,
value run, the five figures and their change from the baseline; plus the baseline rows, one
per seed), sensitivity.md (the table sorted by the largest move in seed SDs, with the baseline
and its seed spread), sensitivity.png (a tornado plot per figure). One progress line per run
goes to stderr.

Also runs alone: python -m fabric_guidance.experiments.sensitivity --out DIR [--quick]
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass, field, fields, replace
import math
import os
from pathlib import Path
import sys
import time
from typing import Callable

import numpy as np
import pandas as pd

from .. import subcommand
from ..atomic import atomic_write, write_csv, write_text
from ..sim.effects import REGISTRY
from ..sim.engine import package_channel_map
from ..sim.population import calibrate_wearer, sample_wearer
from ..sim.protocols import accuracy_trial, speed_trial
from ..sim.scene import Scene
from ..workers import WorkerPool
from .fit_wearer import FREE
from .report import image_path, md_table
from .tradeoff import DEFAULT_ACCURACY_SCENE, DEFAULT_SPEED_SCENE, calibration_key
from .tradeoff.settings import paired_scenes

PROG = 'fabric-guidance sensitivity'
HELP = 'vary every assumed human parameter low and high: how much each moves the headline figures'

#: (effect, parameter) pairs measured or fitted, so not assumptions: never swept. The four that
#: fit-wearer fits to the paper's speed means are here; extend it (or pass --exclude, or give the
#: scene a `measured`/`fitted` list) once a value is measured.
MEASURED: set[tuple[str, str]] = {(f.effect, f.param) for f in FREE}
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
#: Moves beyond this many seed SDs are called beyond noise in the report.
NOISE_SDS = 2.0


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

    def frame(self) -> pd.DataFrame:
        params = {p.key: p for p in self.parameters}
        base = self.baseline
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


# ---------------------------------------------------------------------------------------------
# Output


def _fmt(x) -> str:
    if x is None or not math.isfinite(x):
        return 'n/a'
    return f'{x:.3g}' if abs(x) >= 1e-3 or x == 0 else f'{x:.2e}'


def _signed(x) -> str:
    return 'n/a' if x is None or not math.isfinite(x) else f'{x:+.3g}'


def markdown_table(result: SensitivityResult) -> str:
    params = {p.key: p for p in result.parameters}
    sd = result.seed_sd()
    by = {(r.parameter, r.side): r for r in result.runs}
    base = result.baseline
    header = ['parameter', 'scene value',
              'low / high run'] + [f'{h}: low / high' for h in HEADLINES] + \
        ['largest move (seed SDs)']
    rows = [['baseline', '', f'{len(result.baselines)} seeds']
            + [f'{_fmt(base[h])} (seed SD {_fmt(sd[h])})' for h in HEADLINES] + ['']]
    for key, z, h in result.ranking():
        p = params[key]
        lo, hi = by.get((key, 'low')), by.get((key, 'high'))
        vals = ' / '.join(_fmt(r.value) if r else '-' for r in (lo, hi))
        cells = []
        for name in HEADLINES:
            cells.append(' / '.join(_signed(r.figures[name] - base[name]) if r else '-'
                                    for r in (lo, hi)))
        mark = ' **beyond noise**' if z >= NOISE_SDS else ''
        unit = f' {p.unit}' if p.unit and p.unit != '-' else ''
        rows.append([key, f'{_fmt(p.value)}{unit}', vals] + cells + [f'{z:.1f} ({h}){mark}'])
    return '\n'.join(md_table(header, rows, 'lrr' + 'r' * len(HEADLINES) + 'l'))


def plot_tornado(result: SensitivityResult, path: Path, dpi: int = 120) -> Path:
    """One panel per figure: for each parameter (sorted by its largest move, the largest on
    top) a bar from the baseline to the low run (blue) and to the high run (orange); the grey
    band is +-2 seed SDs of the baseline."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    ranking = [k for k, _, _ in result.ranking()]
    n = max(len(ranking), 1)
    fig = Figure(figsize=(3.3 * len(HEADLINES) + 2.6, 1.6 + 0.32 * n), layout='constrained')
    FigureCanvasAgg(fig)
    by = {(r.parameter, r.side): r for r in result.runs}
    base, sd = result.baseline, result.seed_sd()
    axes = fig.subplots(1, len(HEADLINES), sharey=True)
    ypos = {k: n - 1 - i for i, k in enumerate(ranking)}
    for ax, h in zip(np.atleast_1d(axes), HEADLINES):
        b = base[h]
        noise = NOISE_SDS * result.scale(h, sd)
        ax.axvspan(b - noise, b + noise, color='0.85', zorder=0)
        ax.axvline(b, color='black', lw=1.0, zorder=1)
        for key in ranking:
            y = ypos[key]
            for side, colour, dy in (('low', 'tab:blue', 0.18), ('high', 'tab:orange', -0.18)):
                r = by.get((key, side))
                if r is not None and math.isfinite(r.figures[h]):
                    ax.barh(y + dy, r.figures[h] - b, left=b, height=0.34, color=colour, zorder=2)
        ax.set_title(HEADLINE_TITLES[h], fontsize=9)
        ax.grid(axis='x', alpha=0.3)
        ax.tick_params(axis='x', labelsize=8)
    first = np.atleast_1d(axes)[0]
    first.set_yticks(list(ypos.values()), list(ypos.keys()), fontsize=8)
    first.set_ylim(-0.7, n - 0.3)
    s = result.settings
    fig.suptitle(f'Sensitivity of the headline figures to the assumed parameters '
                 f'(x{s.low:g} blue, x{s.high:g} '
                 f'orange; black line: baseline, grey band: +-{NOISE_SDS:g} SD over '
                 f'{len(result.baselines)} '
                 f'seeds)\n{s.subjects} wearers, scenes {result.scenes[0].name} / '
                 f'{result.scenes[1].name}; '
                 'sorted by the largest move in seed SDs', fontsize=10)
    fig.legend(handles=[Patch(color='tab:blue', label=f'low (x{s.low:g})'),
                        Patch(color='tab:orange', label=f'high (x{s.high:g})'),
                        Patch(color='0.85', label=f'baseline +-{NOISE_SDS:g} seed SD')],
               loc='outside lower center', ncol=3, fontsize=8, frameon=False)
    path = Path(path)
    atomic_write(path, lambda f: fig.savefig(f, dpi=dpi, format='png'))
    return path


def write_outputs(result: SensitivityResult, out: Path) -> dict[str, Path]:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = {'csv': out / 'sensitivity.csv', 'png': out / 'sensitivity.png',
             'md': out / 'sensitivity.md'}
    write_csv(paths['csv'], result.frame())
    plot_tornado(result, paths['png'])
    s = result.settings
    spd, acc = result.scenes
    beyond = [(k, z, h) for k, z, h in result.ranking() if z >= NOISE_SDS]
    lines = ['# Which figures rest on which assumptions', '',
             f'Scenes `{spd.name}` (speed protocol, conditions '
             f'{", ".join(map(str, spd.conditions))}, '
             f'{s.speed_repetitions} trial(s) of {spd.protocol.trial_s:g} s per wearer and '
             'condition) and '
             f'`{acc.name}` (accuracy protocol, conditions '
             f'{", ".join(map(str, acc.conditions))}, {s.repetitions} '
             f'trials), on the same {s.subjects} wearers (the speed scene\'s seed {spd.seed} and '
             'population). '
             f'Each assumed parameter at x{s.low:g} and x{s.high:g} of the scene value (0 goes '
             'to a small positive '
             'value; clipped to the valid range), one at a time, same seed: the moves are '
             'paired. '
             f'{len(result.baselines) + len(result.runs)} runs in {result.wall_s:.0f} s wall '
             f'with {s.workers} '
             f'worker(s)' + (' (--quick)' if s.quick else '') + '.', '',
             'Figures: ' + '; '.join(f'`{h}` {HEADLINE_TITLES[h]}' for h in HEADLINES)
             + '. Targets are scaled '
             'to 40 s; errors are the true gaze\'s at the key press (hypot of h and v).', '',
             '## Table', '',
             f'Moves from the baseline (first row: the baseline at seed {spd.seed} and the SD of '
             'each figure over '
             f'{len(result.baselines)} seeds, i.e. other wearers and targets). Sorted by the '
             'largest move in seed SDs; '
             f'**beyond noise**: at least {NOISE_SDS:g} seed SDs (a paired move can be real '
             'below that, but is '
             'not shown to matter on this many wearers).', '',
             markdown_table(result), '']
    if beyond:
        lines += [f'{len(beyond)} of {len(result.ranking())} parameters move a figure beyond '
                  'noise: '
                  + ', '.join(f'`{k}` ({h}, {z:.1f} SD)' for k, z, h in beyond) + '.', '']
    else:
        lines += ['No parameter moves a figure by 2 seed SDs or more.', '']
    skipped = sorted({f'{e}.{p}' for e, p in MEASURED} | set(s.exclude))
    if skipped:
        lines += ['Not swept (measured, fitted or excluded): '
                  + ', '.join(f'`{k}`' for k in skipped) + '.', '']
    lines += ['## Tornado plot', '', f'![sensitivity]({image_path(paths["png"], out)})', '']
    write_text(paths['md'], '\n'.join(lines))
    return paths


# ---------------------------------------------------------------------------------------------
# Command line


def _positive_int(option: str, text) -> int:
    """Parsed here, not by argparse, so a bad value gives one line naming the option."""
    try:
        v = int(str(text).strip())
    except ValueError:
        raise ValueError(f'{option} must be a whole number >= 1, got {text!r}') from None
    if v < 1:
        raise ValueError(f'{option} must be a whole number >= 1, got {v}')
    return v


def _factor(option: str, text) -> float:
    try:
        v = float(str(text).strip())
    except ValueError:
        raise ValueError(f'{option} must be a positive number, got {text!r}') from None
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f'{option} must be a positive finite factor, got {text}')
    return v


def configure(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    d = Settings()
    parser.add_argument('--out', type=Path, required=True, metavar='DIR',
                        help='folder for the table, report, plot')
    parser.add_argument('--subjects', default=None,
                        help=f'wearers (default {d.subjects}; --quick 2)')
    parser.add_argument('--repetitions', default=None,
                        help=f'accuracy trials per wearer and condition (default {d.repetitions}; '
                             '--quick 2)')
    parser.add_argument('--speed-repetitions', default=None,
                        help=f'speed trials per wearer and condition '
                             f'(default {d.speed_repetitions}; --quick 1)')
    parser.add_argument('--seeds', default=None,
                        help=f'baseline seeds for the noise (default {d.seeds}; --quick 2)')
    parser.add_argument('--low', default=None, help=f'low factor (default {d.low:g})')
    parser.add_argument('--high', default=None, help=f'high factor (default {d.high:g})')
    parser.add_argument('--parameters', default='',
                        help='comma-separated subset of the parameter keys '
                             '(e.g. reaction_delay.mean_s); '
                             'default: every assumed one')
    parser.add_argument('--exclude', default='',
                        help='comma-separated parameter keys not to sweep (measured or fitted)')
    parser.add_argument('--speed-scene', default=DEFAULT_SPEED_SCENE,
                        help='scene for the speed protocol')
    parser.add_argument('--accuracy-scene', default=DEFAULT_ACCURACY_SCENE,
                        help='scene for the accuracy protocol')
    parser.add_argument('--workers', default=min(2, os.cpu_count() or 1),
                        help='processes (default 2)')
    parser.add_argument('--quick', action='store_true',
                        help='2 wearers, 2 seeds, 20 s speed trials: seconds per run, for a check')
    return parser


def add_parser(subparsers) -> argparse.ArgumentParser:
    return subcommand.add(subparsers, 'sensitivity', HELP, __doc__, configure, run)


def _keys(text: str) -> tuple[str, ...]:
    return tuple(k.strip() for k in text.split(',') if k.strip())


def settings_from_args(args: argparse.Namespace) -> Settings:
    base = quick_settings() if args.quick else Settings()
    changes = dict(speed_scene=args.speed_scene, accuracy_scene=args.accuracy_scene,
                   parameters=_keys(args.parameters), exclude=_keys(args.exclude))
    for name in ('subjects', 'repetitions', 'speed_repetitions', 'seeds', 'workers'):
        if getattr(args, name) is not None:
            changes[name] = _positive_int(f'--{name.replace("_", "-")}', getattr(args, name))
    for name in ('low', 'high'):
        if getattr(args, name) is not None:
            changes[name] = _factor(f'--{name}', getattr(args, name))
    return replace(base, **changes)


def run(args: argparse.Namespace) -> int:
    """0 done, 2 bad arguments or scene, 1 an output could not be written."""
    try:
        settings = settings_from_args(args)
        check_settings(settings)
        spd, acc = load_scenes(settings)
        params = assumed_parameters(spd, acc, settings.exclude)
        valid = {q.key for q in assumed_parameters(spd, acc)} | {f'{e}.{p}' for e, p in MEASURED}
        for option, keys, allowed in (('--exclude', settings.exclude, valid),
                                      ('--parameters', settings.parameters,
                                       {q.key for q in params})):
            unknown = [k for k in keys if k not in allowed]
            if unknown:
                raise ValueError(f'{option}: unknown or not swept {", ".join(unknown)}; valid: '
                                 f'{", ".join(sorted(allowed))}')
        print(f'{PROG}: {len(settings.parameters) or len(params)} parameter(s), '
              f'{settings.subjects} wearers, '
              f'{settings.seeds} baseline seed(s), {settings.workers} worker(s)', file=sys.stderr,
              flush=True)
        result = run_sensitivity(settings, progress=lambda line: print(line, file=sys.stderr,
                                                                       flush=True))
    except (ValueError, OSError) as exc:
        subcommand.error(PROG, exc)
        return 2
    try:
        paths = write_outputs(result, args.out)
    except OSError as exc:
        subcommand.error(PROG, f'cannot write {exc.filename or args.out}: {exc.strerror or exc}')
        return 1
    print(markdown_table(result))
    print(f'\nsensitivity: {result.wall_s:.1f} s wall\ntable: {paths["csv"]}\n'
          f'report: {paths["md"]}\n'
          f'plot: {paths["png"]}')
    return 0


def main(argv: list[str] | None = None) -> int:
    return subcommand.main(PROG, __doc__, configure, run, argv)


__all__ = ['HEADLINES', 'MEASURED', 'Parameter', 'SensitivityResult', 'Settings', 'add_parser',
           'apply',
           'assumed_parameters', 'headlines', 'main', 'quick_settings', 'run', 'run_sensitivity',
           'write_outputs']


if __name__ == '__main__':
    sys.exit(main())
