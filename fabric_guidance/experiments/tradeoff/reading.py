"""Reading the curves: the generated prose of tradeoff.md, from the numbers by the rules of
read_curve."""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np
import pandas as pd

from .intervals import SeedRow, SeedSweep, excludes_zero, headlines, t_interval
from .rows import Row
from .settings import KNOB_SYMBOLS, METRICS, REFERENCE
from .sweep import SweepResult, _fmt


#: Changes below this fraction of the curve's level are called flat whatever the noise: too small
#: to matter (5 %).
FLAT_FRACTION = 0.05
#: On the front, accuracy still to gain below this fraction of the front's range counts as bought.
KNEE_FRACTION = 0.10


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
    rates = curves.get(('control_rate_hz', 'guidance_error_deg', 'time_to_key_press_s'), [])
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


# ------------------------------------------------------------- over seeds or variants: intervals

def interval_text(mean: float, lo: float, hi: float, unit: str = '', signed: bool = False) -> str:
    """'13.2 deg [12.1, 14.3]' (the 95 % interval), or without brackets when there is none."""
    f = (lambda x: ('+' if x > 0 else '') + _fmt(x)) if signed else _fmt    # noqa: E731
    u = f' {unit}' if unit and unit != '-' else ''
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return f'{f(mean)}{u}'
    return f'{f(mean)}{u} [{f(lo)}, {f(hi)}]'


def read_curve_interval(rows: list[SeedRow], reference: float | None = None, axis: str = 'seed') -> str:
    """One curve over k runs (seeds or variants), lower is better on both axes:

    1. the curve's ends and its best value, each as the mean over the runs with its 95 % t
       interval;
    2. every other value against the reference (the package's value; `reference` or the
       grid's first value when the grid lacks it): the difference of the accuracy and of the
       time, paired within each run, stated as a finding only where its interval excludes zero;
    3. the values whose differences cross zero, named as no finding.

    One run has no interval: the reading is then the one-sweep reading (read_curve) of that
    run, and says so."""
    rows = [r for r in rows if r.stats('accuracy')['n'] and r.stats('time')['n']]
    if not rows:
        return 'No value produced a sample: nothing to read.'
    k = len(rows[0].runs)
    if k < 2:
        return (f'One {axis}: no interval over {axis}s (the spread below is over this {axis}\'s '
                'wearers and trials). ' + read_curve([r.runs[0] for r in rows]))
    knob = rows[0].knob
    sym = KNOB_SYMBOLS[knob]
    a_name, t_name = METRICS[rows[0].accuracy_metric][0], METRICS[rows[0].time_metric][0].split(' (')[0]
    au, tu = METRICS[rows[0].accuracy_metric][1], METRICS[rows[0].time_metric][1]
    vals = [r.value for r in rows]
    A = [r.interval('accuracy') for r in rows]
    T = [r.interval('time') for r in rows]
    best = int(np.argmin([a[0] for a in A]))
    s1 = (f'Over {k} {axis}s (mean [95 % t interval over the {axis}s]): {a_name} goes from '
          f'{interval_text(*A[0][:3], au)} at {sym} = {vals[0]:g} to {interval_text(*A[-1][:3], au)} at '
          f'{vals[-1]:g} (best mean {interval_text(*A[best][:3], au)} at {vals[best]:g}); the {t_name} from '
          f'{interval_text(*T[0][:3], tu)} to {interval_text(*T[-1][:3], tu)}.')
    if len(rows) == 1:
        return s1
    if reference is None:
        reference = REFERENCE.get(knob, (math.nan, ''))[0]
    ref_i = next((i for i, v in enumerate(vals) if math.isclose(float(v), float(reference), rel_tol=1e-9)), 0)
    ref = rows[ref_i]
    ref_text = _value_text(knob, vals[ref_i]) if knob != 'condition' else f'condition {vals[ref_i]:g}'
    label = (lambda v: f'condition {v:g}') if knob == 'condition' else (lambda v: f'{sym} = {v:g}')  # noqa: E731
    findings, none_a, none_t = [], [], []
    for i, r in enumerate(rows):
        if i == ref_i:
            continue
        parts = []
        for which, unit, short, misses in (('accuracy', au, a_name.split(' (')[0], none_a),
                                           ('time', tu, t_name, none_t)):
            d = [x - y for x, y in zip(r.values(which), ref.values(which))]
            mean, lo, hi, n = t_interval(d)
            if n >= 2 and excludes_zero(lo, hi):
                parts.append(f'{interval_text(mean, lo, hi, unit, signed=True)} {short}')
            else:
                misses.append(f'{vals[i]:g}')
        if parts:
            findings.append(f'{label(vals[i])}: {" and ".join(parts)}')
    s2 = (f'Against {ref_text}, paired within each {axis}, the differences whose interval excludes zero: '
          + ('; '.join(findings) + '.' if findings else 'none.'))
    s3 = []
    if none_a:
        s3.append(f'{a_name.split(" (")[0]} at {", ".join(none_a)}')
    if none_t:
        s3.append(f'{t_name} at {", ".join(none_t)}')
    text = f'{s1} {s2}'
    if s3:
        text += (f' No finding (the interval of the difference from {vals[ref_i]:g} crosses zero): '
                 + '; '.join(s3) + '.')
    caveats = [f'{sym} = {r.value:g}: {r.caveat}' for r in rows if r.caveat]
    if caveats:
        text += ' Caveats (in some runs): ' + '; '.join(caveats) + '.'
    return text


def headline_lines(result: SeedSweep) -> list[str]:
    """A line per headline finding (intervals.headlines): whether it holds on the interval over
    the runs, with the differences that make it."""
    axis, k = result.axis, result.runs
    out = []
    for i, h in enumerate(headlines(result), start=1):
        if not h.ran:
            out.append(f'{i}. **{h.claim}**: not checked (this run did not measure it).')
            continue
        figs = '; '.join(f'{what} {interval_text(*iv[:3], unit, signed=True)} '
                         f'(> 0 in {sum(1 for x in d if x > 0)} of {len(d)} {axis}s)'
                         for what, unit, d, iv in h.parts)
        verdict = {True: f'**holds across {k} {axis}s**', False: f'**does not hold on the interval over {k} '
                   f'{axis}s**', None: f'one {axis}: no interval, not checked across {axis}s'}[h.holds]
        out.append(f'{i}. *{h.claim}*: {verdict}: {figs}.')
    return out
