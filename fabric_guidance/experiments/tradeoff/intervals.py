"""The sweep over several seeds, or over variants of the scenes' fitted parameters: every
figure as the mean over the runs with a 95 % t interval, and the headline findings checked on
the interval.

A seed is new wearers, targets and noise (Scene.replace(seed=...), both scenes alike: the
accuracy scene always takes the speed scene's seed). A variant is a set of scene values
(`effect.param: value`, e.g. one bootstrap draw of the fitted parameters) run at one seed, so
two variants differ by their parameters only. Either way a run is one replicate, and a figure's
interval is the t interval of its replicate values: mean +- t(0.975, k-1) x SD / sqrt(k) for k
runs (k = 1: no interval).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
import math
from pathlib import Path
import time
from typing import Callable, Sequence

import numpy as np
import pandas as pd
from scipy import stats as ss
import yaml

from ...core.safe_input import excerpt
from .rows import Row
from .settings import CSV_COLUMNS, KNOB, Settings, base_scenes, check_settings
from .sweep import SweepResult, run_sweep

CONFIDENCE = 0.95
#: The figures of the table that get an interval over the runs.
INTERVAL_FIGURES = ('accuracy_mean', 'accuracy_sd', 'accuracy_p10', 'accuracy_p90', 'time_mean',
                    'time_sd', 'time_p10', 'time_p90')
#: Most seeds or variants one command runs (each is a whole sweep).
MAX_RUNS = 200


def t_interval(values: Sequence[float], confidence: float = CONFIDENCE) -> tuple[float, float, float, int]:
    """(mean, lo, hi, k) of the finite values: the t interval of their mean. One value has no
    interval (lo = hi = nan); values that agree have a zero-width one."""
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], float)
    k = int(v.size)
    if k == 0:
        return math.nan, math.nan, math.nan, 0
    mean = float(v.mean())
    if k == 1:
        return mean, math.nan, math.nan, 1
    half = float(ss.t.ppf(0.5 + confidence / 2, k - 1) * v.std(ddof=1) / math.sqrt(k))
    return mean, mean - half, mean + half, k


def excludes_zero(lo: float, hi: float) -> bool:
    return math.isfinite(lo) and math.isfinite(hi) and (lo > 0 or hi < 0)


def parse_seeds(text, base: int) -> tuple[int, ...]:
    """'N': N seeds from the scene's (base, base+1, ...); '2025,7,11': those seeds. ValueError
    with one line naming --seeds."""
    raw = str(text).strip()
    parts = [p.strip() for p in raw.split(',')]
    try:
        numbers = [int(p) for p in parts if p]
    except ValueError:
        raise ValueError(f'--seeds must be a count N or a comma-separated list of seeds, got {excerpt(raw)}') \
            from None
    if not numbers:
        raise ValueError('--seeds must be a count N or a comma-separated list of seeds, got nothing')
    if ',' not in raw:
        n = numbers[0]
        if not 1 <= n <= MAX_RUNS:
            raise ValueError(f'--seeds: a count must be within 1..{MAX_RUNS}, got {n}')
        return tuple(base + i for i in range(n))
    if any(s < 0 for s in numbers):
        raise ValueError(f'--seeds: a seed must be >= 0, got {[s for s in numbers if s < 0]}')
    if len(set(numbers)) != len(numbers):
        raise ValueError(f'--seeds: a seed is listed twice in {raw}')
    if len(numbers) > MAX_RUNS:
        raise ValueError(f'--seeds: at most {MAX_RUNS} seeds, got {len(numbers)}')
    return tuple(numbers)


def read_variants(path) -> list[dict]:
    """The variants of a YAML file: a list (or `variants:` a list) of mappings `path: number`,
    each path a scene value (`effect.param`, `population.spread.a`, `controller.gain`...).
    ValueError naming the file, the variant and the reason. The paths are checked against the
    scenes when the variants run (settings.override)."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise ValueError(f'{path}: cannot read: {exc.strerror or exc}') from None
    except yaml.YAMLError as exc:
        raise ValueError(f'{path}: not YAML: {" ".join(str(exc).split())[:200]}') from None
    if isinstance(data, dict) and 'variants' in data:
        data = data['variants']
    if not isinstance(data, list) or not data:
        raise ValueError(f'{path}: must be a non-empty list of variants (mappings "effect.param: value"), '
                         f'got {excerpt(data)}')
    if len(data) > MAX_RUNS:
        raise ValueError(f'{path}: at most {MAX_RUNS} variants, got {len(data)}')
    out = []
    for i, v in enumerate(data, start=1):
        if not isinstance(v, dict) or not v:
            raise ValueError(f'{path}: variant {i} must be a non-empty mapping "effect.param: value", '
                             f'got {excerpt(v)}')
        for key, value in v.items():
            if not isinstance(key, str) or '.' not in key:
                raise ValueError(f'{path}: variant {i}: key {excerpt(key)} must be a scene path like '
                                 f'"regulator_lag.tau_s"')
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f'{path}: variant {i}: {key} must be a finite number, got {excerpt(value)}')
        out.append(dict(v))
    return out


