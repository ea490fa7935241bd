"""Does one seed's simulated speed experiment look like the paper's, as a whole? The bars a seed
of `compare-paper` is held to, beside the figure-by-figure tables:

- every condition's mean within MEANS_SE standard errors of the paper's (SE: the SD of the
  paper's per-subject means / sqrt(15), paper.speed_standard_errors);
- every condition's SD of subject means within SD_RATIO times the paper's;
- condition 1 the best of more subjects than any other condition (the paper: 10 of 15);
- the Friedman test significant at ALPHA (as on the paper's own table, re-analysed per subject);
- the correlations over subjects between conditions (CORRELATION_PAIRS): how consistent a person
  is across conditions; over seeds their mean, with the paper's within one seed SD of it or not.

These bars are the project's (the issue that asked for simulated people as consistent as the
paper's), not the paper's: the paper publishes one experiment, so a seed is one repetition of it.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from . import paper
from .analysis_report import md_table
from .paper import CONDITIONS
from .stats import BlockAnalysis, analyze_blocks, format_p

MEANS_SE = 2.0
SD_RATIO = (0.6, 1.6)
ALPHA = 0.05
CORRELATION_PAIRS = ((1, 3), (3, 4))
#: A validation: SETS sets of PER_SET seeds; a bar is met on at least PER_SET_MIN seeds of every
#: set and TOTAL_MIN of all (the issue that set the bars).
SETS, PER_SET, PER_SET_MIN, TOTAL_MIN = 3, 5, 4, 12


@dataclass(frozen=True)
class Consistency:
    """One seed against the bars."""

    seed: int
    means_within: int          # conditions whose mean is within MEANS_SE SE (of 4)
    sds_within: int            # conditions whose SD of subject means is within SD_RATIO (of 4)
    condition_1_best: bool     # condition 1 best of strictly more subjects than any other
    p: float                   # Friedman
    correlations: dict[tuple[int, int], float]

    @property
    def friedman(self) -> bool:
        return self.p < ALPHA

    @property
    def all_means(self) -> bool:
        return self.means_within == len(CONDITIONS)

    @property
    def all_sds(self) -> bool:
        return self.sds_within == len(CONDITIONS)


def correlations(table) -> dict[tuple[int, int], float]:
    """Pearson correlation over subjects of each pair's per-subject means (a subjects x
    conditions frame, columns named as paper.CONDITIONS)."""
    return {(a, b): float(np.corrcoef(table[CONDITIONS[a]], table[CONDITIONS[b]])[0, 1])
            for a, b in CORRELATION_PAIRS}


def consistency(seed: int, speed: BlockAnalysis) -> Consistency:
    means, ses = paper.speed_means(), paper.speed_standard_errors()
    paper_sds = analyze_blocks(paper.speed_table()).sds
    lo, hi = SD_RATIO
    means_within = sum(abs(float(speed.means[name]) - means[c]) <= MEANS_SE * ses[c] for c, name in CONDITIONS.items())
    sds_within = sum(lo <= float(speed.sds[name]) / float(paper_sds[name]) <= hi for name in CONDITIONS.values())
    best = speed.summary['best_count']
    first = float(best[CONDITIONS[1]])
    condition_1_best = all(first > float(best[name]) for c, name in CONDITIONS.items() if c != 1)
    return Consistency(seed, int(means_within), int(sds_within), bool(condition_1_best), float(speed.p),
                       correlations(speed.table))


def consistency_section(results: Sequence[tuple[int, BlockAnalysis]]) -> list[str]:
    """Markdown lines: a row per seed, a row of how many seeds meet each bar, and the mean
    correlations over seeds against the paper's."""
    if not results:
        return []
    rows = [consistency(seed, speed) for seed, speed in results]
    n = len(rows)
    own = correlations(paper.speed_table())
    pairs = [f'r {a}-{b}' for a, b in CORRELATION_PAIRS]
    lo, hi = SD_RATIO
    lines = ['## The whole experiment, seed by seed', '',
             f'Per seed: the four means within {MEANS_SE:g} SE of the paper\'s, the four SDs of subject means within '
             f'{lo:g}-{hi:g} times the paper\'s, condition 1 the best of more subjects than any other condition, '
             f'Friedman p < {ALPHA:g}, and the correlations over subjects between conditions (how consistent '
             'a person is across conditions). The bars are the project\'s (docs/paper_comparison.md), '
             'not the paper\'s.',
             '']
    table = [[str(r.seed), f'{r.means_within}/4', f'{r.sds_within}/4', 'yes' if r.condition_1_best else 'no',
              format_p(r.p)] + [f'{r.correlations[p]:.2f}' for p in CORRELATION_PAIRS] for r in rows]
    table.append([f'seeds meeting it (of {n})', str(sum(r.all_means for r in rows)),
                  str(sum(r.all_sds for r in rows)), str(sum(r.condition_1_best for r in rows)),
                  str(sum(r.friedman for r in rows))] + [''] * len(CORRELATION_PAIRS))
    theirs = analyze_blocks(paper.speed_table())
    best = int(theirs.summary['best_count'][CONDITIONS[1]])
    table.append(['the paper', '', '', f'yes ({best} of {theirs.n})', format_p(theirs.p)]
                 + [f'{own[p]:.2f}' for p in CORRELATION_PAIRS])
    lines += md_table(['seed', 'means within', 'SDs within', 'condition 1 most often best', 'Friedman p'] + pairs,
                      table, 'lrrlr' + 'r' * len(CORRELATION_PAIRS))
    lines.append('')
    for pair, label in zip(CORRELATION_PAIRS, pairs):
        values = np.array([r.correlations[pair] for r in rows])
        if n > 1:
            sd = float(values.std(ddof=1))
            within = abs(own[pair] - values.mean()) <= sd
            lines.append(f'- {label}: mean over seeds {values.mean():.2f} (SD {sd:.2f}); '
                         f'the paper\'s {own[pair]:.2f} is '
                         + ('within' if within else 'outside') + ' one seed SD of it.')
        else:
            lines.append(f'- {label}: {values[0]:.2f} (one seed); the paper\'s {own[pair]:.2f}.')
    return lines + ['']


