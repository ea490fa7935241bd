"""Friedman test and Dunn-Bonferroni post-hoc for the paper's repeated-measures experiments.

Each subject is a block and each condition a treatment: values are ranked within each subject
(rank 1 = smallest, ties get average ranks), the Friedman chi-square tests whether the
conditions' rank sums differ, and every pair of conditions is compared on the Friedman mean
ranks with

    z_ij = (Rbar_i - Rbar_j) / sqrt(k (k + 1) / (6 n)),

a two-sided normal p, Bonferroni-adjusted by the number of pairs (capped at 1). This is the
block-design form of Dunn's test (Siegel & Castellan 1988, what SPSS calls the pairwise
comparisons of the related-samples Friedman test), not the independent-groups Dunn test on
ranks pooled over all observations.

The statistics come from maintained libraries: scipy.stats.friedmanchisquare (tie-corrected)
and scikit_posthocs.posthoc_siegel_friedman (the formula above on rankdata(axis=1) mean ranks,
then statsmodels' multipletests for the adjustment). Only z, which scikit-posthocs does not
return, and the Friedman statistic for two conditions, which scipy refuses, are computed here.
"""
from __future__ import annotations

import csv
import dataclasses
from dataclasses import dataclass, field
import itertools
import math
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
import pandas as pd
from scipy import stats as ss

from ..core.safe_input import MAX_FILE_BYTES, excerpt

#: The condition names of the paper's table (its Table I numbering) and how to show them.
CONDITION_LABELS = {
    'surface_adjusted': '1 surface, adjusted',
    'surface_fixed': '2 surface, fixed',
    'simple_adjusted': '3 simple (arm), adjusted',
    'speech': '4 speech',
}
#: Cells read as missing values by load_table (compared case-insensitively, after stripping).
MISSING_TOKENS = frozenset({'', 'na', 'n/a', 'nan', 'null', 'none'})
ALPHA = 0.05


def condition_label(name: str) -> str:
    """The paper's label for one of its condition names; any other name unchanged."""
    return CONDITION_LABELS.get(str(name), str(name))


def paper_order(names: Iterable[str]) -> list[str]:
    """Distinct names, the paper's conditions first in its order, then the rest as they come."""
    seen = list(dict.fromkeys(names))
    return [c for c in CONDITION_LABELS if c in seen] + [c for c in seen if c not in CONDITION_LABELS]


def stars(p: float) -> str:
    """'***' for p < 0.001, '**' for p < 0.01, '*' for p < 0.05, '' otherwise (as the paper's figures)."""
    if not p < 0.05:  # also catches NaN
        return ''
    return '***' if p < 0.001 else '**' if p < 0.01 else '*'


