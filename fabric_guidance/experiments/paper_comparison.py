"""`fabric-guidance compare-paper --out DIR`: the simulated experiments next to the paper, seed by seed.

Runs the speed and the accuracy protocol of two scenes (default: the scenes fitted to the paper's
four mean speed counts by `fabric-guidance fit-wearer`) once per seed, and sets every figure the
paper reports beside the simulation's:

- fitted: the four mean counts of identified targets, against the paper's mean +- SE;
- not fitted (speed): the SD of the per-subject means and over trials, how many subjects had
  their best mean in each condition, the Friedman test, and each significance statement the
  paper makes (Dunn-Bonferroni), also checked on the paper's own table;
- not fitted (accuracy): every significance statement of Section V and its 30 deg bound, with
  the simulation's mean and median errors.
- the whole experiment per seed (paper_consistency): all four means within 2 SE, all four
  SDs within 0.6-1.6x, condition 1 most often best, Friedman p < 0.05, and how consistent a
  simulated person is across conditions (the correlations 1-3 and 3-4) against the paper's.

A seed is a new draw of wearers, targets and effect noise (the scene's `seed:`), so the spread
over seeds is the spread one would see repeating the experiment with other people.

Writes DIR/comparison.md (the tables and a reading generated from them), DIR/comparison.png
(means with their spread: the paper against each seed) and DIR/trials-<protocol>-<seed>.csv.
Also runs alone: python -m fabric_guidance.experiments.paper_comparison --out DIR
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass
import os
from pathlib import Path
import sys
import time
from typing import Callable, Sequence

import numpy as np

from .. import subcommand
from ..atomic import atomic_write, write_csv, write_text
from . import paper
from .paper import ACCURACY_CLAIMS, CONDITIONS, SPEED_CLAIMS, Claim
from .analysis_report import md_table
from .paper_consistency import consistency_section
from .stats import BlockAnalysis, analyze_blocks, analyze_trials, format_p

PROG = 'fabric-guidance compare-paper'
HELP = "run both protocols on several seeds and set every figure of the paper beside the simulation's"

#: The scenes compared by default: fitted to the paper's four mean speed counts (fit-wearer).
DEFAULT_SPEED_SCENE = 'paper-fitted-speed'
DEFAULT_ACCURACY_SCENE = 'paper-fitted-accuracy'
DEFAULT_SEEDS = 3
ACCURACY_MEASURES = ('h_error_deg', 'v_error_deg')
MEASURE_LABELS = {'identified': 'identified targets', 'h_error_deg': 'horizontal error',
                  'v_error_deg': 'vertical error'}


@dataclass(frozen=True)
class SeedResult:
    """One seed's analyses: speed (identified) and accuracy (per measure); None when the protocol
    was not run."""

    seed: int
    speed: BlockAnalysis | None
    accuracy: dict[str, BlockAnalysis]
    excluded: tuple[str, ...] = ()
    wall_s: float = 0.0
    sim_s: float = 0.0


def run_seed(speed_scene, accuracy_scene, seed: int, workers: int = 2, subjects: int | None = None,
             out: Path | None = None, progress: Callable[[str], None] | None = None) -> SeedResult:
    """Both protocols with the scenes' seed set to `seed` (either scene may be None)."""
    from ..sim.protocols import run_protocol, trials_frame

    speed, accuracy, excluded, wall, sim = None, {}, [], 0.0, 0.0
    for scene in (speed_scene, accuracy_scene):
        if scene is None:
            continue
        scene = scene.replace(seed=int(seed))
        results = run_protocol(scene, subjects, workers)
        wall += results.wall_s
        sim += results.sim_s
        excluded += [f'{scene.protocol.kind} {e.wearer}: {e.reason}' for e in results.exclusions]
        if progress is not None:
            progress(f'seed {seed}: {scene.name} ({scene.protocol.kind}) done in {results.wall_s:.1f} s')
        frame = trials_frame(results)
        if out is not None:
            write_csv(out / f'trials-{scene.protocol.kind}-{seed}.csv', frame)
        if scene.protocol.kind == 'speed':
            speed = analyze_trials(frame, 'identified', higher_is_better=True)
        else:
            for measure in ACCURACY_MEASURES:
                accuracy[measure] = analyze_trials(frame, measure, higher_is_better=False)
    return SeedResult(int(seed), speed, accuracy, tuple(excluded), wall, sim)


