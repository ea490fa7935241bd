"""The outputs: tradeoff.csv, the markdown table, tradeoff.md and its plots."""
from __future__ import annotations

from pathlib import Path

import pandas as pd

from ...atomic import write_csv, write_text

from ..analysis_report import image_path, md_table
from .intervals import CONFIDENCE, SeedSweep, combine, variant_label
from .plots import _is_plane_only, plane_curves, plot_knob, plot_plane
from .reading import gain_rate_reading, headline_lines, interval_text, read_curve, read_curve_interval
from .settings import CONDITION_LABELS, KNOBS, KNOB_TITLES, REFERENCE
from .sweep import SweepResult, _fmt


def as_seed_sweep(result) -> SeedSweep:
    """A one-sweep result as a sweep over its one seed (the same rows, no interval)."""
    if isinstance(result, SeedSweep):
        return result
    return combine(result.settings, [result.scenes[1].seed], [result], result.wall_s)


def _cell(rec: dict, fig: str) -> str:
    """'mean [lo, hi]' where the row has an interval, else the mean."""
    lo, hi = rec.get(f'{fig}_lo', float('nan')), rec.get(f'{fig}_hi', float('nan'))
    return interval_text(rec[fig], lo, hi)


def plane_text(result: 'SweepResult') -> str:
    s = result.settings
    return ('x: the mean time to find a target in the speed protocol (s, found targets only); '
            'y: the guidance error of the true gaze at the accuracy protocol\'s key press (deg, '
            'hypot of h and v), before any visual capture. Acceptance tolerance, which the '
            'accuracy protocol does not use, has y = the error when a target counts (speed '
            'protocol). Conditions 1-4 at the package defaults; every knob swept in condition '
            f'{s.condition}, both protocols on the same {s.subjects} wearers (common random '
            'numbers). ' + _spread_text(result) + ' The package value of '
            f'each knob other than the tolerance is the condition-{s.condition} point itself.')


def _spread_text(result) -> str:
    k, axis = getattr(result, 'runs', 1), getattr(result, 'axis', 'seed')
    if k > 1:
        return (f'Each figure is the mean over {k} {axis}s with its {CONFIDENCE:.0%} t interval over the '
                f'{axis}s in brackets (whiskers in the plot); SE: the mean over the {axis}s of the SE over '
                'wearer means.')
    return 'Spread: +-1 SE over wearer means (the columns SE); one seed, so no interval over seeds.'


def plane_table(result: 'SweepResult') -> str:
    header = ['knob', 'value', 'y metric', 'y mean', 'y SE', 'time to find (s)', 'time SE',
              'wearers', 'note']
    rows = []
    curves = plane_curves(result)
    labels, axis = getattr(result, 'labels', []), getattr(result, 'axis', 'seed')
    for knob in ('condition',) + tuple(k for k in KNOBS if k in curves):
        for r in curves.get(knob, []):
            rec = r.as_record(labels, axis) if hasattr(r, 'runs') else r.as_record()
            value = CONDITION_LABELS.get(int(r.value),
                                         f'{r.value:g}') if knob == 'condition' else f'{r.value:g}'
            rows.append([knob, value, r.accuracy_metric, _cell(rec, 'accuracy_mean'),
                         _fmt(rec['accuracy_se']),
                         _cell(rec, 'time_mean'), _fmt(rec['time_se']), rec['wearers'], r.note])
    return '\n'.join(md_table(header, rows, 'llrrrrrrl'))


def markdown_table(frame: pd.DataFrame) -> str:
    header = ['knob', 'value', 'accuracy metric', 'mean', 'SD', 'p10 to p90', 'time metric', 'mean', 'SD',
              'p10 to p90', 'n']
    rows = []
    for rec in frame.to_dict('records'):
        c = lambda fig: _cell(rec, fig)  # noqa: E731
        rows.append([rec['knob'], f'{rec["value"]:g}', rec['accuracy_metric'], c('accuracy_mean'), c('accuracy_sd'),
                     f'{c("accuracy_p10")} to {c("accuracy_p90")}', rec['time_metric'], c('time_mean'),
                     c('time_sd'), f'{c("time_p10")} to {c("time_p90")}', int(rec['n'])])
    return '\n'.join(md_table(header, rows, 'lrlrrrlrrrr'))


def _readings(result: SeedSweep) -> dict:
    curves = result.curves()
    cond = result.settings.condition
    return {c: read_curve_interval(rows, cond if c[0] == 'condition' else None, result.axis)
            if result.runs > 1 else read_curve([r.runs[0] for r in rows]) for c, rows in curves.items()}


def _runs_text(result: SeedSweep) -> str:
    if result.axis == 'variant':
        return (f'{result.runs} variant(s) of the scenes\' values, all at seed {result.scenes[1].seed} '
                '(the same wearers, targets and noise)')
    if result.runs == 1:
        return (f'one seed ({result.labels[0]}): the spreads are over its wearers and trials; a run on one '
                'seed has no interval over seeds (--seeds N gives one)')
    return (f'{result.runs} seeds ({", ".join(map(str, result.labels))}): each seed new wearers, targets '
            f'and noise; every figure is the mean over the seeds with its {CONFIDENCE:.0%} t interval over '
            'the seeds in brackets (mean +- t(0.975, k-1) x SD / sqrt(k) of the k seed values)')


