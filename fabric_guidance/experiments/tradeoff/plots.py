"""The plots: accuracy against time per knob, and the plane of all knobs and conditions."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ...atomic import atomic_write
from .intervals import SeedRow
from .reading import _value_text, pareto_front
from .rows import Row
from .settings import CONDITION_LABELS, KNOBS, KNOB_SYMBOLS, KNOB_TITLES, METRICS, REFERENCE
from .sweep import SweepResult


def _runs(rows) -> int:
    return len(rows[0].runs) if rows and isinstance(rows[0], SeedRow) else 1


def plot_knob(curves: list[list[Row]], path: Path, dpi: int = 120) -> Path:
    """One panel per curve of a knob: accuracy (y) against time (x), means with +-SD bars, the
    p10-p90 box shaded, each point labelled with its value, the Pareto front dashed. Rows over
    several seeds or variants (SeedRow): the means over the runs, black bars for their 95 %
    intervals on both axes, and each run's own curve in thin grey."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    fig = Figure(figsize=(6.4 * len(curves), 5.0), layout='constrained')
    canvas = FigureCanvasAgg(fig)
    labels = []     # (axes, knob, rows, x, y): placed once the layout is final
    for k, rows in enumerate(curves):
        rows = [r for r in rows if r.stats('accuracy')['n'] and r.stats('time')['n']]
        ax = fig.add_subplot(1, len(curves), k + 1)
        if not rows:
            ax.text(0.5, 0.5, 'no samples', ha='center', va='center', transform=ax.transAxes)
            continue
        knob = rows[0].knob
        A = [r.stats('accuracy') for r in rows]
        T = [r.stats('time') for r in rows]
        x = np.array([s['mean'] for s in T])
        y = np.array([s['mean'] for s in A])
        colour = f'C{k}'
        for s_t, s_a in zip(T, A):
            w, h = s_t['p90'] - s_t['p10'], s_a['p90'] - s_a['p10']
            if w > 0:
                ax.add_patch(Rectangle((s_t['p10'], s_a['p10']), w, h, color=colour, alpha=0.10, lw=0))
            else:
                ax.vlines(s_t['p10'], s_a['p10'], s_a['p90'], color=colour, alpha=0.25, lw=8)
        k = _runs(rows)
        if k > 1:
            for j in range(k):
                ax.plot([r.values('time')[j] for r in rows], [r.values('accuracy')[j] for r in rows],
                        color='0.75', lw=0.6, marker='.', ms=3, zorder=1,
                        label=f'each {_axis(rows)} ({k})' if j == 0 else None)
        else:
            ax.plot(x, y, color='0.6', lw=0.8, zorder=2)
        ax.errorbar(x, y, xerr=[s['sd'] for s in T], yerr=[s['sd'] for s in A], fmt='none', ecolor=colour,
                    elinewidth=1.2, capsize=3, zorder=3)
        if k > 1:
            xi = np.array([r.interval('time')[1:3] for r in rows])
            yi = np.array([r.interval('accuracy')[1:3] for r in rows])
            ax.errorbar(x, y, xerr=np.abs(xi.T - x), yerr=np.abs(yi.T - y), fmt='none', ecolor='black',
                        elinewidth=1.8, capsize=4, zorder=6, label=f'95 % interval over {k} {_axis(rows)}s')
        front = pareto_front(list(x), list(y))
        dom = [i for i in range(len(rows)) if i not in front]
        ax.scatter(x[front], y[front], s=42, color=colour, edgecolor='black', zorder=5, label='Pareto front')
        if dom:
            ax.scatter(x[dom], y[dom], s=42, facecolor='white', edgecolor=colour, linewidth=1.5, zorder=5,
                       label='dominated')
        ax.plot(x[front], y[front], color='black', ls='--', lw=1.0, zorder=4)
        labels.append((ax, knob, rows, x, y))
        ax.errorbar([], [], xerr=[], yerr=[], fmt='none', ecolor=colour, capsize=3,
                    label='mean +- SD' + (' (mean over runs)' if k > 1 else ''))
        ax.add_patch(Rectangle((0, 0), 0, 0, color=colour, alpha=0.2, lw=0, label='p10-p90'))
        if x.min() > 0 and x.max() / x.min() > 30:
            ax.set_xscale('log')
        if y.min() > 0 and y.max() / y.min() > 100:      # errors over orders of magnitude
            ax.set_yscale('log')
        ax.set_xlabel(METRICS[rows[0].time_metric][0])
        ax.set_ylabel(METRICS[rows[0].accuracy_metric][0])
        ax.set_title(f'{KNOB_TITLES[knob]}\n{METRICS[rows[0].accuracy_metric][0]}', fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc='best', framealpha=0.8)
    canvas.draw()
    renderer = canvas.get_renderer()
    for ax, knob, rows, x, y in labels:
        _label_points(ax, renderer, knob, rows, x, y)
    path = Path(path)
    atomic_write(path, lambda f: fig.savefig(f, dpi=dpi, format='png'))
    return path