def claim_holds(claim: Claim, analysis: BlockAnalysis, alpha: float = 0.05) -> tuple[bool, float]:
    """Whether `analysis` shows what the paper claims for the pair, and its adjusted p. A
    difference needs the claimed direction (mean ranks) at the claimed p; 'ns' needs the
    adjusted p at or above alpha."""
    row = analysis.pair(CONDITIONS[claim.a], CONDITIONS[claim.b])
    p = float(row['p_adjusted'])
    if claim.relation == 'ns':
        return p >= alpha, p
    right_way = row['rank_diff'] > 0 if claim.relation == '>' else row['rank_diff'] < 0
    return bool(right_way and p < claim.p_below), p


# ---------------------------------------------------------------------------------------------
# The comparison as text


def _spread(values: Sequence[float], digits: int = 2) -> str:
    """'mean [min, max]' of per-seed values (one value: itself)."""
    values = [v for v in values if v is not None and np.isfinite(v)]
    if not values:
        return 'n/a'
    if len(values) == 1:
        return f'{values[0]:.{digits}f}'
    return f'{np.mean(values):.{digits}f} [{min(values):.{digits}f}, {max(values):.{digits}f}]'


def _per_seed(values: Sequence[float], digits: int = 2) -> str:
    return ' / '.join(f'{v:.{digits}f}' for v in values)


def speed_sections(results: Sequence[SeedResult]) -> tuple[list[str], dict[str, list[int]]]:
    """Markdown lines for the speed experiment, and per statement the seeds reproducing it."""
    seeds = [r for r in results if r.speed is not None]
    if not seeds:
        return [], {}
    table = analyze_blocks(paper.speed_table())
    means, ses = paper.speed_means(), paper.speed_standard_errors()
    names = ', '.join(str(r.seed) for r in seeds)
    lines = ['## Speed experiment (Section VI)', '',
             f'Identified targets per 40 s trial. Model: mean over the {seeds[0].speed.n} simulated wearers, '
             f'one value per seed ({names}); "within SE" counts the seeds whose mean is within the paper\'s '
             'standard error (SD of the per-subject means / sqrt(15)).', '',
             '### Fitted: mean per condition', '']
    rows, score = [], {}
    for c, name in CONDITIONS.items():
        vals = [float(r.speed.means[name]) for r in seeds]
        inside = sum(abs(v - means[c]) <= ses[c] for v in vals)
        rows.append([str(c), f'{means[c]:.2f} +- {ses[c]:.2f}', _per_seed(vals), f'{inside}/{len(vals)}'])
    lines += md_table(['condition', 'paper (mean +- SE)', f'model, seeds {names}', 'within SE'], rows, 'lrrr')
    lines += ['', '### Not fitted', '']
    rows = []
    for c, name in CONDITIONS.items():
        sds = [float(r.speed.sds[name]) for r in seeds]     # per seed: the spread is what a seed shows
        rows.append([f'SD of per-subject means, {c}', f'{table.sds[name]:.2f}',
                     _per_seed(sds) + (f' (mean {np.mean(sds):.2f})' if len(sds) > 1 else '')])
    for c, name in CONDITIONS.items():
        rows.append([f'SD over trials, {c}', f'{paper.SPEED_TRIAL_SD[c]:.1f} (text)',
                     _spread([float(r.speed.trial_sd[name]) for r in seeds])])
    for c, name in CONDITIONS.items():
        rows.append([f'subjects whose best is {c}', f'{paper.SPEED_BEST_COUNTS[c]}',
                     _per_seed([float(r.speed.best_counts[name]) for r in seeds], 0)])
    rows.append(['Friedman p', f'{format_p(table.p)} (table)', ' / '.join(format_p(r.speed.p) for r in seeds)])
    lines += md_table(['figure', 'paper', 'model: mean [min, max] over seeds, or per seed'], rows, 'lrr')
    lines += ['', 'Best-condition counts: a tie counts for every tied condition (the paper\'s counts sum to 16: '
              'subject B ties conditions 1 and 2).', '',
              '### Significance statements (Friedman, Dunn-Bonferroni on the per-subject means)', '']
    rows = []
    for claim in SPEED_CLAIMS:
        held, p_table = claim_holds(claim, table)
        per_seed = [claim_holds(claim, r.speed) for r in seeds]
        score[f'speed: {claim.text()}'] = [r.seed for r, (ok, _) in zip(seeds, per_seed) if ok]
        rows.append([claim.text(), claim.where, f'{"yes" if held else "no"} (p {format_p(p_table)})',
                     ' / '.join(f'{"yes" if ok else "no"} ({format_p(p)})' for ok, p in per_seed)])
    lines += md_table(['the paper says', 'where', "the paper's table re-analysed", 'model, per seed (p adj.)'],
                      rows, 'llll')
    lines += ['', "The paper's own table, analysed per subject as the package does, supports only 1 > 4: the "
              'paper presumably tested all trials; its trial data are not published.', '']
    return lines, score