@dataclass(frozen=True, eq=False)
class BlockAnalysis:
    """The analysis of one subjects x conditions table (see analyze_blocks)."""

    table: pd.DataFrame            # the per-subject values analysed: index subject, one column per condition
    higher_is_better: bool         # only decides the best condition per subject; the tests are two-sided
    alpha: float
    n: int                         # subjects (blocks)
    k: int                         # conditions (treatments)
    conditions: tuple[str, ...]
    summary: pd.DataFrame          # index condition; mean, sd (ddof=1), median, mean_rank, best_count
    chi2: float                    # Friedman chi-square, tie-corrected (NaN if every subject tied everything)
    df: int
    p: float
    kendall_w: float               # chi2 / (n (k - 1)): Kendall's W with the same tie correction
    pairwise: pd.DataFrame         # a, b, rank_diff, z, p, p_adjusted, significant
    best: dict[str, tuple[str, ...]]  # subject -> its best condition(s); several when tied
    tied_best: tuple[str, ...]     # subjects whose best value is shared by several conditions
    trial_sd: pd.Series | None = None  # analyze_trials only: SD over all trials per condition (ddof=1)
    repetitions: pd.DataFrame | None = None  # analyze_trials only: trials per subject and condition
    notes: tuple[str, ...] = field(default=())

    @property
    def means(self) -> pd.Series:
        return self.summary['mean']

    @property
    def sds(self) -> pd.Series:
        return self.summary['sd']

    @property
    def medians(self) -> pd.Series:
        return self.summary['median']

    @property
    def mean_ranks(self) -> pd.Series:
        return self.summary['mean_rank']

    @property
    def best_counts(self) -> pd.Series:
        """Subjects whose best each condition is; a tie counts for every tied condition."""
        return self.summary['best_count']

    @property
    def rank_se(self) -> float:
        """sqrt(k (k + 1) / (6 n)): the standard error of a difference of two mean ranks."""
        return math.sqrt(self.k * (self.k + 1) / (6.0 * self.n))

    def pair(self, a: str, b: str) -> pd.Series:
        """The pairwise row for conditions a and b, in either order (rank_diff and z as a - b)."""
        rows = self.pairwise
        hit = rows[(rows['a'] == a) & (rows['b'] == b)]
        if len(hit):
            return hit.iloc[0]
        hit = rows[(rows['a'] == b) & (rows['b'] == a)]
        if not len(hit):
            raise KeyError(f'no pair {a!r}, {b!r}; conditions are {list(self.conditions)}')
        row = hit.iloc[0].copy()
        row['a'], row['b'] = a, b
        row['rank_diff'], row['z'] = -row['rank_diff'], -row['z']
        return row

    def significance(self) -> dict[tuple[str, str], float]:
        """(a, b) -> Bonferroni-adjusted p, the form plots.violin_plot takes."""
        return {(r.a, r.b): float(r.p_adjusted) for r in self.pairwise.itertuples()}


# ---------------------------------------------------------------------------------- validation

def _check_table(table: pd.DataFrame, what: str = 'table') -> pd.DataFrame:
    """A float copy of a subjects x conditions table, or ValueError naming what is wrong."""
    if not isinstance(table, pd.DataFrame):
        raise ValueError(f'{what}: expected a pandas DataFrame, got {type(table).__name__}')
    if table.shape[1] < 2:
        raise ValueError(f'{what}: needs at least 2 conditions (columns), got {table.shape[1]}')
    if table.shape[0] < 2:
        raise ValueError(f'{what}: needs at least 2 subjects (rows), got {table.shape[0]}')
    for axis, label in ((table.columns, 'condition'), (table.index, 'subject')):
        dup = axis[axis.duplicated()].unique()
        if len(dup):
            raise ValueError(f'{what}: duplicate {label} {", ".join(map(str, dup))}')
    numeric = table.apply(pd.to_numeric, errors='coerce').astype(float)
    bad = [(s, c) for s, c in _cells(numeric.isna() & table.notna())]
    if bad:
        raise ValueError(f'{what}: non-numeric value at {_where(bad, table)}')
    missing = list(_cells(numeric.isna()))
    if missing:
        raise ValueError(f'{what}: missing value at {_where(missing)}')
    infinite = list(_cells(pd.DataFrame(np.isinf(numeric.to_numpy()), index=numeric.index,
                                        columns=numeric.columns)))
    if infinite:
        raise ValueError(f'{what}: non-finite value at {_where(infinite)}')
    return numeric


def _cells(mask: pd.DataFrame) -> Iterable[tuple[str, str]]:
    rows, cols = np.nonzero(mask.to_numpy())
    return ((mask.index[r], mask.columns[c]) for r, c in zip(rows, cols))


def _where(cells: list[tuple], table: pd.DataFrame | None = None, limit: int = 5) -> str:
    def one(s, c):
        shown = f' ({table.at[s, c]!r})' if table is not None else ''
        return f'subject {s}, condition {c}{shown}'
    text = '; '.join(one(s, c) for s, c in cells[:limit])
    return text + (f' and {len(cells) - limit} more' if len(cells) > limit else '')


# ---------------------------------------------------------------------------------- loading

