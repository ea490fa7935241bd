"""The per-wearer adjustment gain, in simulation: the first open point of the paper's Discussion.

Per-wearer adjustment gain ("the adjustment gain that maximized the adjustment effect
differed among the subjects, and the performance of the proposed system may be further
improved by adjusting the adjustment gain of each user"). Each simulated wearer is calibrated
by Algorithm 1, then their own G is chosen on TUNING speed trials (condition 1, every G of a
grid; the best mean of identified targets, ties broken by the shorter mean time to find,
then by the G nearest the paper's 0.05) and stored in their calibration
(core.calibration.Calibration.with_gain). EVALUATION speed trials, whose targets and random
streams are disjoint from the tuning trials', then compare condition 1 with the paper's
G = 0.05 and with the wearer's own G, as the pressure_controller node runs it with
use_wearer_gain. The evaluation trials are the paper-speed protocol's own condition-1 trials
(same target stream and run keys as protocols.speed_trial): the paper-G arm is exactly what
`python -m fabric_guidance.sim.protocols paper-speed` records for condition 1. Every G of the
grid is also run on the evaluation trials, which gives the oracle: the G that would have
been best on the evaluation trials themselves (an optimistic upper bound, for reference).

The trials, their analysis, plot, summary and report section are in this one module.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Iterable, Sequence

import pandas as pd

from ...core.calibration import Calibration
from ...core.feedback import PAPER_GAIN
from ...sim.node_loop import NodeLoop
from ...sim.protocols import speed_loop, speed_measures
from ...sim.scene import Scene
from ..analysis_report import analysis_markdown, image_path, md_table
from ..stats import analyze_blocks, format_p
from .arms import analyze_arms, pair_p, verdict
from .trials import CONDITION, TrialKey, tuning_keys

#: The G grid of the tuning: 0 to 0.5 in steps of 0.05 (the paper's 0.05 is on it).
GAIN_GRID: tuple[float, ...] = tuple(round(0.05 * i, 2) for i in range(11))


def speed_trial(scene: Scene, wearer, calibration: Calibration, key: TrialKey,
                gain: float | None = None) -> dict:
    """One speed trial (condition 1) as protocols.speed_trial runs it, with G = gain (None: the
    scene's) carried in the calibration and used as the node's use_wearer_gain does."""
    proto = scene.protocol
    if proto.kind != 'speed':
        raise ValueError(f'the gain study needs a speed scene, got {proto.kind!r}')
    cal = calibration.with_gain(gain) if gain is not None else calibration
    loop = NodeLoop(scene, wearer, key.run, CONDITION, cal, use_wearer_gain=gain is not None)
    loop.warm_up()
    return speed_measures(speed_loop(loop, key.targets(scene, wearer.index), proto))


def gain_means(rows: Iterable[dict]) -> dict[float, tuple[float, float]]:
    """gain -> (mean identified, mean of the trials' mean time to find; inf when none found)."""
    by_gain: dict[float, list[dict]] = {}
    for r in rows:
        by_gain.setdefault(float(r['gain']), []).append(r)
    out = {}
    for g, rs in by_gain.items():
        ident = math.fsum(r['identified'] for r in rs) / len(rs)
        finds = [r['mean_find_s'] for r in rs if r['mean_find_s'] is not None]
        out[g] = (ident, math.fsum(finds) / len(finds) if finds else math.inf)
    return out


def choose_gain(means: dict[float, tuple[float, float]], paper_gain: float = PAPER_GAIN) -> float:
    """The best G: most identified targets, then the shorter time to find, then the G nearest
    the paper's, then the smaller."""
    if not means:
        raise ValueError('no gain to choose from')
    return min(means, key=lambda g: (-means[g][0], means[g][1], abs(g - paper_gain), g))


def tune_gain(scene: Scene, wearer, calibration: Calibration, grid: Sequence[float] = GAIN_GRID,
              reps: int = 4) -> tuple[float, list[dict]]:
    """The wearer's own G from `reps` tuning trials per G of the grid; (G, the trial rows)."""
    rows = run_gain_grid(scene, wearer, calibration, grid, tuning_keys(reps))
    return choose_gain(gain_means(rows), scene.controller.gain), rows


def run_gain_grid(scene: Scene, wearer, calibration: Calibration, grid: Sequence[float],
                  keys: Sequence[TrialKey]) -> list[dict]:
    rows = []
    for g in grid:
        for key in keys:
            rows.append(dict(subject=wearer.index, wearer=wearer.name, phase=key.phase,
                             gain=float(g), repetition=key.repetition,
                             **speed_trial(scene, wearer, calibration, key, g)))
    return rows


# The analysis (`fabric-guidance beyond`): statistics, plots, summary and report section.

#: Names of the compared arms (the columns of the analyses and the plots' labels).
GAIN_ARMS = {'paper': f'G = {PAPER_GAIN:g} (paper)', 'own': 'own G (tuned)', 'oracle': 'best G (oracle)'}


def analyze_gain(results, out: dict) -> None:
    """The gain study's analyses of a StudyResults, into the parts dict `out`."""
    from scipy import stats as ss
    gain_trials = results.gain_trials_frame(GAIN_ARMS)
    out['gain_trials'] = gain_trials
    out['gain_choice'] = results.gain_choice_frame()
    out['gain_grid'] = results.gain_grid_frame()
    if not gain_trials.empty:
        main = gain_trials[gain_trials['condition'].isin([GAIN_ARMS['paper'], GAIN_ARMS['own']])]
        out['gain'] = analyze_arms(main, 'identified', True, [GAIN_ARMS['paper'], GAIN_ARMS['own']])
        ref = gain_trials[gain_trials['condition'].isin([GAIN_ARMS['paper'], GAIN_ARMS['oracle']])]
        out['gain_oracle'] = analyze_arms(ref, 'identified', True, [GAIN_ARMS['paper'], GAIN_ARMS['oracle']])
        grid = out['gain_grid']
        ev = grid[grid['phase'] == 'evaluation']
        table = ev.groupby(['wearer', 'gain'])['identified'].mean().unstack('gain')
        table.columns = [f'G={g:g}' for g in table.columns]
        out['grid_table'] = table
        out['grid'] = analyze_blocks(table, higher_is_better=True) if len(table) >= 2 else None
        choice = out['gain_choice']
        if len(choice) >= 3 and choice['tuned_gain'].nunique() > 1 and choice['oracle_gain'].nunique() > 1:
            rho, p = ss.spearmanr(choice['tuned_gain'], choice['oracle_gain'])
            out['tuned_vs_oracle'] = (float(rho), float(p))
        else:
            out['tuned_vs_oracle'] = None


def gain_plots(parts: dict, out: Path, plots: dict, trial_s: float | None = None) -> None:
    from ...core.plot_style import condition_label, measure_label
    from ..violin_plots import violin_plot
    if parts.get('gain') is not None:
        plots['gain'] = violin_plot(parts['gain'], measure_label('identified', trial_s, 'mean per wearer'),
                                    out / 'gain_identified.png', significance=parts['gain'],
                                    title=f"{condition_label(1)}: the paper's G against the wearer's own",
                                    point="one wearer's mean")


def _fmt_gains(values) -> str:
    counts = pd.Series(values).value_counts().sort_index()
    return ', '.join(f'{g:g} (x{n})' for g, n in counts.items())


def gain_summary(results, parts: dict, lines: list[str]) -> None:
    """The gain study's findings as plain sentences with their numbers, appended to `lines`."""
    paper_g = results.scene.controller.gain
    a = parts.get('gain')
    choice = parts.get('gain_choice')
    if a is not None:
        m, s = a.summary['mean'], a.summary['sd']
        pa, po = GAIN_ARMS['paper'], GAIN_ARMS['own']
        p = pair_p(a, pa, po)
        lines.append(f'Per-wearer gain ({a.n} wearers): tuned G = {_fmt_gains(choice["tuned_gain"])}; '
                     f'{int((choice["tuned_gain"] == paper_g).sum())} of {len(choice)} wearers kept the paper\'s '
                     f'{paper_g:g}.')
        lines.append(f'  identified per trial: paper G {m[pa]:.2f} (SD {s[pa]:.2f}), own G {m[po]:.2f} '
                     f'(SD {s[po]:.2f}); difference {m[po] - m[pa]:+.2f}; Friedman p = {format_p(a.p)}, '
                     f'Dunn-Bonferroni p = {format_p(p)} ({verdict(p)}); own G better for '
                     f'{int((choice["identified_own_gain"] > choice["identified_paper_gain"]).sum())}, worse for '
                     f'{int((choice["identified_own_gain"] < choice["identified_paper_gain"]).sum())}, equal for '
                     f'{int((choice["identified_own_gain"] == choice["identified_paper_gain"]).sum())} wearers.')
        ref = parts.get('gain_oracle')
        if ref is not None:
            ro = GAIN_ARMS['oracle']
            lines.append(f'  oracle (best G chosen on the evaluation trials themselves, optimistic): '
                         f'{ref.summary["mean"][ro]:.2f} (SD {ref.summary["sd"][ro]:.2f}), '
                         f'{ref.summary["mean"][ro] - ref.summary["mean"][pa]:+.2f} over the paper\'s G.')
        grid = parts.get('grid')
        if grid is not None:
            lo, hi = grid.summary['mean'].min(), grid.summary['mean'].max()
            lines.append(f'  G over the whole grid (evaluation trials): mean identified {lo:.2f} to {hi:.2f}; '
                         f'Friedman across {grid.k} gains chi2 = {grid.chi2:.2f}, p = {format_p(grid.p)}.')
        tv = parts.get('tuned_vs_oracle')
        if tv is not None:
            lines.append(f'  tuned G vs oracle G across wearers: Spearman rho = {tv[0]:+.2f} (p = {format_p(tv[1])}).')


def gain_report(results, parts: dict, plots: dict, out: Path) -> list[str]:
    """The report's section 1 (markdown lines)."""
    sc, st = results.scene, results.settings
    doc = ['## 1. Per-wearer adjustment gain', '',
           f'Condition 1 (suit, adjusted), speed protocol ({sc.protocol.trial_s:g} s trials). For each wearer every '
           f'G of the grid {", ".join(f"{g:g}" for g in st.grid)} ran on {st.tuning_reps} TUNING trials (targets '
           'and effect streams of their own); the wearer\'s G is the one with the most identified targets '
           '(ties: shorter time to find, then nearest the paper\'s G). It is stored in the calibration '
           '(`Calibration.with_gain`) and used as the pressure_controller node does with `use_wearer_gain`. '
           f'The {st.evaluation_reps} EVALUATION trials per G are the paper-speed protocol\'s own condition-1 '
           'trials (disjoint seeds from the tuning). The oracle G is the best on the evaluation trials themselves: '
           'an optimistic bound, not a usable method.', '']
    choice = parts.get('gain_choice')
    if choice is not None and not choice.empty:
        rows = [[r.wearer, f'{r.tuned_gain:g}', f'{r.oracle_gain:g}', f'{r.tuning_identified_at_tuned:.2f}',
                 f'{r.tuning_identified_at_paper:.2f}', f'{r.identified_paper_gain:.2f}',
                 f'{r.identified_own_gain:.2f}',
                 f'{r.identified_oracle_gain:.2f}'] for r in choice.itertuples()]
        doc += md_table(['wearer', 'tuned G', 'oracle G', 'tuning: at tuned G', 'tuning: at paper G',
                         'eval: paper G', 'eval: own G', 'eval: oracle G'], rows, 'lrrrrrrr')
        doc += ['', 'Mean identified targets per trial.', '']
    if parts.get('gain') is not None:
        doc += ['### Paper G vs own G (evaluation trials)', ''] + analysis_markdown(parts['gain'], level=3) + ['']
        if 'gain' in plots:
            doc += [f'![gain]({image_path(plots["gain"], out)})', '']
    if parts.get('gain_oracle') is not None:
        a = parts['gain_oracle']
        pa, ro = GAIN_ARMS['paper'], GAIN_ARMS['oracle']
        doc += ['### For reference: paper G vs the oracle G', '',
                f'{ro}: mean {a.summary["mean"][ro]:.2f} (SD {a.summary["sd"][ro]:.2f}) vs {a.summary["mean"][pa]:.2f} '
                f'(SD {a.summary["sd"][pa]:.2f}); Friedman p = {format_p(a.p)}. Chosen on the same trials it is '
                'scored on, so it is biased upward: it bounds what any per-wearer G could give here.', '']
    grid = parts.get('grid')
    if grid is not None:
        rows = [[c, f'{grid.summary.at[c, "mean"]:.2f}', f'{grid.summary.at[c, "sd"]:.2f}',
                 f'{grid.summary.at[c, "mean_rank"]:.2f}'] for c in grid.conditions]
        doc += ['### Does G matter at all? Every G on the evaluation trials', '']
        doc += md_table(['G', 'mean identified', 'SD', 'mean rank'], rows, 'lrrr')
        doc += ['', f'Friedman across the {grid.k} gains: chi-square = {grid.chi2:.2f}, df = {grid.df}, '
                    f'p = {format_p(grid.p)}, Kendall\'s W = {grid.kendall_w:.3f}.', '']
        tv = parts.get('tuned_vs_oracle')
        if tv is not None:
            doc += [f'Is the tuned G the wearer\'s real best? Spearman correlation of tuned and oracle G across '
                    f'wearers: rho = {tv[0]:+.2f}, p = {format_p(tv[1])}.', '']
    return doc
