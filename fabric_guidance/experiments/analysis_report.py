"""A markdown report of one or more analyses: summary, Friedman test, pairwise table, best
conditions, and the plots embedded by relative path (so the report and its images move together).
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Mapping, Sequence

from .stats import BlockAnalysis, condition_label, format_p, stars


def _cell(x) -> str:
    return str(x).replace('|', '\\|')


def md_table(header: Sequence[str], rows: Sequence[Sequence], align: str) -> list[str]:
    """A markdown table's lines; align: one of 'l' / 'r' per column."""
    marks = {'l': ':---', 'r': '---:'}
    return (['| ' + ' | '.join(map(_cell, header)) + ' |', '| ' + ' | '.join(marks[a] for a in align) + ' |']
            + ['| ' + ' | '.join(map(_cell, r)) + ' |' for r in rows])


def image_path(path, relative_to: Path | None) -> str:
    """How a report in the folder relative_to links the image at path (relative, with /)."""
    path = Path(path)
    if relative_to is not None:
        path = Path(os.path.relpath(path.resolve(), Path(relative_to).resolve()))
    return path.as_posix()


def analysis_markdown(a: BlockAnalysis, level: int = 2) -> list[str]:
    """The markdown lines for one analysis (no heading)."""
    h = '#' * (level + 1)
    out = [f'{a.n} subjects (blocks) x {a.k} conditions; {"higher" if a.higher_is_better else "lower"} is better.',
           '']
    header = ['condition', 'mean', 'SD', 'median', 'mean rank', 'best for']
    rows = []
    for c in a.conditions:
        s = a.summary.loc[c]
        row = [condition_label(c), f'{s["mean"]:.2f}', f'{s["sd"]:.2f}', f'{s["median"]:.2f}',
               f'{s["mean_rank"]:.3f}', int(s['best_count'])]
        if a.trial_sd is not None:
            row.insert(3, f'{a.trial_sd[c]:.2f}')
        rows.append(row)
    if a.trial_sd is not None:
        header.insert(3, 'SD (all trials)')
    out += md_table(header, rows, 'l' + 'r' * (len(header) - 1))
    out += ['', f'SD: sample SD (ddof = 1) of the {a.n} per-subject values. Mean rank: within-subject ranks, '
            '1 = smallest, ties averaged. Best for: subjects whose best value is in that condition.', '']
    out += [f'{h} Friedman test', '',
            f'chi-square = {a.chi2:.3f}, df = {a.df}, p = {format_p(a.p)} (tie-corrected); '
            f"Kendall's W = {a.kendall_w:.3f}.", '']
    m = len(a.pairwise)
    out += [f'{h} Pairwise comparisons (Dunn-Bonferroni on the Friedman mean ranks)', '',
            f'z = (Rbar_a - Rbar_b) / sqrt(k(k+1)/(6n)) = dR / {a.rank_se:.4f}; two-sided normal p; '
            f'Bonferroni over {m} pair{"s" * (m != 1)}, capped at 1.', '']
    rows = [[condition_label(r.a), condition_label(r.b), f'{r.rank_diff:+.3f}', f'{r.z:+.3f}', format_p(r.p),
             format_p(r.p_adjusted), (stars(r.p_adjusted) or 'yes') if r.significant else 'ns']
            for r in a.pairwise.itertuples()]
    out += md_table(['a', 'b', 'dR', 'z', 'p', 'p (Bonferroni)', f'at {a.alpha:g}'], rows, 'llrrrrl')
    out += ['', f'{h} Best condition per subject', '']
    rows = [[condition_label(c), int(a.summary.at[c, 'best_count']),
             ' '.join(f'{s} (tie)' if s in a.tied_best else str(s) for s, b in a.best.items() if c in b)]
            for c in a.conditions]
    out += md_table(['condition', 'subjects', 'which'], rows, 'lrl')
    if a.notes:
        out += [''] + [f'- {n}' for n in a.notes]
    return out


def markdown_report(title: str, analyses: Mapping[str, BlockAnalysis], plots: Mapping[str, str | Path],
                    notes: Sequence[str] = (), relative_to: str | Path | None = None) -> str:
    """A markdown document: one section per analysis (named by its key), with the plot of the
    same key embedded under it; plots with no analysis of their name go under "Figures".
    Image paths are written relative to `relative_to` (the report's folder) when given, else as passed.
    """
    rel = Path(relative_to) if relative_to is not None else None
    out = [f'# {title}', '']
    if notes:
        out += [f'- {n}' for n in notes] + ['']
    for name, a in analyses.items():
        out += [f'## {name}', ''] + analysis_markdown(a) + ['']
        if name in plots:
            out += [f'![{name}]({image_path(plots[name], rel)})', '']
    extra = [k for k in plots if k not in analyses]
    if extra:
        out += ['## Figures', '']
        for k in extra:
            out += [f'![{k}]({image_path(plots[k], rel)})', '']
    return '\n'.join(out).rstrip() + '\n'