def variant_label(variant: dict) -> str:
    return ', '.join(f'{k} = {v:.4g}' for k, v in variant.items())


@dataclass
class SeedRow:
    """One knob value on one curve over the runs (seeds or variants): the run's Row each."""

    runs: list[Row]
    axis: str = 'seed'

    def __getattr__(self, name):
        # knob, value, metrics, plane: the same in every run
        runs = self.__dict__.get('runs')
        if runs and name in ('knob', 'value', 'accuracy_metric', 'time_metric', 'plane', 'curve'):
            return getattr(runs[0], name)
        raise AttributeError(name)

    @property
    def key(self) -> tuple:
        r = self.runs[0]
        return r.knob, float(r.value), r.accuracy_metric, r.time_metric, bool(r.plane)

    def _ok(self, which: str) -> list[Row]:
        return [r for r in self.runs if r.stats(which)['n']]

    def values(self, which: str, stat: str = 'mean') -> list[float]:
        """The run's `stat` of `which` ('accuracy', 'time') per run (nan where it has no sample)."""
        return [r.stats(which)[stat] if r.stats(which)['n'] else math.nan for r in self.runs]

    def interval(self, which: str, stat: str = 'mean') -> tuple[float, float, float, int]:
        return t_interval(self.values(which, stat))

    def stats(self, which: str) -> dict:
        """The per-run figures averaged over the runs; n: samples of every run together."""
        ok = self._ok(which)
        if not ok:
            return dict(mean=math.nan, sd=math.nan, p10=math.nan, p90=math.nan, n=0, se=math.nan)
        s = [r.stats(which) for r in ok]
        out = {k: float(np.mean([x[k] for x in s])) for k in ('mean', 'sd', 'p10', 'p90', 'se')}
        out['n'] = int(sum(x['n'] for x in s))
        return out

    def whisker(self, which: str) -> float:
        """Half the 95 % interval over the runs; one run: its SE over wearer means."""
        mean, lo, hi, k = self.interval(which)
        if k >= 2:
            return (hi - lo) / 2.0
        return self.runs[0].wearer_se(which)[0]

    def wearer_se(self, which: str) -> tuple[float, int]:
        ses = [r.wearer_se(which) for r in self._ok(which)]
        if not ses:
            return math.nan, 0
        return float(np.mean([s for s, _ in ses])), int(round(np.mean([n for _, n in ses])))

    def _distinct(self, texts: list[str]) -> list[str]:
        return list(dict.fromkeys(t for t in texts if t))

    @property
    def note(self) -> str:
        """The runs' note when they agree, else the first run's (every run's own is in the
        per-run table)."""
        notes = [r.note for r in self.runs]
        if len(self._distinct(notes)) <= 1:
            return (self._distinct(notes) or [''])[0]
        return f'first {self.axis}: {notes[0] or "none"} (the {self.axis}s differ; each in the per-{self.axis} table)'

    @property
    def caveat(self) -> str:
        """The runs' caveat when they agree, else in how many runs there is one, and the first."""
        caveats = [r.caveat for r in self.runs]
        distinct = self._distinct(caveats)
        if len(distinct) <= 1 and all(caveats):
            return (distinct or [''])[0]
        if not distinct:
            return ''
        return f'in {sum(1 for c in caveats if c)} of {len(caveats)} {self.axis}s, e.g. {distinct[0]}'

    def as_record(self, labels: Sequence, axis: str = 'seed') -> dict:
        a, t = self.stats('accuracy'), self.stats('time')
        a_se, wearers = self.wearer_se('accuracy')
        t_se, _ = self.wearer_se('time')
        rec = dict(knob=self.knob, value=self.value, accuracy_metric=self.accuracy_metric,
                   accuracy_mean=a['mean'], accuracy_sd=a['sd'], accuracy_p10=a['p10'], accuracy_p90=a['p90'],
                   accuracy_se=a_se, time_metric=self.time_metric, time_mean=t['mean'], time_sd=t['sd'],
                   time_p10=t['p10'], time_p90=t['p90'], time_se=t_se, n=a['n'], n_time=t['n'],
                   wearers=wearers, plane=self.plane, note=self.note)
        rec[f'{axis}s'] = len(self.runs)
        for fig in INTERVAL_FIGURES:
            which, stat = fig.split('_', 1)
            _, lo, hi, _ = self.interval(which, stat)
            rec[f'{fig}_lo'], rec[f'{fig}_hi'] = lo, hi
        for label, a_v, t_v in zip(labels, self.values('accuracy'), self.values('time')):
            rec[f'accuracy_mean_{axis}{label}'] = a_v
            rec[f'time_mean_{axis}{label}'] = t_v
        return rec