#: No measured time, error or count of the experiments is near this; beyond it sums and plot
#: ranges overflow (a +-1e308 cell broke the violin plot after the statistics).
MAX_ABS_VALUE = 1e12


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def load_table(path: str | Path) -> pd.DataFrame:
    """Read a CSV shaped like the paper's table: a header row, then one row per subject whose
    first cell is the subject id and whose other cells are that subject's value per condition.

    Returns a float DataFrame (index: subject ids as strings, columns: condition names).
    Raises ValueError naming the problem (and the cell) for an empty file, a ragged row, a
    duplicate subject or condition, a missing or non-numeric value, and fewer than 2
    conditions or 2 subjects; OSError if the file cannot be read.
    """
    path = Path(path)
    if path.is_file() and path.stat().st_size > MAX_FILE_BYTES:
        raise ValueError(f'{path}: larger than {MAX_FILE_BYTES} bytes, not a table of subjects')
    try:
        with path.open(newline='', encoding='utf-8-sig') as f:  # -sig: spreadsheets write a BOM
            rows = [r for r in csv.reader(f) if any(cell.strip() for cell in r)]
    except UnicodeDecodeError as exc:
        raise ValueError(f'{path}: not UTF-8 text (byte {exc.start})') from None
    except csv.Error as exc:  # e.g. a field over the csv module's size limit
        raise ValueError(f'{path}: not a CSV table: {excerpt(str(exc))}') from None
    if not rows:
        raise ValueError(f'{path}: empty file, expected a header row and one row per subject')
    header = [h.strip() for h in rows[0]]
    conditions = header[1:]
    if len(conditions) < 2:
        hint = ' (is it comma-separated?)' if len(header) == 1 else ''
        raise ValueError(f'{path}: needs a subject column and at least 2 condition columns, '
                         f'got {len(header)} column(s){hint}')
    if all(_is_number(h) for h in conditions):
        raise ValueError(f'{path}: the first row holds numbers, expected a header row naming the '
                         f'conditions (e.g. subject,C1,C2,C3,C4)')
    if any(not c for c in conditions):
        raise ValueError(f'{path}: empty condition name in the header, column {conditions.index("") + 2}')
    body = rows[1:]
    if len(body) < 2:
        raise ValueError(f'{path}: needs at least 2 subjects, got {len(body)}')
    subjects, values, bad, huge, missing = [], [], [], [], []
    for line, row in enumerate(body, start=2):
        if len(row) != len(header):
            raise ValueError(f'{path}: line {line} has {len(row)} cells, the header has {len(header)}')
        subject = row[0].strip()
        if not subject:
            raise ValueError(f'{path}: line {line} has no subject id')
        subjects.append(subject)
        parsed = []
        for cond, cell in zip(conditions, row[1:]):
            text = cell.strip()
            if text.lower() in MISSING_TOKENS:
                missing.append((subject, cond))
                parsed.append(math.nan)
                continue
            try:
                value = float(text)
            except ValueError:
                value = math.nan
            if not math.isfinite(value):
                bad.append((subject, cond, text))
            elif abs(value) > MAX_ABS_VALUE:
                huge.append((subject, cond, text))
            parsed.append(value)
        values.append(parsed)
    for cells, what in ((bad, 'non-numeric value'), (huge, f'value beyond +-{MAX_ABS_VALUE:g}')):
        if cells:
            raise ValueError(f'{path}: {what} at '
                             + '; '.join(f'subject {s[:40]}, condition {c[:40]} ({excerpt(t)})'
                                         for s, c, t in cells[:5])
                             + (f' and {len(cells) - 5} more' if len(cells) > 5 else ''))
    if missing:
        raise ValueError(f'{path}: missing value at {_where(missing)}')
    table = pd.DataFrame(values, index=pd.Index(subjects, name=header[0] or 'subject'),
                         columns=pd.Index(conditions, name='condition'))
    return _check_table(table, str(path))


# ---------------------------------------------------------------------------------- analysis

