"""Violin plots like the paper's figures: one violin per condition, the points on top, the means
marked, and brackets with * / ** / *** over the pairs the Dunn-Bonferroni test separates.

Drawn on a bare matplotlib Figure (Agg canvas): no pyplot, no display, no global state. The
conditions' names and colours are core/plot_style.py's; the legend, right of the axes, says what
a point is, and the key of the stars shows when a bracket does.
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
import numpy as np
import pandas as pd

from ..atomic import atomic_write
from ..core import plot_style as style
from ..sim.protocols import CONDITION_NAMES
from .stats import BlockAnalysis, format_p, paper_order, stars

SIGNIFICANCE_NOTE = '* p < 0.05   ** p < 0.01   *** p < 0.001 (Friedman, Dunn-Bonferroni)'
#: A table's condition name ('surface_adjusted') -> the condition's number.
CONDITION_NUMBERS = {name: number for number, name in CONDITION_NAMES.items()}


def _name(column: str) -> str:
    """The plots' name of a condition ('1 surface haptics, adjusted'); any other column as it is."""
    number = CONDITION_NUMBERS.get(str(column))
    return style.condition_label(number) if number else str(column)


def _colours(names: list[str]) -> list[str]:
    """A condition's own colour; other columns (gains, laws) the colours no condition has."""
    others = iter(style.SERIES_COLOURS * 2)
    return [style.condition_colour(CONDITION_NUMBERS[n]) if n in CONDITION_NUMBERS else next(others)
            for n in names]


def _is_trials(data) -> bool:
    """A long trials table (one value per trial), not a subjects x conditions table."""
    return isinstance(data, pd.DataFrame) and {'subject', 'condition'} <= set(data.columns)


def _groups(data, measure: str | None) -> tuple[list[str], list[np.ndarray]]:
    """Condition names and their values from a BlockAnalysis, a wide table or a long trials table."""
    if isinstance(data, BlockAnalysis):
        data = data.table
    if not isinstance(data, pd.DataFrame):
        raise ValueError(f'expected a BlockAnalysis or a DataFrame, got {type(data).__name__}')
    if {'subject', 'condition'} <= set(data.columns):  # one row per trial
        if measure is None:
            numeric = [c for c in data.select_dtypes('number').columns if c not in ('subject', 'repetition')]
            if len(numeric) != 1:
                raise ValueError(f'trials table: say which column to plot (measure=...), candidates {numeric}')
            measure = numeric[0]
        names = paper_order(data['condition'])  # the order analyze_trials uses
        return names, [data.loc[data['condition'] == c, measure].to_numpy(float) for c in names]
    return [str(c) for c in data.columns], [data[c].to_numpy(float) for c in data.columns]


def _pairs(significance, names: list[str]) -> list[tuple[int, int, float]]:
    """(position a, position b, p) for every pair with p < 0.05 among the plotted conditions."""
    if significance is None:
        return []
    if isinstance(significance, BlockAnalysis):
        significance = significance.significance()
    elif isinstance(significance, pd.DataFrame):  # a BlockAnalysis.pairwise table
        significance = {(r.a, r.b): r.p_adjusted for r in significance.itertuples()}
    if not isinstance(significance, Mapping):
        raise ValueError('significance: a BlockAnalysis, its pairwise table or a {(a, b): p} mapping')
    out = []
    for (a, b), p in significance.items():
        if stars(p) and str(a) in names and str(b) in names:
            i, j = sorted((names.index(str(a)), names.index(str(b))))
            out.append((i, j, float(p)))
    return out


def _stack(pairs: list[tuple[int, int, float]]) -> list[tuple[int, int, float, int]]:
    """Give each bracket the lowest level where it overlaps no bracket already placed (short ones first)."""
    placed: list[tuple[int, int, float, int]] = []
    for i, j, p in sorted(pairs, key=lambda t: (t[1] - t[0], t[0])):
        level = 0
        while any(lv == level and not (j < a or i > b) for a, b, _, lv in placed):
            level += 1
        placed.append((i, j, p, level))
    return placed


