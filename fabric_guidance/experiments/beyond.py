"""`fabric-guidance beyond --out DIR`: the paper's two open points, tried in simulation.

1. A per-wearer adjustment gain G (tuned on trials of its own) against the paper's G = 0.05,
   on the paper-speed protocol's condition-1 trials: identified targets per 40 s trial.
2. Moving targets (5, 10, 20 deg/s): Eq. 5 as the paper built it (theta_t taken once), Eq. 5 on
   the live target, and core.feedback's follow_target; time to find and tracking error, with
   the target visible (visual capture) and not.

Statistics as the paper's: per-wearer means, Friedman test and Dunn-Bonferroni on the Friedman
mean ranks (experiments.stats; for two conditions the same block test). How the simulation is
set up: fabric_guidance/sim/per_wearer_gain.py and sim/moving_targets.py.

Writes DIR/beyond.md (report), DIR/*.csv (one row per trial; gain_choice.csv one row per
wearer) and DIR/*.png (violin plots); prints a summary. Deterministic for a scene.
Exit status: 0 done, 2 bad arguments or scene, 1 an output file could not be written.

Also runs alone: python -m fabric_guidance.experiments.beyond --out DIR [--subjects N] [--quick]
"""
from __future__ import annotations

import argparse
import math
import os
from pathlib import Path
import sys

import pandas as pd

from .. import subcommand
from .report import _image_path, _md_table, analysis_markdown
from .stats import BlockAnalysis, analyze_blocks, analyze_trials, format_p

PROG = 'fabric-guidance beyond'
HELP = "beyond the paper, in simulation: a per-wearer gain G and moving targets, with the paper's statistics"

#: Names of the compared arms (the columns of the analyses and the plots' labels).
GAIN_ARMS = {'paper': 'G = 0.05 (paper)', 'own': 'own G (tuned)', 'oracle': 'best G (oracle)'}
LAW_NAMES = {'paper': 'paper: theta_t at start', 'live': 'live theta_t, no shift', 'follow': 'follow_target'}
MOVING_MEASURES = {'find_s': 'time to find (s)', 'tracking_error_deg': 'tracking error (deg)'}