def _friedman(values: np.ndarray, ranks: np.ndarray) -> tuple[float, float]:
    """Tie-corrected Friedman chi-square and its p (df = k - 1) for an n x k array."""
    n, k = values.shape
    if all(len(np.unique(row)) == 1 for row in values):
        return math.nan, math.nan  # no within-subject variation at all: 0/0, not evidence either way
    if k >= 3:
        res = ss.friedmanchisquare(*values.T)
        return float(res.statistic), float(res.pvalue)
    # scipy refuses k = 2 although the statistic is defined: the same formula, written out.
    rank_sums = ranks.sum(axis=0)
    ties = sum(float(np.sum(t ** 3 - t)) for t in (np.unique(row, return_counts=True)[1] for row in values))
    correction = 1.0 - ties / (n * k * (k * k - 1))
    chi2 = (12.0 / (n * k * (k + 1)) * float(np.sum(rank_sums ** 2)) - 3.0 * n * (k + 1)) / correction
    return chi2, float(ss.chi2.sf(chi2, k - 1))


def _pairwise(table: pd.DataFrame, mean_ranks: pd.Series, alpha: float) -> pd.DataFrame:
    # Imported here: scikit-posthocs has no rosdep key, so a workspace may lack it; only the
    # post-hoc needs it (the CLI names the missing package in one line).
    import scikit_posthocs
    n, k = table.shape
    raw = scikit_posthocs.posthoc_siegel_friedman(table, p_adjust=None)
    adjusted = scikit_posthocs.posthoc_siegel_friedman(table, p_adjust='bonferroni')
    se = math.sqrt(k * (k + 1) / (6.0 * n))
    rows = []
    for a, b in itertools.combinations(table.columns, 2):
        diff = float(mean_ranks[a] - mean_ranks[b])
        p_adj = float(adjusted.at[a, b])
        rows.append({'a': a, 'b': b, 'rank_diff': diff, 'z': diff / se, 'p': float(raw.at[a, b]),
                     'p_adjusted': p_adj, 'significant': bool(p_adj < alpha)})
    return pd.DataFrame(rows, columns=['a', 'b', 'rank_diff', 'z', 'p', 'p_adjusted', 'significant'])


def _best(table: pd.DataFrame, higher_is_better: bool) -> dict[str, tuple[str, ...]]:
    # Exact equality on purpose: the same rule rankdata uses, so a tie here is a tie in the ranks.
    extreme = table.max(axis=1) if higher_is_better else table.min(axis=1)
    hits = table.eq(extreme, axis=0)
    return {s: tuple(c for c in table.columns if hits.at[s, c]) for s in table.index}


def analyze_blocks(table: pd.DataFrame, higher_is_better: bool = True, alpha: float = ALPHA) -> BlockAnalysis:
    """Friedman test, Dunn-Bonferroni post-hoc on the mean ranks, and the best condition per subject.

    `table` has one row per subject (index = subject id) and one numeric column per condition,
    with no missing values (ValueError otherwise). `higher_is_better` only decides which
    condition is a subject's best (argmax, or argmin when False); the tests are two-sided and
    ranks always run from the smallest value (rank 1) up.
    """
    table = _check_table(table)
    n, k = table.shape
    values = table.to_numpy()
    ranks = ss.rankdata(values, axis=1, method='average')
    mean_ranks = pd.Series(ranks.mean(axis=0), index=table.columns)
    chi2, p = _friedman(values, ranks)
    best = _best(table, higher_is_better)
    best_count = pd.Series({c: sum(c in b for b in best.values()) for c in table.columns})
    summary = pd.DataFrame({'mean': table.mean(), 'sd': table.std(ddof=1), 'median': table.median(),
                            'mean_rank': mean_ranks, 'best_count': best_count})
    summary.index.name = 'condition'
    tied = tuple(s for s, b in best.items() if len(b) > 1)
    notes = []
    if tied:
        word = 'largest' if higher_is_better else 'smallest'
        which = ', '.join(f'{s}: ' + ' = '.join(best[s]) for s in tied)
        notes.append(f'{len(tied)} subject(s) share their {word} value between conditions '
                     f'({which}); each tie counts for every '
                     f'tied condition, so the best-condition counts sum to {int(best_count.sum())} over {n} subjects.')
    if math.isnan(chi2):
        notes.append('Every subject has the same value in all conditions: the Friedman statistic is undefined.')
    return BlockAnalysis(
        table=table, higher_is_better=higher_is_better, alpha=alpha, n=n, k=k,
        conditions=tuple(table.columns), summary=summary, chi2=chi2, df=k - 1, p=p,
        kendall_w=chi2 / (n * (k - 1)), pairwise=_pairwise(table, mean_ranks, alpha),
        best=best, tied_best=tied, notes=tuple(notes))


