"""How the package's figures look, in one place: one name, colour and marker per condition (the
names of conditions.py), axis labels with their units, intervals that stay within a quantity's
range, legends that cover no data, and the checks that no two texts overlap and no legend
hides a data point.

Plain Python and numpy. The functions that take a figure or axes only call its methods, so
importing this module loads no matplotlib (the nodes import the core).
"""
from __future__ import annotations

import math
import textwrap
from typing import Iterable, Sequence

import numpy as np

from .conditions import CONDITIONS

#: One colour per condition in every figure (matplotlib's tab10, its first four).
CONDITION_COLOURS = {1: '#1f77b4', 2: '#ff7f0e', 3: '#2ca02c', 4: '#d62728'}
#: One marker per condition where conditions are points (the trade-off's plane).
CONDITION_MARKERS = {1: 'o', 2: 's', 3: '^', 4: 'D'}
#: Colours for what is not a condition (knobs, statistics, series): none of the conditions'.
SERIES_COLOURS = ('#9467bd', '#8c564b', '#e377c2', '#17becf', '#bcbd22', '#393b79', '#7f7f7f')
#: The grey of each run's own values and of secondary marks.
GREY = '0.6'

#: A measure's column -> (what it is, its unit); a count per trial has the unit 'per trial' and
#: its label names the trial's length when it is known (measure_label).
MEASURES = {
    'identified': ('identified target objects', 'per trial'),
    'presented': ('presented targets', 'per trial'),
    'h_error_deg': ('horizontal error at the key press', 'deg'),
    'v_error_deg': ('vertical error at the key press', 'deg'),
    'time_s': ('time to the key press', 's'),
    'mean_find_s': ('mean time to find a target', 's'),
    'find_s': ('time to find the target', 's'),
    'tracking_error_deg': ('tracking error', 'deg'),
}


def condition_label(number) -> str:
    """'1 surface haptics, adjusted': the condition's number and its name in conditions.py."""
    c = CONDITIONS[int(number)]
    return f'{c.number} {c.name}'


def condition_colour(number) -> str:
    return CONDITION_COLOURS[int(number)]


def wrap(text: str, width: int = 18) -> str:
    """A tick label on lines of about `width` characters (conditions under a violin)."""
    return textwrap.fill(text, width)


def with_unit(what: str, unit: str | None) -> str:
    """'time to find a target (s)'; no unit (a count, a ratio): the words alone."""
    return f'{what} ({unit})' if unit and unit != '-' else what


def measure_label(column: str, trial_s: float | None = None, per: str | None = None) -> str:
    """The axis label of a measure's column, with its unit: 'identified target objects per 40 s
    trial' (the trial's length when known, else 'per trial'), 'horizontal error at the key press
    (deg)'; a column this module does not know is its own label. `per`: what one value is
    ('mean per participant'), appended after a comma."""
    what, unit = MEASURES.get(column, (column, None))
    if unit == 'per trial':
        length = f' {trial_s:g} s' if trial_s is not None and math.isfinite(trial_s) else ''
        text = f'{what} per{length} trial'
    else:
        text = with_unit(what, unit)
    return f'{text}, {per}' if per else text


# ------------------------------------------------------------------------------ intervals

def quantile_interval(values: Iterable[float], low: float = 10.0, high: float = 90.0) -> tuple[float, float]:
    """The `low`-th and `high`-th percentiles of the finite values: a spread that is as
    asymmetric as the values and never leaves their range (nan, nan without values)."""
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], float)
    if not v.size:
        return math.nan, math.nan
    return float(np.percentile(v, low)), float(np.percentile(v, high))


def within_range(lo: float, hi: float, floor: float | None = 0.0) -> tuple[float, float, bool]:
    """(lo, hi, cut): an interval of a quantity that cannot go below `floor` (0 for errors,
    times and counts), its low end raised to the floor where it reaches below; `cut` says so,
    and the figure must show it (mark_cut), never cut silently."""
    if floor is not None and math.isfinite(lo) and lo < floor:
        return floor, hi, True
    return lo, hi, False