def write_outputs(result, out: Path) -> dict[str, Path]:
    """DIR/tradeoff.csv, DIR/<knob>.png, DIR/tradeoff.md (and, over several seeds,
    DIR/tradeoff_per_seed.csv); returns the paths by name. `result`: a SweepResult (one seed)
    or a SeedSweep."""
    result = as_seed_sweep(result)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    frame = result.frame()
    paths = {'csv': out / 'tradeoff.csv'}
    write_csv(paths['csv'], frame)
    if result.runs > 1:
        paths['per_seed'] = out / 'tradeoff_per_seed.csv'
        write_csv(paths['per_seed'], result.per_run_frame())
    curves = result.curves()
    readings = _readings(result)
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
             f'Runs: {_runs_text(result)}. '
             f'Sweep wall time {result.wall_s:.0f} s with {s.workers} worker(s)'
             + (' (--quick: tiny population and grids)' if s.quick else '') + '.', '']
    if result.runs > 1 or s.plane:
        lines += ['## Headline findings across the ' + result.axis + 's', '',
                  f'Each finding as paired differences within each {result.axis} (positive: it holds in that '
                  f'{result.axis}), mean [{CONFIDENCE:.0%} t interval over the {result.axis}s]; it **holds** when '
                  'every difference\'s interval lies above zero.', ''] + headline_lines(result) + ['']
    lines += ['## Grids', '']
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
              'wearer x direction or fits). Spread: SD (ddof 1), p10-p90 over those samples'
              + (f'; each the mean over the {result.runs} {result.axis}s, with its interval over them in '
                 f'brackets; every {result.axis}\'s own table: {paths["per_seed"].name}'
                 if result.runs > 1 else '') + '.', '']
    notes = [(r.knob, r.value, r.note) for r in result.rows if r.note]
    if notes:
        lines += ['Notes per value' + (f' (distinct notes of the {result.axis}s separated by |)'
                                       if result.runs > 1 else '') + ':', '']
        seen = set()
        for knob, value, note in notes:
            if (knob, value, note) not in seen:
                seen.add((knob, value, note))
                lines.append(f'- {knob} {value:g}: {note}')
        lines.append('')
    rule = 'read_curve_interval' if result.runs > 1 else 'read_curve'
    lines += ['## Reading', '',
              f'Generated from the numbers (rules in `fabric_guidance.experiments.tradeoff.{rule}`).', '']
    for (knob, am, tm), text in readings.items():
        lines.append(f'- **{knob}** ({am} against {tm}): {text}')
    if 'control_rate_hz' in s.knobs:
        first = result.sweeps[0]
        prefix = f'(seed {result.labels[0]} alone, paired SEs) ' if result.runs > 1 else ''
        lines.append(f'- **control_rate_hz and G**: {prefix}{gain_rate_reading(first)}')
    lines += ['', '## Plots', '']
    for knob in s.knobs:
        lines += [f'![{knob}]({image_path(paths[knob], out)})', '']
    paths['md'] = out / 'tradeoff.md'
    write_text(paths['md'], '\n'.join(lines).rstrip() + '\n')
    result.readings = readings
    return paths


def variants_table(result: SeedSweep) -> str:
    """Per condition: each figure's mean over the variants [t interval], its range over them."""
    header = ['condition', 'key-press error (deg)', 'range over variants', 'time to find (s)',
              'range over variants', 'variants']
    rows = []
    for r in plane_curves(result).get('condition', []):
        a, t = r.values('accuracy'), r.values('time')
        rows.append([CONDITION_LABELS.get(int(r.value), f'{r.value:g}'),
                     interval_text(*r.interval('accuracy')[:3]), f'{_fmt(min(a))} to {_fmt(max(a))}',
                     interval_text(*r.interval('time')[:3]), f'{_fmt(min(t))} to {_fmt(max(t))}',
                     len(r.runs)])
    return '\n'.join(md_table(header, rows, 'lrrrrr'))


def write_variant_outputs(result: SeedSweep, out: Path) -> dict[str, Path]:
    """DIR/variants.csv (one row per condition: the means, intervals and every variant's
    value), DIR/variants_per_run.csv, DIR/variants.md, DIR/variants.png (the plane)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = {'csv': out / 'variants.csv', 'per_run': out / 'variants_per_run.csv', 'md': out / 'variants.md'}
    write_csv(paths['csv'], result.frame())
    per = result.per_run_frame()
    per.insert(1, 'values', [variant_label(result.variants[int(v) - 1]) for v in per['variant']])
    write_csv(paths['per_run'], per)
    paths['png'] = plot_plane(result, out / 'variants.png',
                              title='Conditions 1-4 at the package defaults over variants of the scenes\' values')
    s = result.settings
    acc, spd = result.scenes
    lines = ['# The headline configuration over variants of the scenes\' values', '',
             f'Scenes `{acc.name}` / `{spd.name}`, conditions 1-4 at the package defaults, the first '
             f'{s.subjects} wearers, {s.repetitions} accuracy trials and {s.speed_repetitions} speed trials of '
             f'{spd.protocol.trial_s:g} s per wearer and condition. Runs: {_runs_text(result)}. Wall time '
             f'{result.wall_s:.0f} s with {s.workers} worker(s)' + (' (--quick)' if s.quick else '') + '.', '',
             'Each figure: the mean over the variants with its '
             f'{CONFIDENCE:.0%} t interval over them in brackets (the uncertainty of that mean), and the range '
             'of the variants\' own values (the spread the parameters\' uncertainty gives one figure).', '',
             variants_table(result), '', '## Headline findings across the variants', ''] + \
        headline_lines(result) + ['', '## Variants', '']
    lines += [f'{i}. {variant_label(v)}' for i, v in enumerate(result.variants, start=1)]
    lines += ['', f'![variants]({image_path(paths["png"], out)})', '']
    write_text(paths['md'], '\n'.join(lines))
    return paths