def analyze_trials(trials: pd.DataFrame, measure: str, higher_is_better: bool = True,
                   conditions: Sequence[str] | None = None, alpha: float = ALPHA) -> BlockAnalysis:
    """analyze_blocks on the per-subject mean of `measure` per condition, as the paper's table.

    `trials` has one row per trial with columns subject, condition, `measure` (and usually
    repetition). Every subject must have at least one trial in every condition; a repeated
    (subject, condition, repetition) is refused as a likely data error. `conditions` fixes the
    column order (default: the paper's order for its names, else order of first appearance).
    The result also carries the SD over all trials per condition (`trial_sd`) and the number of
    trials per subject and condition (`repetitions`).
    """
    if not isinstance(trials, pd.DataFrame):
        raise ValueError(f'trials: expected a pandas DataFrame, got {type(trials).__name__}')
    need = ['subject', 'condition', measure]
    absent = [c for c in need if c not in trials.columns]
    if absent:
        raise ValueError(f'trials: missing column(s) {", ".join(absent)}; have {", ".join(map(str, trials.columns))}')
    data = trials.copy()
    values = pd.to_numeric(data[measure], errors='coerce')
    bad = data.index[values.isna() & data[measure].notna()]
    if len(bad):
        raise ValueError(f'trials: non-numeric {measure} in row(s) {", ".join(map(str, bad[:5]))}')
    if values.isna().any() or data['subject'].isna().any() or data['condition'].isna().any():
        rows = data.index[values.isna() | data['subject'].isna() | data['condition'].isna()]
        raise ValueError(f'trials: missing value in row(s) {", ".join(map(str, rows[:5]))}')
    data[measure] = values.astype(float)
    if 'repetition' in data.columns:
        dup = data[data.duplicated(['subject', 'condition', 'repetition'], keep=False)]
        if len(dup):
            s, c, r = dup.iloc[0][['subject', 'condition', 'repetition']]
            raise ValueError(f'trials: repeated trial (subject {s}, condition {c}, repetition {r})')
    if conditions is None:
        conditions = paper_order(data['condition'])
    unknown = sorted(set(data['condition']) - set(conditions), key=str)
    if unknown:
        raise ValueError(f'trials: condition(s) {", ".join(map(str, unknown))} not in {list(conditions)}')
    # math.fsum: exactly rounded, so two subjects with the same trials get bit-identical means
    # and tie in the ranks whatever the trial order.
    grouped = data.groupby(['subject', 'condition'], sort=False)[measure]
    means = grouped.agg(lambda v: math.fsum(v) / len(v)).unstack('condition')
    counts = grouped.size().unstack('condition')
    means = means.reindex(index=list(dict.fromkeys(data['subject'])), columns=list(conditions))
    holes = list(_cells(means.isna()))
    if holes:
        raise ValueError(f'trials: no trial for {_where(holes)}')
    counts = counts.reindex(index=means.index, columns=list(conditions)).astype(int)
    means.columns.name = counts.columns.name = 'condition'
    base = analyze_blocks(means, higher_is_better, alpha)
    notes = list(base.notes)
    n_trials = counts.to_numpy()
    if n_trials.min() != n_trials.max():
        notes.append(f'Unequal repetitions: {n_trials.min()} to {n_trials.max()} trials per subject '
                     'and condition; each subject mean weighs its own trials only.')
    trial_sd = data.groupby('condition')[measure].std(ddof=1).reindex(list(conditions))
    return dataclasses.replace(base, trial_sd=trial_sd, repetitions=counts, notes=tuple(notes))