def interval_bars(ax, centre: Sequence[float], lo: Sequence[float], hi: Sequence[float], *,
                  vertical: bool = True, colour='black', lw: float = 1.2, cap: float = 6.0,
                  zorder: float = 3, alpha: float = 1.0, label: str | None = None):
    """Bars from lo to hi (asymmetric, not necessarily around the point) at `centre` on the
    other axis, with caps; nan intervals are skipped. Returns the bars' LineCollection."""
    c, a, b = (np.asarray(x, float) for x in (centre, lo, hi))
    ok = np.isfinite(c) & np.isfinite(a) & np.isfinite(b)
    c, a, b = c[ok], a[ok], b[ok]
    draw = ax.vlines if vertical else ax.hlines
    bars = draw(c, a, b, colors=colour, lw=lw, zorder=zorder, alpha=alpha, label=label)
    caps = '_' if vertical else '|'
    xs, ys = (np.r_[c, c], np.r_[a, b]) if vertical else (np.r_[a, b], np.r_[c, c])
    if cap and xs.size:
        ax.plot(xs, ys, ls='none', marker=caps, ms=cap, mew=lw, color=colour, zorder=zorder, alpha=alpha)
    return bars


def mark_cut(ax, x: Sequence[float], y: Sequence[float], *, vertical: bool = True, colour='black',
             zorder: float = 6):
    """A triangle pointing down (left) at each interval end raised to its floor: the interval
    goes on below, the figure cannot show it."""
    if len(x):
        ax.plot(x, y, ls='none', marker='v' if vertical else '<', ms=6, color=colour, zorder=zorder)


def from_zero(ax, x: bool = True, y: bool = True) -> None:
    """A linear axis of a quantity that is never negative starts at 0 at the lowest, not in the
    margin below it (a log axis, and an axis of categories, x=False, are left as they are)."""
    if x and ax.get_xscale() == 'linear' and ax.get_xlim()[0] < 0:
        ax.set_xlim(left=0.0)
    if y and ax.get_yscale() == 'linear' and ax.get_ylim()[0] < 0:
        ax.set_ylim(bottom=0.0)


# ------------------------------------------------------------------------------ legends

def legend_below(ax, ncol: int = 2, fontsize: float = 8, **kwargs):
    """The axes' legend under its tick labels and x label, outside the data (a constrained
    layout makes room; call it once the labels are set)."""
    renderer = _renderer(ax.figure)
    frame, tight = ax.get_window_extent(renderer), ax.get_tightbbox(renderer)
    below = (frame.y0 - tight.y0) / max(frame.height, 1.0) + 0.02
    return ax.legend(loc='upper center', bbox_to_anchor=(0.5, -below), ncol=ncol, fontsize=fontsize,
                     frameon=False, **kwargs)


def legend_clear(ax, fontsize: float = 8, renderer=None, **kwargs):
    """The axes' legend inside it where it covers no data point and none of the axes' texts
    (matplotlib's 'best' first, then each corner and side); where no place is clear, under the
    axes (legend_below). Call it once the figure's layout is whole; `renderer`: of a draw of it
    since (several axes share one draw: a legend inside one axes moves no other)."""
    from matplotlib.text import Text
    renderer = renderer or _renderer(ax.figure)
    points = _data_points(ax)
    texts = [Text.get_window_extent(t, renderer) for t in ax.texts if t.get_visible() and t.get_text()]
    for loc in ('best', 'upper left', 'upper right', 'lower right', 'lower left', 'center left', 'center right',
                'upper center', 'lower center'):
        legend = ax.legend(loc=loc, fontsize=fontsize, **kwargs)
        legend.draw(renderer)               # placed ('best' too) as the figure's draw will place it
        box = legend.get_window_extent(renderer)
        if not any(box.x0 < x < box.x1 and box.y0 < y < box.y1 for x, y in points) and \
                not any(box.overlaps(t) for t in texts):
            return legend
        legend.remove()
    return legend_below(ax, fontsize=fontsize, **kwargs)


def _data_points(ax) -> np.ndarray:
    """Display coordinates of the axes' data: line vertices and markers, scatter points, the ends
    of bars (LineCollections); areas (violins, bands) are not points."""
    pts = []
    for line in ax.get_lines():
        if line.get_visible() and line.get_transform().contains_branch(ax.transData):
            xy = np.asarray(line.get_xydata(), float)
            if xy.size:
                pts.append(line.get_transform().transform(xy))
    for coll in ax.collections:
        if not coll.get_visible():
            continue
        offsets = np.asarray(coll.get_offsets(), float)
        if offsets.size and coll.get_offset_transform().contains_branch(ax.transData) \
                and type(coll).__name__ == 'PathCollection':
            pts.append(coll.get_offset_transform().transform(offsets))
        elif type(coll).__name__ == 'LineCollection' and coll.get_transform().contains_branch(ax.transData):
            for seg in coll.get_segments():
                if len(seg):
                    pts.append(coll.get_transform().transform(np.asarray(seg, float)))
    if not pts:
        return np.empty((0, 2))
    out = np.concatenate(pts)
    return out[np.all(np.isfinite(out), axis=1)]