def _label_points(ax, renderer, knob: str, rows: list[Row], x, y) -> None:
    """Each point's value, without overprinting: values at (nearly) the same place share one
    label ('G = 0, 0.01, 0.02'), and labels go where they overlap no other (_place_labels);
    a value that finds no place is named in a note in the corner."""
    pix = ax.transData.transform(np.column_stack([x, y]))
    groups: list[list[int]] = []
    for i in range(len(rows)):
        for g in groups:
            if np.hypot(*(pix[g[0]] - pix[i])) < 4.0:
                g.append(i)
                break
        else:
            groups.append([i])
    items = []
    for g in groups:
        text = _value_text(knob, rows[g[0]].value)
        if len(g) > 1:
            ref, source = REFERENCE[knob]
            values = ', '.join(f'{rows[i].value:.4g}' for i in g)
            text = f'{KNOB_SYMBOLS[knob]} = {values}'
            if any(math.isclose(float(rows[i].value), float(ref), rel_tol=1e-9) for i in g):
                text += f' ({source}: {ref:.4g})'
        items.append((x[g[0]], y[g[0]], text, 'black'))
    boxes = [ax.get_legend().get_window_extent(renderer)] if ax.get_legend() else []
    dropped = _place_labels(ax, renderer, items, boxes)
    if dropped:
        ax.text(0.01, 0.01, 'not labelled (no room): ' + '; '.join(dropped),
                transform=ax.transAxes, fontsize=7, va='bottom', ha='left', color='0.3')


def _axis(rows) -> str:
    return getattr(rows[0], 'axis', 'seed')


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


def _place_labels(ax, renderer, items, placed=None):
    """Annotate (x, y, text, colour) items at the first of a few offsets whose box overlaps no
    label placed before (greedy); a label that fits nowhere is left out (the legend names it)."""
    placed = [] if placed is None else placed
    offsets = [(7, 5, 'left', 'bottom'), (7, -5, 'left', 'top'), (-7, 5, 'right', 'bottom'),
               (-7, -5, 'right', 'top'), (0, 10, 'center', 'bottom'), (0, -10, 'center', 'top'),
               (14, 14, 'left', 'bottom'), (-14, -14, 'right', 'top'), (14, -16, 'left', 'top'),
               (-14, 16, 'right', 'bottom')]
    dropped = []
    for x, y, text, colour in items:
        for dx, dy, ha, va in offsets:
            ann = ax.annotate(text, (x, y), textcoords='offset points', xytext=(dx, dy), ha=ha,
                              va=va,
                              fontsize=7.5, color=colour, zorder=8,
                              bbox=dict(boxstyle='round,pad=0.15', fc='white', ec='none',
                                        alpha=0.8))
            box = ann.get_window_extent(renderer).padded(4.0)   # the label's white box and a gap
            inside = ax.get_window_extent(renderer).contains(box.x0, box.y0) and \
                ax.get_window_extent(renderer).contains(box.x1, box.y1)
            if inside and not any(box.overlaps(b) for b in placed):
                placed.append(box)
                break
            ann.remove()
        else:
            dropped.append(text)
    return dropped


def _whisker(row, which: str) -> float:
    return row.whisker(which) if isinstance(row, SeedRow) else row.wearer_se(which)[0]


