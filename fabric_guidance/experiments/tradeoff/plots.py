"""The plots: accuracy against time per knob, and the plane of all knobs and conditions (in
core/plot_style.py's style; the intervals and labels of a point: plot_marks.py)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ...atomic import atomic_write
from ...core import plot_style as style
from .intervals import SeedRow
from .plot_marks import (axis_name, draw_intervals, group_close, interval, place_labels, point_boxes, runs, spread,
                         value_items)
from .reading import _value_text, pareto_front
from .rows import Row
from .settings import KNOBS, KNOB_SYMBOLS, KNOB_TITLES, METRICS, REFERENCE
from .sweep import SweepResult


def plot_knob(curves: list[list[Row]], path: Path, dpi: int = 120) -> Path:
    """One panel per curve of a knob: accuracy (y) against time (x), each value's mean with its
    trials' p10-p90 on both axes (thin, the knob's colour), each point labelled with its value,
    the Pareto front dashed. Rows over several seeds or variants (SeedRow): the means over the
    runs, dark bars for the 95 % interval of the mean over them (tradeoff.csv's; errors and times
    are positive: an interval reaching below 0 is cut there and marked), and each run's own curve
    in thin grey. The legend is under the panels, off the data."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    fig = Figure(figsize=(6.4 * len(curves), 5.6), layout='constrained')
    canvas = FigureCanvasAgg(fig)
    labels = []     # (axes, knob, rows, x, y): placed once the layout is final
    for k, rows in enumerate(curves):
        rows = [r for r in rows if r.stats('accuracy')['n'] and r.stats('time')['n']]
        ax = fig.add_subplot(1, len(curves), k + 1)
        if not rows:
            ax.text(0.5, 0.5, 'no samples', ha='center', va='center', transform=ax.transAxes)
            continue
        knob = rows[0].knob
        x = np.array([r.stats('time')['mean'] for r in rows])
        y = np.array([r.stats('accuracy')['mean'] for r in rows])
        colour = knob_colour(knob)
        n_runs = runs(rows)
        spreads = ([(*spread(r, 'time'), False) for r in rows], [(*spread(r, 'accuracy'), False) for r in rows])
        whiskers = ([interval(r, 'time') for r in rows], [interval(r, 'accuracy') for r in rows]) \
            if n_runs > 1 else None
        every = np.array([v for iv in spreads + (whiskers or ()) for i in iv for v in i[:2]] + list(x) + list(y))
        if x.min() > 0 and x.max() / x.min() > 30:
            ax.set_xscale('log')
        if y.min() > 0 and y.max() / y.min() > 100:      # errors over orders of magnitude
            ax.set_yscale('log')
        positive = every[np.isfinite(every) & (every > 0)]
        floor = float(positive.min()) / 2 if positive.size else None
        log_floor = (floor if ax.get_xscale() == 'log' else None, floor if ax.get_yscale() == 'log' else None)
        if n_runs > 1:
            for j in range(n_runs):
                ax.plot([r.values('time')[j] for r in rows], [r.values('accuracy')[j] for r in rows],
                        color='0.75', lw=0.6, marker='.', ms=3, zorder=1)
        else:
            ax.plot(x, y, color=style.GREY, lw=0.8, zorder=2)
        cut = draw_intervals(ax, x, y, *spreads, colour=colour, lw=1.0, cap=4, zorder=3, alpha=0.8,
                             log_floor=log_floor)
        if whiskers:
            cut |= draw_intervals(ax, x, y, *whiskers, colour='0.15', lw=1.2, cap=6, zorder=6, log_floor=log_floor)
        front = pareto_front(list(x), list(y))
        dom = [i for i in range(len(rows)) if i not in front]
        ax.scatter(x[front], y[front], s=42, color=colour, edgecolor='black', zorder=7)
        if dom:
            ax.scatter(x[dom], y[dom], s=42, facecolor='white', edgecolor=colour, linewidth=1.5, zorder=7)
        ax.plot(x[front], y[front], color='black', ls='--', lw=1.0, zorder=4)
        labels.append((ax, knob, rows, x, y))
        handles = [Line2D([], [], ls='none', marker='o', ms=7, mfc=colour, mec='black', label='Pareto front'),
                   Line2D([], [], ls='none', marker='o', ms=7, mfc='white', mec=colour, mew=1.5, label='dominated'),
                   Line2D([], [], color=colour, lw=1.0, marker='|', ms=6,
                          label='p10-p90 of the trials' + (' (runs\' mean)' if n_runs > 1 else ''))]
        if n_runs > 1:
            handles += [Line2D([], [], color='0.15', lw=1.2, marker='|', ms=6,
                               label=f'95 % interval of the mean over {n_runs} {axis_name(rows)}s'),
                        Line2D([], [], color='0.75', lw=0.6, marker='.', ms=3,
                               label=f'each {axis_name(rows)} ({n_runs})')]
        if cut:
            handles.append(Line2D([], [], ls='none', marker='v', color='black',
                                  label='interval cut at 0 (reaches below)' if not any(log_floor) else
                                  "interval cut at the log axis's bottom (reaches 0 or below)"))
        ax.set_xlabel(METRICS[rows[0].time_metric][0])
        ax.set_ylabel(METRICS[rows[0].accuracy_metric][0])
        ax.set_title(f'{KNOB_TITLES[knob]}\n{METRICS[rows[0].accuracy_metric][0]}', fontsize=10)
        ax.grid(alpha=0.3)
        style.from_zero(ax)
        style.legend_below(ax, handles=handles, ncol=2)
    canvas.draw()
    renderer = canvas.get_renderer()
    for ax, knob, rows, x, y in labels:
        _label_points(ax, renderer, knob, rows, x, y)
    path = Path(path)
    atomic_write(path, lambda f: fig.savefig(f, dpi=dpi, format='png'))
    return path