def violin_plot(table_or_trials, measure_label: str, path: str | Path, significance=None, *,
                measure: str | None = None, title: str | None = None, point: str | None = None,
                dpi: int = 150) -> Path:
    """Write a PNG violin plot of `table_or_trials` to `path` and return the path.

    table_or_trials: a BlockAnalysis or a subjects x conditions table (one point per subject),
    or a trials table with columns subject, condition and the value column `measure` (one point
    per trial). significance: a BlockAnalysis, its `pairwise` table, or {(a, b): adjusted p};
    pairs with p < 0.05 get a bracket with *, ** or ***. measure_label: the y axis, with its unit
    (plot_style.measure_label). point: what a point is, for the legend (default 'one trial' or
    'one subject's mean').
    """
    fig = violin_figure(table_or_trials, measure_label, significance, measure=measure, title=title, point=point)
    path = Path(path)
    atomic_write(path, lambda f: fig.savefig(f, dpi=dpi, format='png'))
    return path


def violin_figure(table_or_trials, measure_label: str, significance=None, *, measure: str | None = None,
                  title: str | None = None, point: str | None = None) -> Figure:
    """The figure violin_plot writes."""
    names, groups = _groups(table_or_trials, measure)
    trials = _is_trials(table_or_trials)
    pos = np.arange(1, len(names) + 1)
    fig = Figure(figsize=(max(5.0, 1.7 * len(names) + 1.5) + 1.9, 5.0), layout='constrained')
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    colours = _colours(names)

    # gaussian_kde cannot smooth a single value: such a condition is drawn as its points only.
    spread = [i for i, g in enumerate(groups) if len(np.unique(g)) > 1]
    if spread:
        parts = ax.violinplot([groups[i] for i in spread], positions=pos[spread], widths=0.8,
                              showextrema=False)
        for i, body in zip(spread, parts['bodies']):
            body.set_facecolor(colours[i])
            body.set_edgecolor('black')
            body.set_alpha(0.35)
    rng = np.random.default_rng(0)  # fixed jitter: the same figure on every run
    for x, g, col in zip(pos, groups, colours):
        ax.scatter(x + rng.uniform(-0.09, 0.09, len(g)), g, s=16, color=col, edgecolor='black',
                   linewidth=0.4, zorder=3)
        ax.hlines(np.median(g), x - 0.22, x + 0.22, color='black', linewidth=1.2, linestyle=':', zorder=4)
        ax.scatter([x], [np.mean(g)], marker='D', s=46, color='white', edgecolor='black', zorder=5)
    ax.scatter([], [], s=16, color='0.55', edgecolor='black', linewidth=0.4,
               label=point or ('one trial' if trials else "one subject's mean"))
    ax.scatter([], [], marker='D', s=46, color='white', edgecolor='black', label='mean')
    ax.plot([], [], color='black', linestyle=':', label='median')

    lo = min(float(np.min(g)) for g in groups)
    hi = max(float(np.max(g)) for g in groups)
    step = 0.08 * ((hi - lo) or 1.0)
    top = hi
    brackets = _stack(_pairs(significance, names))
    for i, j, p, level in brackets:
        y = hi + step * (1 + 1.4 * level)
        ax.plot([pos[i], pos[i], pos[j], pos[j]], [y - step * 0.3, y, y, y - step * 0.3], color='black', lw=1)
        ax.text((pos[i] + pos[j]) / 2, y, stars(p), ha='center', va='bottom', fontsize=12)
        top = max(top, y + step * 0.9)
    ax.set_ylim(lo - step, top + step)

    ax.set_xticks(pos, [style.wrap(_name(n)) for n in names])
    ax.set_xlim(0.4, len(names) + 0.6)
    ax.set_ylabel(measure_label)
    ax.grid(axis='y', alpha=0.3)
    ax.legend(loc='upper left', bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    heading = title or measure_label
    if isinstance(significance, BlockAnalysis):
        heading += (f'\nFriedman chi2 = {significance.chi2:.2f}, df = {significance.df}, '
                    f'p = {format_p(significance.p)}; n = {significance.n}')
    ax.set_title(heading, fontsize=11)
    if brackets:
        ax.set_xlabel(SIGNIFICANCE_NOTE, fontsize=7, color='0.3')  # a label, so the layout makes room
    return fig