def accuracy_sections(results: Sequence[SeedResult]) -> tuple[list[str], dict[str, list[int]]]:
    seeds = [r for r in results if r.accuracy]
    if not seeds:
        return [], {}
    names = ', '.join(str(r.seed) for r in seeds)
    n = seeds[0].accuracy[ACCURACY_MEASURES[0]].n
    lines = ['## Accuracy experiment (Section V): nothing of it was fitted', '',
             f'Absolute error of the gaze at the key press, {n} simulated wearers x 10 trials per condition, '
             f'seeds {names}. The paper gives no error figure other than its bound: "the mean and median of the '
             f'horizontal and vertical errors were less than {paper.ACCURACY_LIMIT_DEG:g} deg" in all conditions.', '']
    rows = []
    for measure in ACCURACY_MEASURES:
        for c, name in CONDITIONS.items():
            rows.append([f'{MEASURE_LABELS[measure]}, {c}',
                         _spread([float(r.accuracy[measure].means[name]) for r in seeds]),
                         _spread([float(r.accuracy[measure].medians[name]) for r in seeds])])
    lines += md_table(['measure, condition', 'mean of per-subject means (deg)', 'median of per-subject means (deg)'],
                      rows, 'lrr')
    lines += ['']
    rows, score = [], {}
    bound = [all(float(r.accuracy[m].summary.loc[name, key]) < paper.ACCURACY_LIMIT_DEG
                 for m in ACCURACY_MEASURES for name in CONDITIONS.values() for key in ('mean', 'median'))
             for r in seeds]
    score[f'accuracy: every mean and median < {paper.ACCURACY_LIMIT_DEG:g} deg'] = [
        r.seed for r, ok in zip(seeds, bound) if ok]
    rows.append([f'every mean and median < {paper.ACCURACY_LIMIT_DEG:g} deg', 'Section V-B',
                 ' / '.join('yes' if ok else 'no' for ok in bound)])
    for claim in ACCURACY_CLAIMS:
        per_seed = [claim_holds(claim, r.accuracy[claim.measure]) for r in seeds]
        key = f'accuracy, {MEASURE_LABELS[claim.measure]}: {claim.text()}'
        score[key] = [r.seed for r, (ok, _) in zip(seeds, per_seed) if ok]
        rows.append([f'{MEASURE_LABELS[claim.measure]}: {claim.text()}', claim.where,
                     ' / '.join(f'{"yes" if ok else "no"} ({format_p(p)})' for ok, p in per_seed)])
    lines += md_table(['the paper says', 'where', 'model, per seed (p adj.)'], rows, 'lll')
    lines += ['']
    return lines, score