def knob_colour(knob: str) -> str:
    """One colour per knob in every plot (none of the conditions')."""
    return style.SERIES_COLOURS[KNOBS.index(knob) % len(style.SERIES_COLOURS)]


def _value_group_text(knob: str, rows) -> str:
    """'G = 0.05 (the paper)' for one value, 'G = 0, 0.01' for values at one place."""
    if len(rows) == 1:
        return _value_text(knob, rows[0].value)
    ref, source = REFERENCE[knob]
    text = f'{KNOB_SYMBOLS[knob]} = ' + ', '.join(f'{r.value:.4g}' for r in rows)
    if any(math.isclose(float(r.value), float(ref), rel_tol=1e-9) for r in rows):
        text += f' ({source}: {ref:.4g})'
    return text


def _label_points(ax, renderer, knob: str, rows: list[Row], x, y) -> None:
    """Each point's value, without overprinting: values at (nearly) the same place share one
    label ('G = 0, 0.01, 0.02'), and labels go where they overlap no other label nor point
    (place_labels); a value that finds no place is named in a note in the corner."""
    groups = group_close(ax, x, y)
    items = value_items(rows, x, y, groups, lambda rs: _value_group_text(knob, rs), 'black')
    dropped = place_labels(ax, renderer, items, point_boxes(ax, zip(x, y), 5.0))
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