def configure(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    parser.add_argument('--out', type=Path, required=True, metavar='DIR', help='folder for the report, CSVs, PNGs')
    parser.add_argument('--subjects', type=int, default=None, metavar='N',
                        help='only the first N wearers (default: the scene\'s 15; 3 with --quick)')
    parser.add_argument('--quick', action='store_true',
                        help='a short run (fewer gains, trials and speeds): a first look and the tests')
    parser.add_argument('--workers', type=int, default=min(2, os.cpu_count() or 1), help='processes (default 2)')
    parser.add_argument('--scene', default='paper-speed', help='a speed scene (default: paper-speed)')
    return parser


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the `beyond` subcommand to an argparse subparsers object; dispatch to run(args)."""
    return subcommand.add(subparsers, 'beyond', HELP, __doc__, configure, run)


def _error(message) -> None:
    print(f'{PROG}: error: {" ".join(str(message).split())}', file=sys.stderr)


# ---------------------------------------------------------------------------------------------
# Analyses


def _analyze(frame: pd.DataFrame, measure: str, higher: bool, conditions) -> BlockAnalysis | None:
    if frame.empty or frame['subject'].nunique() < 2:
        return None
    # The wearers' names (S01, ...) as the subject ids of the tables.
    return analyze_trials(frame.assign(subject=frame['wearer']), measure, higher_is_better=higher,
                          conditions=list(conditions))


def analyze(results) -> dict:
    """Every analysis of a BeyondResults: a dict of named parts for the report and the summary."""
    from scipy import stats as ss
    out: dict = {}
    gain_trials = results.gain_trials_frame(GAIN_ARMS)
    out['gain_trials'] = gain_trials
    out['gain_choice'] = results.gain_choice_frame()
    out['gain_grid'] = results.gain_grid_frame()
    if not gain_trials.empty:
        main = gain_trials[gain_trials['condition'].isin([GAIN_ARMS['paper'], GAIN_ARMS['own']])]
        out['gain'] = _analyze(main, 'identified', True, [GAIN_ARMS['paper'], GAIN_ARMS['own']])
        ref = gain_trials[gain_trials['condition'].isin([GAIN_ARMS['paper'], GAIN_ARMS['oracle']])]
        out['gain_oracle'] = _analyze(ref, 'identified', True, [GAIN_ARMS['paper'], GAIN_ARMS['oracle']])
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
    moving = results.moving_frame()
    out['moving_trials'] = moving
    out['moving'] = {}
    if not moving.empty:
        for scenario in results.settings.scenarios:
            for speed in results.settings.speeds_dps:
                part = moving[(moving['scenario'] == scenario) & (moving['speed_dps'] == float(speed))].copy()
                part['condition'] = part['law'].map(LAW_NAMES)
                for measure in MOVING_MEASURES:
                    out['moving'][(scenario, float(speed), measure)] = _analyze(part, measure, False,
                                                                                 LAW_NAMES.values())
    return out


def _pair_p(a: BlockAnalysis | None, x: str, y: str) -> float:
    return math.nan if a is None else float(a.pair(x, y)['p_adjusted'])


def _verdict(p: float) -> str:
    return 'n/a' if math.isnan(p) else ('significant' if p < 0.05 else 'not significant')


# ---------------------------------------------------------------------------------------------
# Plots


def make_plots(parts: dict, out: Path) -> dict:
    from .plots import violin_plot
    plots = {}
    if parts.get('gain') is not None:
        plots['gain'] = violin_plot(parts['gain'], 'identified targets per 40 s trial (per wearer)',
                                    out / 'gain_identified.png', significance=parts['gain'],
                                    title='Condition 1: paper G vs own G')
    for (scenario, speed, measure), a in parts['moving'].items():
        if a is None:
            continue
        name = f'moving_{scenario}_{speed:g}dps_{measure}.png'
        plots[(scenario, speed, measure)] = violin_plot(
            a, f'{MOVING_MEASURES[measure]} (per wearer)', out / name, significance=a,
            title=f'Target moving {speed:g} deg/s, {scenario}: {MOVING_MEASURES[measure]}')
    return plots


# ---------------------------------------------------------------------------------------------
# Text


def _fmt_gains(values) -> str:
    counts = pd.Series(values).value_counts().sort_index()
    return ', '.join(f'{g:g} (x{n})' for g, n in counts.items())


def summary_lines(results, parts: dict) -> list[str]:
    """The findings as plain sentences with their numbers (the report's summary and stdout)."""
    lines = []
    paper_g = results.scene.controller.gain
    a = parts.get('gain')
    choice = parts.get('gain_choice')
    if a is not None:
        m, s = a.summary['mean'], a.summary['sd']
        pa, po = GAIN_ARMS['paper'], GAIN_ARMS['own']
        p = _pair_p(a, pa, po)
        lines.append(f'Per-wearer gain ({a.n} wearers): tuned G = {_fmt_gains(choice["tuned_gain"])}; '
                     f'{int((choice["tuned_gain"] == paper_g).sum())} of {len(choice)} wearers kept the paper\'s '
                     f'{paper_g:g}.')
        lines.append(f'  identified per trial: paper G {m[pa]:.2f} (SD {s[pa]:.2f}), own G {m[po]:.2f} '
                     f'(SD {s[po]:.2f}); difference {m[po] - m[pa]:+.2f}; Friedman p = {format_p(a.p)}, '
                     f'Dunn-Bonferroni p = {format_p(p)} ({_verdict(p)}); own G better for '
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
    for scenario in results.settings.scenarios:
        for speed in results.settings.speeds_dps:
            bits = []
            for measure, unit in (('find_s', 's'), ('tracking_error_deg', 'deg')):
                a = parts['moving'].get((scenario, float(speed), measure))
                if a is None:
                    continue
                m = a.summary['mean']
                p = _pair_p(a, LAW_NAMES['paper'], LAW_NAMES['follow'])
                p_live = _pair_p(a, LAW_NAMES['live'], LAW_NAMES['follow'])
                bits.append(f'{MOVING_MEASURES[measure].split(" (")[0]} paper {m[LAW_NAMES["paper"]]:.2f} / live '
                            f'{m[LAW_NAMES["live"]]:.2f} / follow {m[LAW_NAMES["follow"]]:.2f} {unit} '
                            f'(Friedman p = {format_p(a.p)}; follow vs paper p = {format_p(p)}, '
                            f'vs live p = {format_p(p_live)})')
            if bits:
                lines.append(f'Moving target {speed:g} deg/s, {scenario}: ' + '; '.join(bits) + '.')
    return lines


def _found_table(moving: pd.DataFrame) -> list[str]:
    rows = []
    for (scenario, speed), part in moving.groupby(['scenario', 'speed_dps'], sort=False):
        row = [scenario, f'{speed:g}']
        for law in LAW_NAMES:
            g = part[part['law'] == law]
            per = g.groupby('subject')
            row.append(f'{100 * g["found"].mean():.0f} % / {per["find_s"].mean().mean():.2f} s / '
                       f'{per["tracking_error_deg"].mean().mean():.1f} / {per["late_error_deg"].mean().mean():.1f}')
        rows.append(row)
    return _md_table(['target', 'deg/s'] + [LAW_NAMES[k] for k in LAW_NAMES], rows, 'lr' + 'l' * len(LAW_NAMES))


def report_text(results, parts: dict, plots: dict, out: Path) -> str:
    sc, st = results.scene, results.settings
    n_in, n_ex = len(results.included), len(results.exclusions)
    doc = ['# Beyond the paper: a per-wearer gain and moving targets (simulation)', '',
           f'Scene `{sc.name}` (seed {sc.seed}; effects: {", ".join(sc.effect_names) or "none"}); '
           f'{n_in} simulated wearers calibrated by Algorithm 1, {n_ex} excluded'
           + (': ' + '; '.join(f'{w}: {e}' for w, e in results.exclusions) if n_ex else '') + '. '
           f'{results.sim_s:.0f} simulated s in {results.wall_s:.1f} wall s. '
           'Set-up and keys of every trial: `fabric_guidance/sim/per_wearer_gain.py`, '
           '`sim/moving_targets.py`. Statistics: per-wearer means, '
           'Friedman test, Dunn-Bonferroni on the Friedman mean ranks (`fabric_guidance/experiments/stats.py`), '
           'as the paper.', '', '## Summary', '']
    doc += [f'- {line.strip()}' for line in summary_lines(results, parts)] + ['']
    doc += ['These are results of a model whose wearers, suit and effects are assumptions '
            '(config/scenes/paper-speed.yaml); they say what the options do in this model, not on people.', '']

    # ---- 1
    doc += ['## 1. Per-wearer adjustment gain', '',
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
        doc += _md_table(['wearer', 'tuned G', 'oracle G', 'tuning: at tuned G', 'tuning: at paper G',
                          'eval: paper G', 'eval: own G', 'eval: oracle G'], rows, 'lrrrrrrr')
        doc += ['', 'Mean identified targets per trial.', '']
    if parts.get('gain') is not None:
        doc += ['### Paper G vs own G (evaluation trials)', ''] + analysis_markdown(parts['gain'], level=3) + ['']
        if 'gain' in plots:
            doc += [f'![gain]({_image_path(plots["gain"], out)})', '']
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
        doc += _md_table(['G', 'mean identified', 'SD', 'mean rank'], rows, 'lrrr')
        doc += ['', f'Friedman across the {grid.k} gains: chi-square = {grid.chi2:.2f}, df = {grid.df}, '
                    f'p = {format_p(grid.p)}, Kendall\'s W = {grid.kendall_w:.3f}.', '']
        tv = parts.get('tuned_vs_oracle')
        if tv is not None:
            doc += [f'Is the tuned G the wearer\'s real best? Spearman correlation of tuned and oracle G across '
                    f'wearers: rho = {tv[0]:+.2f}, p = {format_p(tv[1])}.', '']

    # ---- 2
    doc += ['## 2. Moving targets', '',
            f'A target starts as a speed-protocol target (within +-{sc.protocol.horizontal_deg:g} deg horizontally, '
            f'+-{sc.protocol.vertical_deg:g} deg vertically) and moves at {", ".join(f"{s:g}" for s in st.speeds_dps)} '
            'deg/s (in the horizontal and vertical angles) in a random direction, reflected at the edges of that '
            f'range; {st.moving_reps} trials per speed, {st.moving_s:g} s each, guidance throughout (condition 1, the '
            f'scene\'s G = {sc.controller.gain:g}). The same targets and effect streams for the three laws:', '',
            f'- **{LAW_NAMES["paper"]}**: Eq. 5 as the paper built it for static targets: theta_t is taken once, '
            'when guidance begins.',
            f'- **{LAW_NAMES["live"]}**: Eq. 5 fed the moving target every control step, without the shift: what '
            'the pressure_controller node does with `follow_moving_target` false.',
            f'- **{LAW_NAMES["follow"]}**: the same with `follow_target`: a change of theta_t shifts the pressure by '
            'f(new) - f(old).', '',
            'Time to find: until the tracked gaze has first stayed within '
            f'{sc.protocol.acceptance_deg:g} deg of the moving target for {sc.protocol.dwell_s:g} s (censored at '
            f'{st.moving_s:g} s when never). Tracking error: angle between the true gaze and the target, mean over the '
            'trial. *seen*: the target is visible, the eyes catch it once it is in the central field (as in the speed '
            'protocol); *unseen*: no visual capture, the suit alone guides (as in the accuracy protocol).', '',
            'Per cell: found within the trial / mean time to find / mean tracking error (deg) / mean error over '
            'the second half (deg), means over wearers.', '']
    moving = parts.get('moving_trials')
    if moving is not None and not moving.empty:
        doc += _found_table(moving) + ['']
    for (scenario, speed, measure), a in parts['moving'].items():
        if a is None:
            continue
        doc += [f'### {speed:g} deg/s, {scenario}: {MOVING_MEASURES[measure]}', ''] + analysis_markdown(a, level=3)
        doc += ['']
        if (scenario, speed, measure) in plots:
            doc += [f'![{scenario} {speed:g} {measure}]({_image_path(plots[(scenario, speed, measure)], out)})', '']
    doc += ['## Files', '',
            '- `gain_grid.csv`: every tuning and evaluation trial of the G grid (phase, gain, repetition, '
            'identified, presented, mean_find_s).',
            '- `gain_trials.csv`: the evaluation trials of the compared arms (condition = arm).',
            '- `gain_choice.csv`: per wearer, the tuned and oracle G and the means.',
            '- `moving_trials.csv`: every moving-target trial (scenario, speed, law, start, heading, found, find_s, '
            'tracking_error_deg, late_error_deg).', '']
    return '\n'.join(doc).rstrip() + '\n'


# ---------------------------------------------------------------------------------------------
# Command


def run(args: argparse.Namespace) -> int:
    from ..sim.discussion_studies import QUICK, BeyondSettings, run_beyond
    from ..sim.scene import SceneError, load_scene
    try:
        scene = load_scene(args.scene)
        if scene.protocol.kind != 'speed':
            raise ValueError(f'scene {scene.name} runs the {scene.protocol.kind} protocol; '
                             '`beyond` needs a speed scene')
        subjects = args.subjects if args.subjects is not None else (min(3, scene.population.subjects)
                                                                    if args.quick else None)
        if subjects is not None and not 2 <= subjects <= scene.population.subjects:
            raise ValueError(f'--subjects must be within 2..{scene.population.subjects} (the statistics need '
                             f'at least 2 wearers), got {subjects}')
        if args.workers < 1:
            raise ValueError(f'--workers must be >= 1, got {args.workers}')
    except (SceneError, ValueError) as exc:
        _error(exc)
        return 2
    settings = QUICK if args.quick else BeyondSettings()

    def progress(done, total, subject):
        print(f'  wearer S{subject + 1:02d} done ({done}/{total})', file=sys.stderr, flush=True)

    results = run_beyond(scene, subjects, settings, args.workers, progress)
    parts = analyze(results)
    out: Path = args.out
    try:
        out.mkdir(parents=True, exist_ok=True)
        parts['gain_grid'].to_csv(out / 'gain_grid.csv', index=False)
        parts['gain_trials'].to_csv(out / 'gain_trials.csv', index=False)
        parts['gain_choice'].to_csv(out / 'gain_choice.csv', index=False)
        parts['moving_trials'].to_csv(out / 'moving_trials.csv', index=False)
        plots = make_plots(parts, out)
        (out / 'beyond.md').write_text(report_text(results, parts, plots, out))
    except OSError as exc:
        _error(f'cannot write {exc.filename or "output"}: {exc.strerror or exc}')
        return 1
    print(f'beyond: scene {scene.name}, {len(results.included)} wearers ({len(results.exclusions)} excluded), '
          f'{"quick" if args.quick else "full"} settings; {results.sim_s:.0f} simulated s in '
          f'{results.wall_s:.1f} wall s')
    for line in summary_lines(results, parts):
        print(line)
    print(f'report: {out / "beyond.md"}')
    return 0


def main(argv: list[str] | None = None) -> int:
    return subcommand.main(PROG, __doc__, configure, run, argv)


if __name__ == '__main__':
    sys.exit(main())