def reading(score: dict[str, list[int]], n_seeds: int) -> list[str]:
    """Which statements every seed, some seeds or no seed reproduces."""
    groups = {'in every seed': [], 'in some seeds': [], 'in no seed': []}
    for text, seeds in score.items():
        key = 'in every seed' if len(seeds) == n_seeds else ('in no seed' if not seeds else 'in some seeds')
        groups[key].append(f'{text} ({len(seeds)}/{n_seeds})' if key == 'in some seeds' else text)
    lines = ['## Reading', '',
             "Generated from the tables above: which of the paper's statements the model reproduces.", '']
    for key, texts in groups.items():
        lines.append(f'- **Reproduced {key}**: ' + ('; '.join(texts) if texts else 'none') + '.')
    return lines + ['']


def comparison_markdown(results: Sequence[SeedResult], speed_name: str | None, accuracy_name: str | None,
                        image: str | None = None) -> str:
    speed_lines, speed_score = speed_sections(results)
    acc_lines, acc_score = accuracy_sections(results)
    lines = ['# The simulation next to the paper', '',
             f'Scenes: speed `{speed_name}`, accuracy `{accuracy_name}`; seeds '
             f'{", ".join(str(r.seed) for r in results)}. Simulated wearers, not people: the tables show what '
             'the model implies.', '']
    excluded = [e for r in results for e in r.excluded]
    if excluded:
        lines += ['Excluded wearers (calibration failed): ' + '; '.join(excluded), '']
    lines += reading({**speed_score, **acc_score}, len(results))
    lines += consistency_section([(r.seed, r.speed) for r in results if r.speed is not None])
    lines += speed_lines + acc_lines
    if image:
        lines += [f'![the paper and the model, per seed]({image})', '']
    wall = sum(r.wall_s for r in results)
    sim = sum(r.sim_s for r in results)
    lines += [f'{sim:.0f} simulated seconds in {wall:.1f} wall seconds.', '']
    return '\n'.join(lines)


# ---------------------------------------------------------------------------------------------
# The comparison as a figure