def plot_plane(result: 'SweepResult', path: Path, dpi: int = 130, title: str | None = None) -> Path:
    """The one plane: x = mean time to find a target (speed protocol, s), y = guidance error
    at the key press (accuracy protocol, deg; acceptance tolerance: the error when a target
    counts). Conditions 1-4 at the package defaults, one polyline per knob through its values
    in the sweep's condition; whiskers +-1 SE over wearer means (over several seeds or variants:
    the 95 % interval over them). Left: the whole plane; right:
    the same axes zoomed on the knobs other than the tolerance (they crowd round the condition
    point), where their end values are labelled; without such knobs (a variants run) the whole
    plane alone."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.patches import Rectangle
    from matplotlib.transforms import Bbox

    curves = plane_curves(result)
    cond = result.settings.condition
    k = getattr(result, 'runs', 1)
    whiskers = (f'whiskers: 95 % interval over {k} {getattr(result, "axis", "seed")}s' if k > 1 else
                'whiskers +-1 SE over wearer means')
    knobs = [k for k in KNOBS if k in curves]
    swept = [k for k in knobs if k != 'acceptance_deg']
    fig = Figure(figsize=(14.0, 8.6) if swept else (9.0, 8.0), layout='constrained')
    canvas = FigureCanvasAgg(fig)
    whole, zoom = fig.subplots(1, 2, width_ratios=(1.0, 1.0)) if swept else (fig.subplots(1, 1), None)
    axes = (whole, zoom) if zoom is not None else (whole,)

    def stats(rows):
        t = np.array([r.stats('time')['mean'] for r in rows])
        a = np.array([r.stats('accuracy')['mean'] for r in rows])
        tse = np.nan_to_num([_whisker(r, 'time') for r in rows])
        ase = np.nan_to_num([_whisker(r, 'accuracy') for r in rows])
        return t, a, tse, ase

    colours = {k: f'C{i}' for i, k in enumerate(knobs)}
    markers = {1: 'o', 2: 's', 3: '^', 4: 'D'}
    handles, labels = [], []
    for knob in knobs:
        style = ':' if knob == 'acceptance_deg' else '-'
        rows = curves[knob]
        ref, _ = REFERENCE[knob]
        label = (f'{KNOB_TITLES[knob]}: {rows[0].value:g} to {rows[-1].value:g} '
                 f'(package {ref:.3g})')
        if knob == 'acceptance_deg':
            label += ';\n   y = error when a target counts (speed protocol)'
        elif knob in ('calibration_steps', 'fit_tolerance'):
            label += ';\n   own cost (calibration time / fit wall time) in the labels'
        handles.append(Line2D([], [], color=colours[knob], ls=style, marker='.', lw=1.6))
        labels.append(label)
    cond_rows = sorted(curves.get('condition', []), key=lambda r: r.value)
    for row in cond_rows:
        c = int(row.value)
        handles.insert(len(handles) - len(knobs),
                       Line2D([], [], ls='none', marker=markers.get(c, 'o'), ms=9, mec='black',
                              mfc='0.2' if c == cond else 'white'))
        labels.insert(len(labels) - len(knobs), f'condition {CONDITION_LABELS[c]}'
                      + (' (the knobs are swept here)' if c == cond and swept else ''))

    for ax in axes:
        for knob in knobs:
            x, y, xe, ye = stats(curves[knob])
            style = ':' if knob == 'acceptance_deg' else '-'
            ax.errorbar(x, y, xerr=xe, yerr=ye, fmt='none', ecolor=colours[knob], elinewidth=1.0,
                        capsize=2,
                        alpha=0.7, zorder=3)
            ax.plot(x, y, style, color=colours[knob], lw=1.6, marker='.', ms=7, zorder=4)
        # the sweep's own condition last and smaller: another at the same point stays visible
        for row in sorted(cond_rows, key=lambda r: int(r.value) == cond):
            c = int(row.value)
            if isinstance(row, SeedRow) and len(row.runs) > 1:     # each run's own point
                ax.scatter(row.values('time'), row.values('accuracy'), s=14, marker=markers.get(c, 'o'),
                           facecolor='0.6', edgecolor='none', alpha=0.8, zorder=4)
            x, y, xe, ye = stats([row])
            ax.errorbar(x, y, xerr=xe, yerr=ye, fmt='none', ecolor='black', elinewidth=1.2,
                        capsize=3, zorder=5)
            ax.scatter(x, y, s=60 if c == cond else 130, marker=markers.get(c, 'o'),
                       facecolor='0.2' if c == cond else 'white', edgecolor='black', linewidth=1.6,
                       zorder=7 if c == cond else 6)
        ax.set_xlabel('mean time to find a target (s, speed protocol)')
        ax.set_ylabel('guidance error at the key press (deg, accuracy protocol; hypot of h and v)')
        ax.grid(alpha=0.3, which='both')
    xs = np.concatenate([stats(v)[0] for v in curves.values()]) if curves else np.array([])
    ys = np.concatenate([stats(v)[1] for v in curves.values()]) if curves else np.array([])
    if xs.size and xs.min() > 0 and xs.max() / xs.min() > 4:
        whole.set_xscale('log')
    if ys.size and ys.min() > 0 and ys.max() / ys.min() > 30:
        whole.set_yscale('log')
    # the zoom: every knob but the tolerance, and the sweep's condition, with their whiskers
    near = [r for k in knobs if k != 'acceptance_deg' for r in curves[k]] + \
        [r for r in cond_rows if int(r.value) == cond]
    if near and zoom is not None:
        x, y, xe, ye = stats(near)
        x0, x1, y0, y1 = (x - xe).min(), (x + xe).max(), (y - ye).min(), (y + ye).max()
        mx, my = 0.12 * ((x1 - x0) or 0.1), 0.12 * ((y1 - y0) or 0.1)
        zoom.set_xlim(x0 - mx, x1 + mx)
        zoom.set_ylim(y0 - my, y1 + my)
        whole.add_patch(Rectangle((x0 - mx, y0 - my), x1 - x0 + 2 * mx, y1 - y0 + 2 * my,
                                  fill=False,
                                  ec='0.4', ls='--', lw=0.8, zorder=2))
    s = result.settings
    if zoom is not None:
        whole.set_title('the whole plane (dashed box: the zoom on the right)', fontsize=10)
        zoom.set_title(f'zoom: the knobs swept in condition {cond} '
                       '(package values at the filled point)',
                       fontsize=10)
    fig.suptitle((title or 'What accuracy costs in time: conditions 1-4 at the package defaults and '
                  'every knob') + f';\n{s.subjects} wearers, {whiskers}'
                 + ('; grey: each run\'s own point' if k > 1 else '') + '; lower and to the left is better',
                 fontsize=11)
    fig.legend(handles, labels, loc='outside lower center', ncol=2, fontsize=8.5, frameon=False)
    canvas.draw()
    renderer = canvas.get_renderer()

    def obstacles(ax, rows):
        out = []
        for row in rows:
            cx, cy = ax.transData.transform((row.stats('time')['mean'],
                                             row.stats('accuracy')['mean']))
            out.append(Bbox([[cx - 9, cy - 9], [cx + 9, cy + 9]]))
        return out

    tol = curves.get('acceptance_deg', [])
    if tol:
        x, y, _, _ = stats(tol)
        idx = sorted({0, len(tol) - 1} | {i for i, r in enumerate(tol)
                                          if math.isclose(float(r.value),
                                                          REFERENCE['acceptance_deg'][0])})
        items = [(x[i], y[i], f'tolerance {tol[i].value:g}'
                  + (' (package)' if i not in (0, len(tol) - 1) else ''),
                  colours['acceptance_deg'])
                 for i in idx]
        _place_labels(whole, renderer, items, obstacles(whole, cond_rows))
    items = []
    for knob in knobs:
        if knob == 'acceptance_deg':
            continue
        rows = curves[knob]
        x, y, _, _ = stats(rows)
        for i in sorted({0, len(rows) - 1}):
            text = f'{KNOB_SYMBOLS[knob]} {rows[i].value:g}'
            if knob in ('calibration_steps', 'fit_tolerance'):
                text += f' ({rows[i].note.split("; ")[0]})'
            items.append((x[i], y[i], text, colours[knob]))
    if zoom is not None:
        _place_labels(zoom, renderer, items, obstacles(zoom,
                                                       [r for r in cond_rows if int(r.value) == cond]))
    path = Path(path)
    atomic_write(path, lambda f: fig.savefig(f, dpi=dpi, format='png'))
    return path
