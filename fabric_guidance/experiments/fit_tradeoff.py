"""Which of the paper's statistics pull against which in the population fit (fit-wearer).

The fit weighs eighteen statistics of the paper's per-subject table alike (population_fit.GROUPS:
means, SDs of subject means, best-condition counts, correlations between conditions). Its
population reproduces the means and SDs but not the paper's consistency of a person across
conditions (correlations 1-3 and 3-4), and with it not the paper's effect strength (Friedman
p < 0.05 on about half of the seeds). This refits the shipped designs with the correlations
weighed `emphasis` times more and shows, per emphasis, what the fit then reaches and what it
costs the other statistics, with what the fitted population predicts for the bar of
compare-paper: how often a draw of 15 people gives Friedman p < 0.05 and condition 1 as the most
frequent best (design wearers drawn by the population's weights, their own six-trial means, as
a new seed draws new people).

    python -m fabric_guidance.experiments.fit_tradeoff --out DIR [--emphasis 1,2,4,8,16,32]
                                                       [--draws 1000] [--design FILE ...]

Writes DIR/fit_tradeoff.md and DIR/fit_tradeoff.png; seconds on one core.
"""
from __future__ import annotations

import argparse
from pathlib import Path
import sys

import numpy as np

from ..atomic import write_text
from ..paths import config_path
from . import population_fit as pf
from .fit_wearer import load_designs, read_table

PAIRS = ('1-2', '1-3', '1-4', '2-3', '2-4', '3-4')


def predicted_bar(design: pf.Design, w: np.ndarray, n: int, draws: int, seed: int) -> tuple[float, float]:
    """(share of draws of n people with Friedman p < 0.05, share with condition 1 the most
    frequent best, ties counting for each) from the weighted design."""
    from scipy.stats import friedmanchisquare
    rng = np.random.default_rng(seed)
    sig = first = 0
    for _ in range(draws):
        y = design.y[rng.choice(len(w), size=n, p=w)]
        sig += friedmanchisquare(*y.T).pvalue < 0.05
        best = (y == y.max(axis=1, keepdims=True)).sum(axis=0)
        first += best[0] == best.max()
    return sig / draws, first / draws


def tradeoff(designs, table: np.ndarray, emphases, draws: int, seed: int = 34, say=print) -> list[dict]:
    """One row per emphasis of the correlations: the profiled fit (the lowest weighted objective
    over the designs), its statistics, each group's unweighted share of the fit's distance, and
    the predicted bar."""
    n = table.shape[0]
    target = pf.table_statistics(table)
    rows = []
    for k in emphases:
        fits = [(pf.fit_population(d, target, n, emphasis=emphasis_of(k)), d) for d in designs]
        (phi, weighted), design = min(fits, key=lambda f: f[0][1])
        w = pf.weights(design, phi)
        stats = pf.weighted_statistics(design, w, n)
        parts = {g: float(np.sum(v ** 2)) for g, v in pf.discrepancy(stats, target, n).items() if g in WEIGHED}
        sig, first = predicted_bar(design, w, n, draws, seed)
        rows.append(dict(emphasis=k, arm_spread=design.arm_spread, ess=1.0 / float(np.sum(w ** 2)),
                         objective=sum(parts.values()), parts=parts, stats=stats, friedman=sig, first_best=first))
        say(f'  correlations x{k:g}: arm_spread {design.arm_spread:g}, distance {sum(parts.values()):.1f}, '
            f'corr 1-3 {stats["corr"][1]:.2f}, 3-4 {stats["corr"][5]:.2f}, P(Friedman p<0.05) {sig:.2f}')
    return rows


def report(rows: list[dict], table: np.ndarray, draws: int) -> str:
    target = pf.table_statistics(table)
    paper_sig = '7.6e-4'
    lines = ['# Which statistics pull against which (`python -m fabric_guidance.experiments.fit_tradeoff`)', '',
             f'The shipped designs refitted with the correlations weighed more; P: share of {draws} draws of '
             f'{table.shape[0]} people from the fitted population (the paper: Friedman p {paper_sig}, condition 1 '
             'the most frequent best). Distance: the eighteen statistics, unweighted, as the fit counts them.', '',
             '| correlations weighed | arm_spread | distance: means / SDs / best / corr | means 1-4 | SDs 1-4 '
             '| corr ' + ' / '.join(PAIRS) + ' | P(Friedman p < 0.05) | P(1 most frequent best) |',
             '| --- | --- | --- | --- | --- | --- | --- | --- |']
    fmt = ' / '.join
    lines.append('| paper | | | ' + fmt(f'{v:.2f}' for v in target['means']) + ' | '
                 + fmt(f'{v:.2f}' for v in target['sds']) + ' | ' + fmt(f'{v:.2f}' for v in target['corr'])
                 + ' | 1 (p 7.6e-4) | 1 (10 of 15) |')
    for r in rows:
        p, s = r['parts'], r['stats']
        lines.append(f"| x{r['emphasis']:g} | {r['arm_spread']:g} | {r['objective']:.1f}: "
                     + fmt(f'{p[g]:.1f}' for g in WEIGHED) + ' | ' + fmt(f'{v:.2f}' for v in s['means'])
                     + ' | ' + fmt(f'{v:.2f}' for v in s['sds']) + ' | ' + fmt(f'{v:.2f}' for v in s['corr'])
                     + f" | {r['friedman']:.2f} | {r['first_best']:.2f} |")
    return '\n'.join(lines) + '\n'