# ---------------------------------------------------------------------------------- text

def format_p(p: float) -> str:
    """A p-value for people: four decimals, scientific notation below 0.001."""
    if math.isnan(p):
        return 'n/a'
    return f'{p:.2e}' if p < 0.001 else f'{p:.4f}'


def _table(header: Sequence[str], rows: Sequence[Sequence[str]], left: int = 1) -> list[str]:
    """Aligned plain-text columns: the first `left` columns left-aligned, the rest right-aligned."""
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows)]

    def line(cells):
        return '  '.join(str(c).ljust(w) if i < left else str(c).rjust(w)
                         for i, (c, w) in enumerate(zip(cells, widths))).rstrip()
    return [line(header), line(['-' * w for w in widths])] + [line(r) for r in rows]


def format_analysis(a: BlockAnalysis) -> str:
    """A plain-text report of an analysis: summary, Friedman test, pairwise table, best conditions."""
    direction = 'higher' if a.higher_is_better else 'lower'
    out = [f'Friedman test with Dunn-Bonferroni post-hoc: {a.n} subjects (blocks) x {a.k} conditions; '
           f'{direction} is better', '']
    rows = []
    for c in a.conditions:
        s = a.summary.loc[c]
        row = [condition_label(c), f'{s["mean"]:.3f}', f'{s["sd"]:.3f}', f'{s["median"]:.3f}',
               f'{s["mean_rank"]:.3f}', str(int(s['best_count']))]
        if a.trial_sd is not None:
            row.insert(3, f'{a.trial_sd[c]:.3f}')
        rows.append(row)
    header = ['condition', 'mean', 'SD', 'median', 'mean rank', 'best for']
    if a.trial_sd is not None:
        header.insert(3, 'SD trials')
    out += _table(header, rows)
    sd_note = f'SD: sample SD (ddof=1) of the {a.n} per-subject values'
    if a.trial_sd is not None:
        sd_note += '; SD trials: over all trials of the condition'
    out += [sd_note + '. Mean rank: within-subject ranks, 1 = smallest, ties averaged.', '']
    out.append(f'Friedman chi-square = {a.chi2:.3f}, df = {a.df}, p = {format_p(a.p)} (tie-corrected); '
               f"Kendall's W = {a.kendall_w:.3f}")
    out.append('')
    m = len(a.pairwise)
    out.append(f'Pairwise (Dunn on Friedman mean ranks): z = dR / sqrt(k(k+1)/(6n)) = dR / {a.rank_se:.4f}, '
               f'two-sided; Bonferroni over {m} pair{"s" * (m != 1)}')
    rows = [[condition_label(r.a), condition_label(r.b), f'{r.rank_diff:+.3f}', f'{r.z:+.3f}', format_p(r.p),
             format_p(r.p_adjusted), (stars(r.p_adjusted) or 'yes') if r.significant else 'ns']
            for r in a.pairwise.itertuples()]
    out += _table(['condition a', 'condition b', 'dR', 'z', 'p', 'p Bonferroni', f'at {a.alpha:g}'], rows, left=2)
    out.append('')
    word = 'largest' if a.higher_is_better else 'smallest'
    out.append(f'Best condition per subject ({word} value; a tie counts for each tied condition):')
    for c in a.conditions:
        who = [f'{s}(tie)' if s in a.tied_best else str(s) for s, b in a.best.items() if c in b]
        out.append(f'  {condition_label(c):<{max(len(condition_label(x)) for x in a.conditions)}}  '
                   f'{len(who):>2}  {" ".join(who)}')
    if a.notes:
        out.append('')
        out += [f'Note: {n}' for n in a.notes]
    return '\n'.join(out) + '\n'