@dataclass
class SeedSweep:
    """The sweep repeated over runs: `axis` 'seed' (labels: the seeds) or 'variant' (labels
    1..k, `variants` the scene values of each)."""

    settings: Settings
    labels: list
    sweeps: list[SweepResult]
    rows: list[SeedRow]
    wall_s: float
    axis: str = 'seed'
    variants: list = field(default_factory=list)
    readings: dict = field(default_factory=dict)

    @property
    def scenes(self):
        return self.sweeps[0].scenes

    @property
    def knob_wall_s(self) -> dict:
        out: dict = {}
        for s in self.sweeps:
            for k, v in s.knob_wall_s.items():
                out[k] = out.get(k, 0.0) + v
        return out

    @property
    def runs(self) -> int:
        return len(self.labels)

    def columns(self) -> list[str]:
        cols = list(CSV_COLUMNS) + [f'{self.axis}s']
        cols += [f'{f}_{e}' for f in INTERVAL_FIGURES for e in ('lo', 'hi')]
        cols += [f'{m}_mean_{self.axis}{lab}' for lab in self.labels for m in ('accuracy', 'time')]
        return cols

    def frame(self) -> pd.DataFrame:
        recs = [r.as_record(self.labels, self.axis) for r in self.rows
                if r.stats('accuracy')['n'] and r.stats('time')['n']]
        return pd.DataFrame(recs, columns=self.columns())

    def per_run_frame(self) -> pd.DataFrame:
        """Every run's own table, one block per seed or variant."""
        parts = []
        for label, s in zip(self.labels, self.sweeps):
            f = s.frame()
            f.insert(0, self.axis, label)
            parts.append(f)
        return pd.concat(parts, ignore_index=True)

    def curves(self) -> dict[tuple[str, str, str], list[SeedRow]]:
        out: dict = {}
        for r in self.rows:
            out.setdefault(r.curve, []).append(r)
        return out

    def find(self, knob: str, value: float, accuracy_metric: str, time_metric: str,
             plane: bool | None = None) -> SeedRow | None:
        for r in self.rows:
            if (r.knob, r.accuracy_metric, r.time_metric) == (knob, accuracy_metric, time_metric) \
                    and math.isclose(float(r.value), float(value), rel_tol=1e-9, abs_tol=1e-15) \
                    and (plane is None or bool(r.plane) == plane):
                return r
        return None


def combine(settings: Settings, labels: list, sweeps: list[SweepResult], wall_s: float = 0.0,
            axis: str = 'seed', variants: list | None = None) -> SeedSweep:
    """The runs' rows matched by knob, value, metrics and plane (every run has the same grids),
    in the first run's order."""
    keyed = []
    for s in sweeps:
        keyed.append({(r.knob, float(r.value), r.accuracy_metric, r.time_metric, bool(r.plane)): r
                      for r in s.rows})
    rows = []
    for key, first in keyed[0].items():
        runs = [k.get(key) for k in keyed]
        if all(r is not None for r in runs):
            rows.append(SeedRow(runs, axis))
    return SeedSweep(settings, list(labels), list(sweeps), rows, wall_s, axis, list(variants or []))


def run_seeds(settings: Settings, seeds: Sequence[int],
              progress: Callable[[str], None] | None = None) -> SeedSweep:
    """The whole sweep on every seed (one seed: exactly run_sweep's lines and numbers)."""
    say = progress or (lambda line: None)
    start = time.perf_counter()
    sweeps = []
    for i, seed in enumerate(seeds, start=1):
        prefix = '' if len(seeds) == 1 else f'seed {seed} ({i}/{len(seeds)}) '
        sweeps.append(run_sweep(replace(settings, seed=seed), lambda line: say(prefix + line)))
    return combine(settings, list(seeds), sweeps, time.perf_counter() - start)