def plot_plane(result: 'SweepResult', path: Path, dpi: int = 130, title: str | None = None) -> Path:
    """The one plane: x = mean time to find a target (speed protocol, s), y = guidance error
    at the key press (accuracy protocol, deg; acceptance tolerance: the error when a target
    counts). Conditions 1-4 at the package defaults (plot_style's names, colours and markers),
    one polyline per knob through its values in the sweep's condition; whiskers +-1 SE over the
    wearers' means (over several seeds or variants: the 95 % interval of the mean over them),
    a low end below 0 cut there and marked (a log axis: at its bottom). Left: the whole plane; right: the
    same axes zoomed on the knobs other than the tolerance (they crowd round the condition
    point), every gain and the other knobs' end values labelled, and every condition whose point
    falls in the zoom drawn whole; without such knobs (a variants run) the whole plane alone."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.patches import Rectangle

    curves = plane_curves(result)
    cond = result.settings.condition
    k = getattr(result, 'runs', 1)
    whiskers = (f'whiskers: 95 % interval of the mean over {k} {getattr(result, "axis", "seed")}s' if k > 1 else
                'whiskers: +-1 SE over the wearers\' means')
    knobs = [k for k in KNOBS if k in curves]
    swept = [k for k in knobs if k != 'acceptance_deg']
    fig = Figure(figsize=(14.0, 8.8) if swept else (9.0, 8.0), layout='constrained')
    canvas = FigureCanvasAgg(fig)
    whole, zoom = fig.subplots(1, 2, width_ratios=(1.0, 1.0)) if swept else (fig.subplots(1, 1), None)

    def stats(rows):
        t = np.array([r.stats('time')['mean'] for r in rows])
        a = np.array([r.stats('accuracy')['mean'] for r in rows])
        return t, a, [interval(r, 'time') for r in rows], [interval(r, 'accuracy') for r in rows]

    colours = {k: knob_colour(k) for k in knobs}
    cond_rows = sorted(curves.get('condition', []), key=lambda r: r.value)
    handles, labels = [], []
    for row in cond_rows:
        c = int(row.value)
        handles.append(Line2D([], [], ls='none', marker=style.CONDITION_MARKERS.get(c, 'o'), ms=9, mec='black',
                              mfc=style.condition_colour(c)))
        swept_here = ' (the knobs are swept here)' if c == cond and swept else ''
        labels.append(f'condition {style.condition_label(c)}{swept_here}')
    for knob in knobs:
        rows = curves[knob]
        ref, _ = REFERENCE[knob]
        label = f'{KNOB_TITLES[knob]}: {rows[0].value:g} to {rows[-1].value:g} (package {ref:.3g})'
        if knob == 'acceptance_deg':
            label += ';\n   y = error when a target counts (speed protocol)'
        elif knob in ('calibration_steps', 'fit_tolerance'):
            label += ';\n   own cost (calibration time / fit wall time) in the labels'
        handles.append(Line2D([], [], color=colours[knob], ls=':' if knob == 'acceptance_deg' else '-',
                              marker='.', lw=1.6))
        labels.append(label)

    # the zoom: every knob but the tolerance, the sweep's condition, and each other condition
    # whose point falls in it, every one with its whole whiskers
    near = [r for k in swept for r in curves[k]] + [r for r in cond_rows if int(r.value) == cond]
    in_zoom, limits = set(), None
    if near and zoom is not None:
        t, a, ti, ai = stats(near)
        box = [min(i[0] for i in ti), max(i[1] for i in ti), min(i[0] for i in ai), max(i[1] for i in ai)]
        box = [np.nanmin([box[0], t.min()]), np.nanmax([box[1], t.max()]),
               np.nanmin([box[2], a.min()]), np.nanmax([box[3], a.max()])]
        for row in cond_rows:
            (x,), (y,), (xi,), (yi,) = stats([row])
            if int(row.value) == cond or (box[0] <= x <= box[1] and box[2] <= y <= box[3]):
                in_zoom.add(int(row.value))
                box = [np.nanmin([box[0], xi[0]]), np.nanmax([box[1], xi[1]]),
                       np.nanmin([box[2], yi[0]]), np.nanmax([box[3], yi[1]])]
        mx, my = 0.08 * ((box[1] - box[0]) or 0.1), 0.08 * ((box[3] - box[2]) or 0.1)
        limits = (max(box[0] - mx, 0.0), box[1] + mx, max(box[2] - my, 0.0), box[3] + my)

    xs = np.concatenate([stats(v)[0] for v in curves.values()]) if curves else np.array([])
    ys = np.concatenate([stats(v)[1] for v in curves.values()]) if curves else np.array([])
    floors = {}
    if xs.size and xs.min() > 0 and xs.max() / xs.min() > 4:
        whole.set_xscale('log')
        floors['x'] = xs.min() / 2
    if ys.size and ys.min() > 0 and ys.max() / ys.min() > 30:
        whole.set_yscale('log')
        floors['y'] = ys.min() / 2
    cut = False
    for ax in (whole, zoom):
        if ax is None:
            continue
        for knob in (knobs if ax is whole else swept):
            x, y, xi, yi = stats(curves[knob])
            cut |= draw_intervals(ax, x, y, xi, yi, colour=colours[knob], lw=1.0, cap=4, zorder=3, alpha=0.7,
                                  log_floor=(floors.get('x'), floors.get('y')) if ax is whole else None)
            ax.plot(x, y, ':' if knob == 'acceptance_deg' else '-', color=colours[knob], lw=1.6, marker='.', ms=7,
                    zorder=4)
        # the sweep's own condition last and smaller: another at the same point stays visible
        for row in sorted(cond_rows, key=lambda r: int(r.value) == cond):
            c = int(row.value)
            if ax is zoom and c not in in_zoom:
                continue
            if isinstance(row, SeedRow) and len(row.runs) > 1:     # each run's own point
                ax.scatter(row.values('time'), row.values('accuracy'), s=14, marker=style.CONDITION_MARKERS[c],
                           facecolor='0.6', edgecolor='none', alpha=0.8, zorder=4)
            x, y, xi, yi = stats([row])
            cut |= draw_intervals(ax, x, y, xi, yi, colour='black', lw=1.2, cap=6, zorder=5,
                                  log_floor=(floors.get('x'), floors.get('y')) if ax is whole else None)
            ax.scatter(x, y, s=60 if c == cond else 130, marker=style.CONDITION_MARKERS.get(c, 'o'),
                       facecolor=style.condition_colour(c), edgecolor='black', linewidth=1.6,
                       zorder=7 if c == cond else 6)
        ax.set_xlabel('mean time to find a target (s, speed protocol)')
        ax.set_ylabel('guidance error at the key press (deg, accuracy protocol; hypot of h and v)')
        ax.grid(alpha=0.3, which='both')
    style.from_zero(whole)
    if limits is not None:
        x0, x1, y0, y1 = limits
        zoom.set_xlim(x0, x1)
        zoom.set_ylim(y0, y1)
        whole.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ec='0.4', ls='--', lw=0.8, zorder=2))
    if cut:
        handles.append(Line2D([], [], ls='none', marker='v', color='black'))
        labels.append('whisker cut at 0, or at a log axis\'s bottom (it reaches below; the CSV has its ends)')
    s = result.settings
    if zoom is not None:
        whole.set_title('the whole plane (dashed box: the zoom on the right)', fontsize=10)
        outside = [str(int(r.value)) for r in cond_rows if int(r.value) not in in_zoom]
        zoom.set_title(f'zoom: the knobs swept in condition {cond} (package values at its point)'
                       + (f'\ncondition{"s" if len(outside) > 1 else ""} {", ".join(outside)} '
                          f'{"lie" if len(outside) > 1 else "lies"} outside the zoom' if outside else ''),
                       fontsize=10)
    heading = ((title or 'What accuracy costs in time: conditions 1-4 at the package defaults and every knob')
               + f';\n{s.subjects} wearers, {whiskers}' + ('; grey: each run\'s own point' if k > 1 else '')
               + '; lower and to the left is better')
    width = int(fig.get_figwidth() * 11)       # characters a line of the title holds at 11 pt
    fig.suptitle('\n'.join(style.wrap(line, width) for line in heading.split('\n')), fontsize=11)
    fig.legend(handles, labels, loc='outside lower center', ncol=2, fontsize=8.5, frameon=False)
    canvas.draw()
    renderer = canvas.get_renderer()
    _label_plane(whole, zoom, renderer, curves, cond_rows, in_zoom, colours, stats)
    path = Path(path)
    atomic_write(path, lambda f: fig.savefig(f, dpi=dpi, format='png'))
    return path


def _label_plane(whole, zoom, renderer, curves, cond_rows, in_zoom, colours, stats) -> None:
    """The whole plane: the tolerance's ends and package value. The zoom: every gain, the other
    knobs' ends; not the package values (they are the condition's point), values at one place
    under one label; labels overlap no other and no point, what fits nowhere is named."""
    def points(ax, rows):
        return point_boxes(ax, [(r.stats('time')['mean'], r.stats('accuracy')['mean']) for r in rows], 9.0)

    tol = curves.get('acceptance_deg', [])
    if tol:
        x, y, _, _ = stats(tol)
        idx = sorted({0, len(tol) - 1} | {i for i, r in enumerate(tol)
                                          if math.isclose(float(r.value), REFERENCE['acceptance_deg'][0])})
        items = [(x[i], y[i], f'tolerance {tol[i].value:g}' + (' (package)' if i not in (0, len(tol) - 1) else ''),
                  colours['acceptance_deg']) for i in idx]
        place_labels(whole, renderer, items, points(whole, cond_rows + tol))
    if zoom is None:
        return
    shown = [r for r in cond_rows if int(r.value) in in_zoom]
    items, obstacles = [], points(zoom, shown)
    for knob in [k for k in curves if k not in ('acceptance_deg', 'condition')]:
        rows = curves[knob]
        x, y, _, _ = stats(rows)
        obstacles += points(zoom, rows)
        ref = REFERENCE[knob][0]
        keep = [i for i in (range(len(rows)) if knob == 'gain' else sorted({0, len(rows) - 1}))
                if not math.isclose(float(rows[i].value), float(ref), rel_tol=1e-9)]
        for g in group_close(zoom, x[keep], y[keep]):
            values = [rows[keep[i]] for i in g]
            text = f'{KNOB_SYMBOLS[knob]} ' + ', '.join(f'{r.value:g}' for r in values)
            if knob in ('calibration_steps', 'fit_tolerance'):
                text += f' ({values[0].note.split("; ")[0]})'
            items.append((x[keep[g[0]]], y[keep[g[0]]], text, colours[knob]))
    dropped = place_labels(zoom, renderer, items, obstacles)
    if dropped:
        zoom.text(0.01, 0.01, 'not labelled (no room): ' + '; '.join(dropped), transform=zoom.transAxes,
                  fontsize=7, va='bottom', ha='left', color='0.3')
