"""What the trade-off's plots draw at a point: its intervals (within the quantity's range) and
its value labels (placed where they overlap no other text and no point)."""
from __future__ import annotations

import math

import numpy as np

from ...core import plot_style as style
from .intervals import SeedRow
from .rows import Row


def runs(rows) -> int:
    return len(rows[0].runs) if rows and isinstance(rows[0], SeedRow) else 1


def axis_name(rows) -> str:
    return getattr(rows[0], 'axis', 'seed')


def spread(row, which: str) -> tuple[float, float]:
    """The trials' p10 to p90 of `which` ('accuracy', 'time'): the spread of one value, as
    asymmetric as the trials and within their range (over several runs: the runs' mean of each)."""
    s = row.stats(which)
    return s['p10'], s['p90']


def interval(row, which: str) -> tuple[float, float, bool]:
    """(lo, hi, cut) of the whisker of the row's mean of `which`: over several runs the 95 % t
    interval of the mean over the runs (tradeoff.csv's _lo/_hi), one run +-1 SE over the wearers'
    means (its _se); errors and times are positive, so a low end below 0 is cut at 0 (cut: True,
    and the plot marks it)."""
    if isinstance(row, SeedRow) and len(row.runs) > 1:
        _, lo, hi, _ = row.interval(which)
    else:
        mean = row.stats(which)['mean']
        se = (row.runs[0] if isinstance(row, SeedRow) else row).wearer_se(which)[0]
        lo, hi = mean - se, mean + se
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return math.nan, math.nan, False
    return style.within_range(lo, hi, 0.0)


def draw_intervals(ax, x, y, xi, yi, *, colour, lw: float, cap: float, zorder: float, alpha: float = 1.0,
                   log_floor: tuple[float, float] | None = None) -> bool:
    """Bars of the intervals xi, yi ([(lo, hi, cut)] per point) through the points (x, y); a cut
    end is marked. log_floor: per axis (x, y) the lowest value a log axis shows, for an end cut at
    0 there. True when some end was cut."""
    cut_any = False
    for vertical, centre, ivs in ((True, x, yi), (False, y, xi)):
        lo = np.array([i[0] for i in ivs], float)
        hi = np.array([i[1] for i in ivs], float)
        cut = np.array([i[2] for i in ivs], bool)
        floor = (log_floor or (None, None))[1 if vertical else 0]
        if floor is not None:
            cut |= np.isfinite(lo) & (lo < floor)
            lo = np.where(cut, floor, lo)
        style.interval_bars(ax, centre, lo, hi, vertical=vertical, colour=colour, lw=lw, cap=cap, zorder=zorder,
                            alpha=alpha)
        if cut.any():
            cut_any = True
            ends = (np.asarray(centre, float)[cut], lo[cut])
            style.mark_cut(ax, *(ends if vertical else ends[::-1]), vertical=vertical, colour=colour)
    return cut_any


def point_boxes(ax, xy, radius: float = 8.0):
    """Boxes round the points (data coordinates) in pixels: where a label must not sit."""
    from matplotlib.transforms import Bbox
    out = []
    for x, y in xy:
        if math.isfinite(x) and math.isfinite(y):
            cx, cy = ax.transData.transform((x, y))
            out.append(Bbox([[cx - radius, cy - radius], [cx + radius, cy + radius]]))
    return out


def group_close(ax, x, y, px: float = 6.0) -> list[list[int]]:
    """Indices of the points, grouped where they lie within `px` pixels of the first of a group."""
    pix = ax.transData.transform(np.column_stack([x, y]))
    groups: list[list[int]] = []
    for i in range(len(x)):
        for g in groups:
            if np.hypot(*(pix[g[0]] - pix[i])) < px:
                g.append(i)
                break
        else:
            groups.append([i])
    return groups


#: (dx, dy) in points, ha, va, a leader line: near the point first, then further out.
OFFSETS = [(7, 5, 'left', 'bottom'), (7, -5, 'left', 'top'), (-7, 5, 'right', 'bottom'),
           (-7, -5, 'right', 'top'), (0, 10, 'center', 'bottom'), (0, -10, 'center', 'top')] + \
    [(dx * r, dy * r, ha, va) for r in (2.2, 3.6, 5.2) for dx, dy, ha, va in
     ((10, 10, 'left', 'bottom'), (10, -10, 'left', 'top'), (-10, 10, 'right', 'bottom'),
      (-10, -10, 'right', 'top'), (0, 14, 'center', 'bottom'), (0, -14, 'center', 'top'),
      (16, 0, 'left', 'center'), (-16, 0, 'right', 'center'))]


def place_labels(ax, renderer, items, placed=None) -> list[str]:
    """Annotate (x, y, text, colour) items at the first offset whose box lies inside the axes and
    overlaps no box placed before (labels, points, the legend); a label away from its point gets a
    thin leader line. Returns the texts that fit nowhere (the caller names them)."""
    from matplotlib.text import Text
    placed = [] if placed is None else placed
    frame = ax.get_window_extent(renderer)
    dropped = []
    for x, y, text, colour in items:
        for dx, dy, ha, va in OFFSETS:
            far = abs(dx) + abs(dy) > 20
            ann = ax.annotate(text, (x, y), textcoords='offset points', xytext=(dx, dy), ha=ha, va=va,
                              fontsize=7.5, color=colour, zorder=8,
                              bbox=dict(boxstyle='round,pad=0.15', fc='white', ec='none', alpha=0.85),
                              arrowprops=dict(arrowstyle='-', lw=0.6, color=colour, shrinkA=0, shrinkB=3)
                              if far else None)
            ann.update_positions(renderer)
            box = Text.get_window_extent(ann, renderer).padded(3.0)   # the words' white box and a gap
            if frame.contains(box.x0, box.y0) and frame.contains(box.x1, box.y1) and \
                    not any(box.overlaps(b) for b in placed):
                placed.append(box)
                break
            ann.remove()
        else:
            dropped.append(text)
    return dropped


def value_items(rows: list[Row], x, y, groups, text_of, colour) -> list[tuple]:
    """One label item per group of points: 'G = 0, 0.01' for points at one place."""
    return [(x[g[0]], y[g[0]], text_of([rows[i] for i in g]), colour) for g in groups]