def plot_comparison(results: Sequence[SeedResult], path: Path, dpi: int = 120) -> Path:
    """Left: identified targets per condition, the paper (per-subject points, mean +- SD) and
    each seed (mean +- SD over wearers, as the paper gives its spread). Right: the accuracy
    protocol's errors per condition and seed: each wearer's mean, the mean over wearers, and
    whiskers from the 10th to the 90th percentile of the wearers (errors are positive: an
    interval as asymmetric as they are), with the paper's 30 deg bound. The conditions under
    plot_style's names, the legends under the panels."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    from ..core import plot_style as style

    seeds = [r for r in results if r.speed is not None]
    acc = [r for r in results if r.accuracy]
    fig = Figure(figsize=(12.5, 6.2), layout='constrained')
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2)
    conds = list(CONDITIONS)
    x = np.arange(len(conds), dtype=float)
    ticks = [style.wrap(style.condition_label(c)) for c in conds]
    colour = {r.seed: style.SERIES_COLOURS[i % len(style.SERIES_COLOURS)] for i, r in enumerate(results)}
    ax = axes[0]
    table = paper.speed_table()
    width = 0.8 / (1 + max(len(seeds), 1))
    offsets = (np.arange(1 + len(seeds)) - len(seeds) / 2.0) * width
    jitter = np.linspace(-0.25, 0.25, len(table)) * width
    for k, c in enumerate(conds):
        values = table[CONDITIONS[c]].to_numpy()
        ax.scatter(x[k] + offsets[0] + jitter, values, s=10, color='0.6', zorder=1,
                   label='paper: subjects' if k == 0 else None)
    cut = _mean_sd(ax, x + offsets[0], [table[CONDITIONS[c]] for c in conds], 'black', 's',
                   'paper: mean +- SD')
    for i, r in enumerate(seeds):
        cut |= _mean_sd(ax, x + offsets[i + 1], [r.speed.table[CONDITIONS[c]] for c in conds], colour[r.seed],
                        'o', f'model seed {r.seed}: mean +- SD over wearers')
    if cut:
        ax.plot([], [], ls='none', marker='v', color='black', label='SD bar cut at 0 (reaches below)')
    ax.set_xticks(x, ticks)
    ax.set_ylabel(style.measure_label('identified', paper.SPEED_TRIAL_S))
    ax.set_title('Speed experiment: identified targets')
    ax.grid(axis='y', alpha=0.3)
    style.from_zero(ax, x=False)
    style.legend_below(ax, ncol=2)
    ax = axes[1]
    if acc:
        pairs = [(m, r) for r in acc for m in ACCURACY_MEASURES]
        width = 0.8 / len(pairs)
        for i, (measure, r) in enumerate(pairs):
            a = r.accuracy[measure]
            at = x + (i - (len(pairs) - 1) / 2.0) * width
            marker = 'o' if measure == 'h_error_deg' else '^'
            lo, hi = zip(*(style.quantile_interval(a.table[CONDITIONS[c]]) for c in conds))
            style.interval_bars(ax, at, lo, hi, colour=colour[r.seed], lw=1.2, cap=5, zorder=3)
            for k, c in enumerate(conds):
                wearers = a.table[CONDITIONS[c]].to_numpy(float)
                ax.scatter(np.full(len(wearers), at[k]), wearers, s=9, marker=marker, color=colour[r.seed],
                           alpha=0.35, lw=0, zorder=2)
            ax.scatter(at, [a.means[CONDITIONS[c]] for c in conds], s=40, marker=marker, color=colour[r.seed],
                       edgecolor='black', zorder=4,
                       label=f'seed {r.seed}, {"horizontal" if measure == "h_error_deg" else "vertical"}: '
                             'mean, wearers, p10-p90')
        ax.axhline(paper.ACCURACY_LIMIT_DEG, color='black', linestyle='--', linewidth=1,
                   label=f'the paper: every mean < {paper.ACCURACY_LIMIT_DEG:g} deg')
        ax.set_ylim(0, None)
    ax.set_xticks(x, ticks)
    ax.set_ylabel(style.with_unit('absolute error at the key press', 'deg'))
    ax.set_title('Accuracy experiment: the model over its wearers')
    ax.grid(axis='y', alpha=0.3)
    if acc:
        style.legend_below(ax, ncol=1)
    else:
        ax.legend(handles=[Line2D([], [], ls='none')], labels=['no accuracy scene run'], loc='center')
    atomic_write(path, lambda f: fig.savefig(f, dpi=dpi, format=Path(path).suffix.lstrip('.') or 'png'))
    return path


def _mean_sd(ax, at, columns, colour, marker: str, label: str) -> bool:
    """Means +- SD (ddof 1) of the columns at `at`; a bar reaching below 0 is cut there and marked
    (counts are never negative). True when one was cut."""
    from ..core import plot_style as style
    means = np.array([float(np.mean(c)) for c in columns])
    sds = np.array([float(np.std(c, ddof=1)) if len(c) > 1 else 0.0 for c in columns])
    bounds = [style.within_range(m - s, m + s, 0.0) for m, s in zip(means, sds)]
    lo, hi, cut = (np.array(v) for v in zip(*bounds))
    style.interval_bars(ax, at, lo, hi, colour=colour, lw=1.4, cap=7, zorder=3)
    ax.scatter(at, means, s=45, marker=marker, color=colour, edgecolor='black', zorder=4, label=label)
    style.mark_cut(ax, np.asarray(at)[cut.astype(bool)], lo[cut.astype(bool)], colour=colour)
    return bool(cut.any())


# ---------------------------------------------------------------------------------------------
# Command line


def configure(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    parser.add_argument('--out', type=Path, required=True, help='folder for comparison.md, comparison.png, CSVs')
    parser.add_argument('--speed-scene', default=DEFAULT_SPEED_SCENE,
                        help=f'speed scene (config/scenes name or file; default {DEFAULT_SPEED_SCENE}); "none" skips')
    parser.add_argument('--accuracy-scene', default=DEFAULT_ACCURACY_SCENE,
                        help=f'accuracy scene (default {DEFAULT_ACCURACY_SCENE}); "none" skips')
    parser.add_argument('--seeds', default=None,
                        help=f'comma-separated seeds (default: the speed scene\'s seed and the next '
                             f'{DEFAULT_SEEDS - 1})')
    parser.add_argument('--subjects', type=int, default=None, help='only the first N wearers (default: all)')
    parser.add_argument('--workers', type=int, default=min(2, os.cpu_count() or 1), help='processes (default 2)')
    return parser


def _error(message: str) -> int:
    subcommand.error(PROG, message)
    return 2


def _seeds(text: str | None, base: int) -> list[int]:
    if text is None:
        return [base + k for k in range(DEFAULT_SEEDS)]
    try:
        seeds = [int(s) for s in text.split(',') if s.strip()]
    except ValueError:
        raise ValueError(f'--seeds: comma-separated whole numbers, got {text!r}') from None
    if not seeds or len(set(seeds)) != len(seeds) or any(s < 0 for s in seeds):
        raise ValueError(f'--seeds: one or more distinct whole numbers >= 0, got {text!r}')
    return seeds


def run(args: argparse.Namespace) -> int:
    from ..sim.scene import SceneError, load_scene

    scenes = {}
    for kind, name in (('speed', args.speed_scene), ('accuracy', args.accuracy_scene)):
        if name is None or name == 'none':
            scenes[kind] = None
            continue
        try:
            scene = load_scene(name)
        except (SceneError, OSError) as exc:
            return _error(str(exc))
        if scene.protocol.kind != kind:
            return _error(f'--{kind}-scene: {name} runs the {scene.protocol.kind} protocol, not {kind}')
        if set(scene.conditions) != set(CONDITIONS):
            return _error(f'--{kind}-scene: {name} has conditions {list(scene.conditions)}; the paper\'s are 1-4')
        scenes[kind] = scene
    if scenes['speed'] is None and scenes['accuracy'] is None:
        return _error('nothing to run: both scenes are "none"')
    if not isinstance(args.workers, int) or args.workers < 1:
        return _error(f'--workers must be >= 1, got {args.workers}')
    base = (scenes['speed'] or scenes['accuracy']).seed
    try:
        seeds = _seeds(args.seeds, base)
    except ValueError as exc:
        return _error(str(exc))
    limit = min(s.population.subjects for s in scenes.values() if s is not None)
    if args.subjects is not None and not 2 <= args.subjects <= limit:
        return _error(f'--subjects must be 2..{limit} (the statistics need two wearers)')
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)

    progress = subcommand.printer(sys.stderr)
    started = time.monotonic()
    results = [run_seed(scenes['speed'], scenes['accuracy'], seed, args.workers, args.subjects, out, progress)
               for seed in seeds]
    image = plot_comparison(results, out / 'comparison.png')
    text = comparison_markdown(results, args.speed_scene if scenes['speed'] else None,
                               args.accuracy_scene if scenes['accuracy'] else None, image.name)
    write_text(out / 'comparison.md', text)
    print(text)
    print(f'wrote {out / "comparison.md"} and {image} in {time.monotonic() - started:.1f} s', file=sys.stderr)
    return 0


def add_parser(subparsers) -> argparse.ArgumentParser:
    return subcommand.add(subparsers, 'compare-paper', HELP, __doc__, configure, run)


def main(argv: list[str] | None = None) -> int:
    return subcommand.main(PROG, __doc__, configure, run, argv)


if __name__ == '__main__':
    sys.exit(main())