def emphasis_of(k: float) -> tuple[float, ...]:
    """The fit's weights (population_fit.DEFAULT_EMPHASIS) with the correlations' times k."""
    return tuple(k * g if name == 'corr' else g for name, g in zip(pf.GROUPS, pf.DEFAULT_EMPHASIS))


#: The groups of statistics the fit weighs (population_fit.DEFAULT_EMPHASIS above 0).
WEIGHED = tuple(g for g, k in zip(pf.GROUPS, pf.DEFAULT_EMPHASIS) if k > 0)
#: What each group of the fit's statistics is (population_fit.GROUPS), for the legend.
GROUP_NAMES = {'means': 'the four conditions\' means', 'sds': 'the SDs of the subjects\' means',
               'best': 'how often each condition is best', 'corr': 'the correlations between conditions',
               'trial_sds': 'the SDs over all trials'}


def plot(rows: list[dict], table: np.ndarray, path: Path) -> None:
    """Left: what the fit reaches per weight of the correlations (model against paper for three
    pairs, and the predicted share of draws with Friedman p < 0.05); right: what it costs each
    group of statistics. One weight axis for both (log, the weights as ticks), the legends under
    the panels in words, pairs and groups in colours no condition has (plot_style)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from ..core import plot_style as style
    target = pf.table_statistics(table)
    k = [r['emphasis'] for r in rows]
    fig = Figure(figsize=(11, 5.4), layout='constrained')
    FigureCanvasAgg(fig)
    a, b = fig.subplots(1, 2)
    colours = iter(style.SERIES_COLOURS)
    for i, pair in ((1, '1-3'), (5, '3-4'), (0, '1-2')):
        colour = next(colours)
        a.plot(k, [r['stats']['corr'][i] for r in rows], 'o-', color=colour,
               label=f'correlation of conditions {pair}: the fitted model')
        a.axhline(target['corr'][i], color=colour, ls=':', label=f'correlation of conditions {pair}: the paper')
    n = table.shape[0]
    a.plot(k, [r['friedman'] for r in rows], 's-k', label=f'share of draws of {n} people with Friedman p < 0.05')
    a.set(ylabel='correlation, or share of draws', ylim=(0, 1.02), title='What the fit reaches')
    for g in WEIGHED:
        b.plot(k, [r['parts'][g] for r in rows], 'o-', color=next(colours), label=GROUP_NAMES.get(g, g))
    b.set(ylabel='squared standardized distance (sum over the group)', title='What it costs each group',
          ylim=(0, None))
    for ax in (a, b):
        ax.set_xscale('log')
        ax.set_xticks(k, labels=[f'{x:g}' for x in k])
        ax.minorticks_off()
        ax.set_xlabel('weight of the correlations in the fit (x)')
        ax.grid(alpha=0.3)
        style.legend_below(ax, ncol=1)
    fig.savefig(path, dpi=110)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog='python -m fabric_guidance.experiments.fit_tradeoff',
                                description=__doc__.split('\n')[0])
    p.add_argument('--out', type=Path, required=True)
    p.add_argument('--emphasis', default='1,2,4,8,16,32', help='weights of the correlations, comma list')
    p.add_argument('--draws', type=int, default=1000, help='draws of 15 people per fit for the predicted bar')
    p.add_argument('--design', type=Path, nargs='+', help="designs (default: fit-wearer's shipped ones)")
    args = p.parse_args(argv)
    try:
        emphases = [float(x) for x in args.emphasis.split(',')]
    except ValueError:
        p.error(f'--emphasis: a comma list of numbers, got {args.emphasis!r}')
    if not emphases or min(emphases) <= 0:
        p.error('--emphasis: every weight must be > 0')
    if args.draws < 1:
        p.error('--draws: at least 1')
    paths = args.design or sorted(config_path('scenes/fit').glob('design-arm_spread-*.npz'))
    table = read_table()
    rows = tradeoff(load_designs(paths), table, emphases, args.draws, say=lambda s: print(s, flush=True))
    args.out.mkdir(parents=True, exist_ok=True)
    write_text(args.out / 'fit_tradeoff.md', report(rows, table, args.draws))
    plot(rows, table, args.out / 'fit_tradeoff.png')
    print(f'wrote {args.out / "fit_tradeoff.md"} and {args.out / "fit_tradeoff.png"}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
