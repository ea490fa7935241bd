"""The outputs: tradeoff.csv, the markdown table, tradeoff.md and its plots."""
from __future__ import annotations

from pathlib import Path

import pandas as pd

from ...atomic import write_csv, write_text

from ..analysis_report import image_path, md_table
from .plots import _is_plane_only, plane_curves, plot_knob, plot_plane
from .reading import gain_rate_reading, read_curve
from .settings import CONDITION_LABELS, KNOBS, KNOB_TITLES, REFERENCE
from .sweep import SweepResult, _fmt


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
    write_csv(paths['csv'], frame)
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
    if 'control_rate_hz' in s.knobs:
        lines.append(f'- **control_rate_hz and G**: {gain_rate_reading(result)}')
    lines += ['', '## Plots', '']
    for knob in s.knobs:
        lines += [f'![{knob}]({image_path(paths[knob], out)})', '']
    paths['md'] = out / 'tradeoff.md'
    write_text(paths['md'], '\n'.join(lines).rstrip() + '\n')
    result.readings = readings
    return paths
