"""Rows and curves: a knob value's accuracy and time, with their spread, from the samples."""
from __future__ import annotations

from dataclasses import dataclass
import math
import time
from typing import Sequence

import numpy as np
import pandas as pd

from ...core.geometry import DIRECTIONS
from ...core.power_law import CalibrationFitError, fit_power_law
from ...sim.population import law_angle_error_deg, sample_wearer
from ...sim.scene import Scene


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
    guidance = accuracy_rows('calibration_steps', value, samples, cals, timeout_s)
    guidance.time_metric = 'calibration_time_s'
    guidance.time = _wearer_time(cals)
    law = [dict(subject=o.subject, direction=d, error=o.angle_error_deg[d])
           for o, _ in cals.values() if o.ok for d in DIRECTIONS]
    law_row = Row('calibration_steps', value, 'law_angle_error_deg', 'calibration_time_s',
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
