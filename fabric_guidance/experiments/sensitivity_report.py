"""The outputs of `fabric-guidance sensitivity` (sensitivity.py): the CSV, the Markdown table
sorted by the largest move in seed SDs against the baseline's interval over seeds, and the
tornado plot per headline figure."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..atomic import atomic_write, write_csv, write_text
from ..core.plot_style import condition_label, measure_label, wrap
from .analysis_report import image_path, md_table
from .sensitivity_runs import HEADLINE_TITLES, HEADLINES, MEASURED, SensitivityResult


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
    iv = result.seed_interval()
    k = len(result.baselines)
    seed0 = result.baselines[0].seed

    def base_cell(h):
        if k < 2:
            return f'{_fmt(base[h])} (one seed: no interval)'
        return (f'{_fmt(base[h])} at seed {seed0}; mean over {k} seeds {_fmt(iv[h][0])} '
                f'[{_fmt(iv[h][1])}, {_fmt(iv[h][2])}], seed SD {_fmt(sd[h])}; noise +-{_fmt(result.noise(h, sd))}')
    rows = [['baseline', '', f'{k} seed(s)'] + [base_cell(h) for h in HEADLINES] + ['']]
    for key, z, h in result.ranking():
        p = params[key]
        lo, hi = by.get((key, 'low')), by.get((key, 'high'))
        vals = ' / '.join(_fmt(r.value) if r else '-' for r in (lo, hi))
        cells = []
        for name in HEADLINES:
            cells.append(' / '.join(_signed(r.figures[name] - base[name]) if r else '-'
                                    for r in (lo, hi)))
        moved = set()
        for r in (lo, hi):
            if r is not None:
                moved.update(result.beyond(r, sd))
        mark = ' **beyond noise**' if moved else ''
        unit = f' {p.unit}' if p.unit and p.unit != '-' else ''
        rows.append([key, f'{_fmt(p.value)}{unit}', vals] + cells + [f'{z:.1f} ({h}){mark}'])
    return '\n'.join(md_table(header, rows, 'lrr' + 'r' * len(HEADLINES) + 'l'))


#: Per headline figure: (condition(s), what it is on the x axis, never negative). The targets
#: are per 40 s whatever the trials' length (sensitivity_runs scales them so).
PANELS = {'c1_targets': ((1,), measure_label('identified', 40.0), True),
          'c1_minus_c2': ((1, 2), 'difference in ' + measure_label('identified', 40.0), False),
          'c4_targets': ((4,), measure_label('identified', 40.0), True),
          'c1_error_deg': ((1,), 'error at the key press (deg, hypot of h and v)', True),
          'c4_error_deg': ((4,), 'error at the key press (deg, hypot of h and v)', True)}


def _panel_title(conditions) -> str:
    if len(conditions) == 2:
        return f'condition {conditions[0]} minus condition {conditions[1]}'
    return wrap(f'condition {condition_label(conditions[0])}', 30)


def plot_tornado(result: SensitivityResult, path: Path, dpi: int = 120) -> Path:
    """One panel per figure (its conditions in plot_style's names, the figure with its unit on
    the x axis): for each parameter (sorted by its largest move, the largest on top) a bar from
    the baseline to the low run (blue) and to the high run (orange); the grey band is the noise
    (+-2 seed SDs of the baseline), the hatched one the interval of the baseline's mean; a band
    of a figure that cannot be negative is cut at 0, and the legend says so."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    ranking = [k for k, _, _ in result.ranking()]
    n = max(len(ranking), 1)
    fig = Figure(figsize=(3.3 * len(HEADLINES) + 2.6, 2.6 + 0.32 * n), layout='constrained')
    FigureCanvasAgg(fig)
    by = {(r.parameter, r.side): r for r in result.runs}
    base, sd = result.baseline, result.seed_sd()
    iv = result.seed_interval()
    axes = fig.subplots(1, len(HEADLINES), sharey=True)
    ypos = {k: n - 1 - i for i, k in enumerate(ranking)}
    cut = False
    for ax, h in zip(np.atleast_1d(axes), HEADLINES):
        conditions, xlabel, positive = PANELS[h]
        floor = 0.0 if positive else -math.inf
        b = base[h]
        noise = result.noise(h, sd)
        if math.isfinite(noise):
            cut |= b - noise < floor
            ax.axvspan(max(b - noise, floor), b + noise, color='0.85', zorder=0)
        if math.isfinite(iv[h][1]):
            cut |= iv[h][1] < floor
            ax.axvspan(max(iv[h][1], floor), iv[h][2], fill=False, hatch='///', ec='0.45', lw=0, zorder=0)
        ax.axvline(b, color='black', lw=1.0, zorder=1)
        for key in ranking:
            y = ypos[key]
            for side, colour, dy in (('low', 'tab:blue', 0.18), ('high', 'tab:orange', -0.18)):
                r = by.get((key, side))
                if r is not None and math.isfinite(r.figures[h]):
                    ax.barh(y + dy, r.figures[h] - b, left=b, height=0.34, color=colour, zorder=2)
        ax.set_title(_panel_title(conditions), fontsize=9)
        ax.set_xlabel(wrap(xlabel, 34), fontsize=8)
        ax.grid(axis='x', alpha=0.3)
        ax.tick_params(axis='x', labelsize=8)
        if positive:
            ax.set_xlim(left=max(ax.get_xlim()[0], 0.0))
    first = np.atleast_1d(axes)[0]
    first.set_yticks(list(ypos.values()), list(ypos.keys()), fontsize=8)
    first.set_ylim(-0.7, n - 0.3)
    s = result.settings
    k = len(result.baselines)
    band = (f'grey band: the noise, +-{result.noise_sds():.2f} seed SDs (95 % prediction interval of one '
            f'seed from {k})' if k > 1 else 'one seed: no interval, no noise band')
    fig.suptitle(f'Sensitivity of the headline figures to the assumed parameters: x{s.low:g} blue, '
                 f'x{s.high:g} orange; black line: the baseline at seed {result.baselines[0].seed}\n'
                 f'{band}; {s.subjects} wearers, scenes {result.scenes[0].name} / {result.scenes[1].name}; '
                 'sorted by the largest move in seed SDs', fontsize=10)
    handles = [Patch(color='tab:blue', label=f'low (x{s.low:g})'),
               Patch(color='tab:orange', label=f'high (x{s.high:g})'),
               Patch(color='0.85', label='baseline +- noise (one seed\'s 95 % prediction interval)'),
               Patch(fill=False, hatch='///', ec='0.45', label=f'95 % interval of the mean over {k} seeds')]
    if cut:
        handles.append(Patch(color='white', label='bands cut at 0: targets and errors are never negative'))
    fig.legend(handles=handles, loc='outside lower center', ncol=3, fontsize=8, frameon=False)
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
    sd = result.seed_sd()
    moved = {}
    for r in result.runs:
        moved.setdefault(r.parameter, set()).update(result.beyond(r, sd))
    beyond = [(k, z, h) for k, z, h in result.ranking() if moved.get(k)]
    nk = len(result.baselines)
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
             f'Moves from the baseline (first row: the baseline at seed {spd.seed}, its mean over '
             f'{nk} seed(s) (other wearers and targets) with the 95 % t interval of that mean, the seed SD, '
             'and the noise). Sorted by the largest move in seed SDs. '
             + (f'**beyond noise**: a move larger than the noise, the half-width of the 95 % prediction interval '
                f'of one seed\'s figure from the {nk} baseline seeds: t(0.975, {nk - 1}) x sqrt(1 + 1/{nk}) = '
                f'{result.noise_sds():.2f} seed SDs (a seed SD below the figure\'s resolution is raised to it). '
                'A paired move can be real below that, but is not shown to matter on this many wearers.'
                if nk > 1 else '**One baseline seed: no interval over seeds, so no move is called beyond '
                'noise** (run --seeds 3 or more).'), '',
             markdown_table(result), '']
    if beyond:
        lines += [f'{len(beyond)} of {len(result.ranking())} parameters move a figure beyond '
                  'noise: '
                  + ', '.join(f'`{k}` ({h}, {z:.1f} SD)' for k, z, h in beyond) + '.', '']
    else:
        lines += ['No parameter moves a figure beyond noise.', '']
    skipped = sorted({f'{e}.{p}' for e, p in MEASURED} | set(s.exclude))
    if skipped:
        lines += ['Not swept (measured, fitted or excluded): '
                  + ', '.join(f'`{k}`' for k in skipped) + '.', '']
    lines += ['## Tornado plot', '', f'![sensitivity]({image_path(paths["png"], out)})', '']
    write_text(paths['md'], '\n'.join(lines))
    return paths