def _renderer(fig):
    """Draw the figure and return its renderer (a figure closed by pyplot gets an Agg canvas)."""
    if not hasattr(fig.canvas, 'get_renderer'):
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        FigureCanvasAgg(fig)
    fig.canvas.draw()
    return fig.canvas.get_renderer()


def legends_covering_data(fig) -> list[str]:
    """One line per legend that lies over a data point of its axes (after a draw)."""
    renderer = _renderer(fig)
    found = []
    for ax in fig.axes:
        legend = ax.get_legend()
        if legend is None or not legend.get_visible():
            continue
        box = legend.get_window_extent(renderer)
        frame = ax.get_window_extent(renderer)
        pts = _data_points(ax)
        inside = [(x, y) for x, y in pts if frame.x0 <= x <= frame.x1 and frame.y0 <= y <= frame.y1
                  and box.x0 < x < box.x1 and box.y0 < y < box.y1]
        if inside:
            found.append(f'the legend of "{ax.get_title() or ax.get_ylabel()}" covers {len(inside)} data point(s)')
    return found


# ------------------------------------------------------------------------------ text

def _drawn_tick_labels(axis) -> list:
    """The tick labels matplotlib draws: ticks within the view, labels switched on."""
    view = sorted(axis.get_transform().transform(np.asarray(axis.get_view_interval(), float)))
    out = []
    for locs, ticks in ((axis.get_majorticklocs(), axis.get_major_ticks),
                        (axis.get_minorticklocs(), axis.get_minor_ticks)):
        locs = np.asarray(locs, float)
        if not locs.size:
            continue
        where = axis.get_transform().transform(locs)
        tol = 1e-9 * max(1.0, abs(view[1] - view[0]))
        for loc, tick in zip(where, ticks(len(locs))):
            if view[0] - tol <= loc <= view[1] + tol:
                out += [t for t in (tick.label1, tick.label2) if t.get_visible() and t.get_text()]
    return out


def _texts(fig) -> list[tuple[str, object]]:
    """(description, artist) of every text a reader sees: titles, axis labels, drawn tick labels,
    annotations and free texts, and each legend as one box (matplotlib lays out its entries)."""
    from matplotlib.legend import Legend
    from matplotlib.text import Text
    legends = [a for a in fig.findobj(Legend) if a.get_visible()]
    inside_legends = {id(t) for lg in legends for t in lg.findobj(Text)}
    every, drawn = set(), set()
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            ticks = axis.get_major_ticks() + axis.get_minor_ticks()
            every.update(id(t) for tk in ticks for t in (tk.label1, tk.label2))
            drawn.update(id(t) for t in _drawn_tick_labels(axis))
    out = []
    for t in fig.findobj(Text):
        if id(t) in inside_legends or not t.get_visible() or not t.get_text().strip():
            continue
        if id(t) in every and id(t) not in drawn:
            continue
        out.append((f'text {t.get_text()!r}', t))
    out += [(f'the legend ({", ".join(x.get_text() for x in lg.get_texts()[:2])}...)', lg) for lg in legends]
    return out


def overlapping_texts(fig, pad: float = 0.5) -> list[str]:
    """One line per pair of texts whose boxes overlap, and per text not wholly inside the figure
    (after a draw; boxes shrunk by `pad` pixels so that touching is no overlap). Every text
    counts: titles, axis labels, tick labels (also those of one axis: long condition names can
    run into each other), annotations, and each legend as one box."""
    renderer = _renderer(fig)
    page = fig.bbox
    from matplotlib.text import Text
    boxes = []
    for name, artist in _texts(fig):
        # an annotation's own extent takes in its arrow: the words are what must not overlap
        if hasattr(artist, 'update_positions'):
            artist.update_positions(renderer)
        box = Text.get_window_extent(artist, renderer) if isinstance(artist, Text) else \
            artist.get_window_extent(renderer)
        if box.width <= 0 or box.height <= 0:
            continue
        boxes.append((name, box.expanded(1.0, 1.0).padded(-pad)))
    found = []
    for name, box in boxes:
        if box.x0 < page.x0 - 1 or box.y0 < page.y0 - 1 or box.x1 > page.x1 + 1 or box.y1 > page.y1 + 1:
            found.append(f'{name} runs off the figure')
    for i, (a, box_a) in enumerate(boxes):
        for b, box_b in boxes[i + 1:]:
            if box_a.overlaps(box_b):
                found.append(f'{a} overlaps {b}')
    return found