def check_variants(settings: Settings, variants: list[dict], seed: int | None = None) -> Settings:
    """The settings the variants run with; ValueError naming the first variant whose values the
    scenes do not have or do not accept."""
    base = replace(settings, knobs=(), plane=True, seed=seed)
    for i, v in enumerate(variants, start=1):
        try:
            base_scenes(replace(base, overrides=tuple(v.items())))
        except ValueError as exc:
            raise ValueError(f'variant {i}: {exc}') from None
    check_settings(base, base_scenes(base)[0])
    return base


def run_variants(settings: Settings, variants: list[dict], seed: int | None = None,
                 progress: Callable[[str], None] | None = None) -> SeedSweep:
    """The headline configuration (conditions 1-4 at the package defaults, both protocols) on
    each variant of the scenes' values, all at one seed (the same wearers: the variants differ
    by their values only)."""
    say = progress or (lambda line: None)
    base = check_variants(settings, variants, seed)
    start = time.perf_counter()
    sweeps = []
    for i, v in enumerate(variants, start=1):
        say(f'variant {i}/{len(variants)}: {variant_label(v)}')
        sweeps.append(run_sweep(replace(base, overrides=tuple(v.items())),
                                lambda line: say(f'variant {i} {line}')))
    return combine(base, list(range(1, len(variants) + 1)), sweeps, time.perf_counter() - start,
                   'variant', variants)


# ------------------------------------------------------------------------- the headline checks

@dataclass
class Headline:
    """One headline finding checked on every run: the per-run differences that make it, their
    interval, and whether it holds on the interval (every part excludes zero the stated way)."""

    name: str
    claim: str
    parts: list          # (what, unit, per-run differences, (mean, lo, hi, k)); the claim: > 0
    ran: bool = True

    @property
    def holds(self) -> bool | None:
        """True: holds on the interval; False: does not; None: not run or one run."""
        if not self.ran:
            return None
        if any(p[3][3] < 2 for p in self.parts):
            return None
        return all(excludes_zero(p[3][1], p[3][2]) and p[3][0] > 0 for p in self.parts)


def _diff(a: SeedRow | None, b: SeedRow | None, which: str) -> list[float] | None:
    if a is None or b is None:
        return None
    return [x - y for x, y in zip(a.values(which), b.values(which))]


def headlines(result: SeedSweep) -> list[Headline]:
    """The three headline findings of docs/tradeoff.md, each as per-run paired differences
    (positive: the finding holds in that run):

    1. accuracy is bought by the modality: speech (condition 4) lands closer than the suit
       (condition 1) at the key press, and takes longer to find a target;
    2. Eq. 5's adjustment makes the suit accurate: G = 0 leaves a larger key-press error than
       the package's G (the gain sweep, accuracy protocol);
    3. condition 1 finds a target faster than condition 2 (speed protocol).
    """
    plane = ('guidance_error_deg', 'time_to_find_s')
    c = {k: result.find('condition', k, *plane, plane=True) for k in (1, 2, 4)}
    out = []
    parts = []
    for what, unit, d in (('condition 1 minus condition 4, key-press error', 'deg',
                           _diff(c[1], c[4], 'accuracy')),
                          ('condition 4 minus condition 1, time to find a target', 's',
                           _diff(c[4], c[1], 'time'))):
        if d is not None:
            parts.append((what, unit, d, t_interval(d)))
    out.append(Headline('modality', 'accuracy is bought by the modality: speech guides closer than the suit '
                        'and takes longer per target', parts, len(parts) == 2))
    g_ref = KNOB['gain'].reference
    acc = ('guidance_error_deg', 'time_to_key_press_s')
    d = _diff(result.find('gain', 0.0, *acc, plane=False), result.find('gain', g_ref, *acc, plane=False),
              'accuracy')
    out.append(Headline('adjustment', f"Eq. 5's adjustment makes the suit accurate: G = 0 leaves a larger "
                        f'key-press error than G = {g_ref:g}',
                        [] if d is None else [(f'G = 0 minus G = {g_ref:g}, key-press error', 'deg', d,
                                               t_interval(d))], d is not None))
    d = _diff(c[2], c[1], 'time')
    out.append(Headline('c1_faster', 'condition 1 finds a target faster than condition 2',
                        [] if d is None else [('condition 2 minus condition 1, time to find a target', 's', d,
                                               t_interval(d))], d is not None))
    return out
