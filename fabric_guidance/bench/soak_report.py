"""The soak run's outputs, apart from the run (bench/soak.py): the verdict on drift (a
least-squares slope per hour with its 95 % interval for every figure), soak.md's summary and the
plot of every figure over time. Plain rows in, no ROS."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..atomic import write_bytes

#: A figure drifts when its slope exceeds this fraction of its mean per hour (and its floor).
RELATIVE = 0.10
#: The least slope per hour that counts, per kind of figure (where the mean is near zero).
FLOORS = {'ms': 0.1, 'MB': 1.0, 's/min': 0.1, 'count': 1.0, 'per row': 1.0, 's': 0.1}


# ---------------------------------------------------------------- the verdict
def drift(t_h, y, unit: str) -> dict:
    """Least-squares slope of y per hour with its 95 % interval (Student t, n - 2 degrees of
    freedom), and the verdict: DRIFTS when the interval excludes zero and |slope| exceeds the
    threshold, max(RELATIVE * |mean|, FLOORS[unit]), with its direction ('DRIFTS up', 'DRIFTS
    down'); 'steady' when the interval holds zero; 'small' when it does not but the slope is below
    the threshold."""
    from scipy import stats
    t_h, y = np.asarray(t_h, dtype=float), np.asarray(y, dtype=float)
    ok = np.isfinite(t_h) & np.isfinite(y)
    t_h, y = t_h[ok], y[ok]
    out = {'n': int(len(y)), 'mean': float(y.mean()) if len(y) else None, 'unit': unit}
    if len(y) < 3 or np.ptp(t_h) == 0:
        return {**out, 'slope_per_h': None, 'low': None, 'high': None, 'threshold': None,
                'verdict': 'too few rows'}
    threshold = max(RELATIVE * abs(out['mean']), FLOORS[unit])
    if np.ptp(y) == 0:
        slope = stderr = 0.0
    else:
        fit = stats.linregress(t_h, y)
        slope, stderr = float(fit.slope), float(fit.stderr)
    half = float(stats.t.ppf(0.975, len(y) - 2)) * stderr
    low, high = slope - half, slope + half
    excludes = low > 0 or high < 0
    if not excludes:
        verdict = 'steady'
    elif abs(slope) > threshold:
        verdict = 'DRIFTS up' if slope > 0 else 'DRIFTS down'
    else:
        verdict = 'small'
    return {**out, 'slope_per_h': slope, 'low': low, 'high': high, 'threshold': threshold, 'verdict': verdict}


#: The figures for which fewer is worse: everything else drifts the wrong way upwards.
DOWN_IS_WORSE = ('targets_reached',)


def harmful(column: str, result: dict) -> bool:
    """A drift the lab must act on: upwards, or downwards for DOWN_IS_WORSE."""
    return result['verdict'] == ('DRIFTS down' if column in DOWN_IS_WORSE else 'DRIFTS up')


def verdicts(rows: list[dict], figures: dict[str, str], columns) -> dict[str, dict]:
    """Every figure of `figures` (column or per-node prefix -> unit; one per node for the per-node
    ones, as `columns` has them) over the rows."""
    t_h = [(r['t_start_s'] + r['t_end_s']) / 2 / 3600 for r in rows]
    out = {}
    for figure, unit in figures.items():
        for col in [c for c in columns if c == figure or c.startswith(figure + '.')]:
            out[col] = drift(t_h, [number(r.get(col)) for r in rows], unit)
    return out


def number(v, missing=math.nan):
    """A cell of a row or a diagnostics value as a float; `missing` where it holds none (empty,
    absent, not a number). The one parser of soak's rows and counters."""
    try:
        return float(v)
    except (TypeError, ValueError):
        return missing


def verdict_table(results: dict[str, dict]) -> list[str]:
    def f(v):
        return '—' if v is None else f'{v:+.3g}'
    lines = ['| figure | mean | slope per hour | 95 % interval | threshold | verdict |',
             '| --- | --- | --- | --- | --- | --- |']
    for col, r in results.items():
        mean = '—' if r['mean'] is None else f"{r['mean']:.3g} {r['unit']}"
        interval = '—' if r['low'] is None else f"[{f(r['low'])}, {f(r['high'])}]"
        threshold = '—' if r['threshold'] is None else f"{r['threshold']:.3g}"
        lines.append(f"| {col} | {mean} | {f(r['slope_per_h'])} | {interval} | {threshold} | {r['verdict']} |")
    return lines


def summary(rows: list[dict], results: dict[str, dict], args: dict, problems: list[str], latency: str) -> str:
    drifting = [f"{c} ({r['verdict'][7:]})" for c, r in results.items() if r['verdict'].startswith('DRIFTS')]
    stalls = [r for r in rows if r['stall']]
    head = (f"Soak run: {len(rows)} rows of {args['row_seconds']:g} s ({args['minutes']:g} min asked). "
            + ('No figure drifts.' if not drifting else f"Drifting: {', '.join(drifting)}.")
            + (f' {len(stalls)} row(s) stalled.' if stalls else ' No row stalled.')) if rows else (
        f"Soak run: no row written ({args['minutes']:g} min asked); see the problems below.")
    lines = [head, '', f'Latency: {latency}', '',
             f'Verdict per figure: least-squares slope per hour over the rows with its 95 % interval (Student t, '
             f'n - 2 degrees of freedom); DRIFTS (up or down) only where the interval excludes zero and the slope '
             f'exceeds the threshold, {RELATIVE:.0%} of the mean per hour or the floor of its unit '
             f"({', '.join(f'{v:g} {k}' for k, v in FLOORS.items())}), whichever is larger; 'small' where the "
             "interval excludes zero below the threshold. Counts per row are per row of the run. The exit code "
             f"is 1 for a drift upwards (downwards for {', '.join(DOWN_IS_WORSE)}), a stalled row or a problem.",
             '',
             *verdict_table(results)]
    if stalls:
        lines += ['', 'Stalled rows:', '']
        lines += [f"- row {r['row']} ({r['t_start_s'] / 60:.1f}-{r['t_end_s'] / 60:.1f} min): {r['stall']}; "
                  f"{r['targets_reached']} reached, {r['targets_skipped']} skipped"
                  + (f"; {r['warnings']}" if r['warnings'] else '') for r in stalls]
    if problems:
        lines += ['', 'Problems:', ''] + [f'- {p}' for p in problems]
    return '\n'.join(lines) + '\n'


# ---------------------------------------------------------------- the plot
def plot(rows: list[dict], path: Path, observed) -> Path:
    """The per-row figures over time, one panel each, as a PNG; a node has one colour in every
    panel (one legend above them); each axis says its unit (core/plot_style.py), a panel's own
    legend lies where it covers no data."""
    import io

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    from ..core.plot_style import legend_clear, with_unit
    from matplotlib import colormaps

    t = [r['t_end_s'] / 60 for r in rows]
    colours = dict(zip(observed, colormaps['tab10'].colors))
    fig = Figure(figsize=(13, 15), layout='constrained')
    canvas = FigureCanvasAgg(fig)
    axes = fig.subplots(4, 2, sharex=True)
    with_legend = []        # their legends once every panel is drawn

    def panel(ax, series, title, ylabel, zero=True, legend=True):
        top = 0.0
        for col, label, style in series:
            y = [number(r.get(col)) for r in rows]
            top = max([top] + [v for v in y if math.isfinite(v)])
            ax.plot(t, y, marker='.', label=label, **style)
        ax.set_title(title)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        if zero:   # counts and times from zero: a flat line must not look like a swing
            ax.set_ylim(0, max(1.0, 1.25 * top))
        if legend:
            with_legend.append(ax)

    for ax in axes[-1]:
        ax.set_xlabel(with_unit('time since the start', 'min'))
    panel(axes[0, 0], [(f'{kind}_{q}_ms', f'{label} {q}', dict(linestyle=ls, color=c))
                       for kind, label, ls in (('latency', 'to register', '-'), ('command', 'to command', '--'))
                       for q, c in (('p50', 'tab:blue'), ('p99', 'tab:orange'), ('max', 'tab:red'))],
          'gaze-to-register and gaze-to-command latency', with_unit('latency', 'ms'))
    for ax, figure, title, unit, zero in ((axes[0, 1], 'rss_mb', 'resident memory', 'MB', False),
                                          (axes[1, 0], 'cpu_s_per_min', 'CPU', 's per minute', True),
                                          (axes[1, 1], 'fds', 'open file descriptors', 'count', True),
                                          (axes[2, 0], 'threads', 'threads', 'count', True)):
        panel(ax, [(f'{figure}.{n}', n, dict(color=colours[n])) for n in observed], title,
              with_unit(title if figure != 'cpu_s_per_min' else 'CPU time', unit), zero, legend=False)
    losses = ('datagrams_lost', 'datagrams_dropped', 'commands_not_landed', 'steps_unseen', 'samples_unmatched',
              'plc_watchdog_trips')
    panel(axes[2, 1], [(col, col, {}) for col in losses], 'losses per row', with_unit('losses per row', 'count'))
    panel(axes[3, 0], [('targets_reached', 'reached', {}), ('targets_skipped', 'skipped', {})],
          'targets per row', with_unit('targets per row', 'count'))
    panel(axes[3, 1], [('time_to_target_s', 'median', {})], 'time to a target', with_unit('time to a target', 's'))
    handles = [Line2D([], [], color=colours[n], marker='.') for n in observed]
    fig.legend(handles, observed, loc='outside upper center', ncol=len(observed), fontsize=8, title='processes')
    canvas.draw()
    for ax in with_legend:
        legend_clear(ax, fontsize=7, renderer=canvas.get_renderer(), ncol=2, handlelength=3)
    buf = io.BytesIO()
    fig.savefig(buf, format='png', dpi=90)
    return write_bytes(path, buf.getvalue())