def bars_chance(scale: float = 1.0, validations: int = 10000, seed: int = 0) -> dict[str, float]:
    """How often an ideal model meets the means and SD bars: each seed 15 people drawn from a
    normal with the paper's own per-subject means and covariance (its spread times `scale`).
    The chance that one seed meets each bar, and that a validation (SETS sets of PER_SET seeds)
    does, for 'means', 'sds' and 'both'. Drawn in chunks: memory stays bounded for any count."""
    table = paper.speed_table()
    y = np.column_stack([table[name].to_numpy(float) for name in CONDITIONS.values()])
    n = y.shape[0]
    # The bars' own figures of the paper (as consistency() judges a seed against them)
    centre = np.array([paper.speed_means()[c] for c in CONDITIONS])
    ses = np.array([paper.speed_standard_errors()[c] for c in CONDITIONS])
    sds = y.std(axis=0, ddof=1)
    cov = np.cov(y.T) * scale ** 2
    lo, hi = SD_RATIO
    rng = np.random.default_rng(seed)
    per_seed = {'means': [], 'sds': []}
    met = {'means': [], 'sds': [], 'both': []}
    done = 0
    while done < validations:
        k = min(1000, validations - done)
        x = rng.multivariate_normal(centre, cov, size=(k * SETS * PER_SET, n))
        ok = {'means': (np.abs(x.mean(axis=1) - centre) <= MEANS_SE * ses).all(axis=-1)}
        ratio = x.std(axis=1, ddof=1) / sds
        ok['sds'] = ((ratio >= lo) & (ratio <= hi)).all(axis=-1)
        for key in per_seed:
            per_seed[key].append(ok[key])
            per = ok[key].reshape(k, SETS, PER_SET).sum(axis=-1)
            met[key].append((per >= PER_SET_MIN).all(axis=-1) & (per.sum(axis=-1) >= TOTAL_MIN))
        met['both'].append(met['means'][-1] & met['sds'][-1])
        done += k
    out = {f'seed_{key}': float(np.concatenate(v).mean()) for key, v in per_seed.items()}
    out.update({f'validation_{key}': float(np.concatenate(v).mean()) for key, v in met.items()})
    return out
