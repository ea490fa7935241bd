"""`fabric-guidance beyond --out DIR`: the paper's two open points, tried in simulation.

1. A per-wearer adjustment gain G (tuned on trials of its own) against the paper's G = 0.05,
   on the paper-speed protocol's condition-1 trials: identified targets per 40 s trial.
2. Moving targets (5, 10, 20 deg/s): Eq. 5 as the paper built it (theta_t taken once), Eq. 5 on
   the live target, and core.feedback's follow_target; time to find and tracking error, with
   the target visible (visual capture) and not.

Statistics as the paper's: per-wearer means, Friedman test and Dunn-Bonferroni on the Friedman
mean ranks (experiments.stats; for two conditions the same block test). How the simulation is
set up, analysed, plotted and reported: per_wearer_gain.py and moving_targets.py beside this
file (one module per study), both run on the same wearers by studies.py.

Writes DIR/beyond.md (report), DIR/*.csv (one row per trial; gain_choice.csv one row per
wearer) and DIR/*.png (violin plots); prints a summary. Deterministic for a scene.
Exit status: 0 done, 2 bad arguments or scene, 1 an output file could not be written.

Also runs alone: python -m fabric_guidance.experiments.discussion.beyond --out DIR [--subjects N] [--quick]
"""
from __future__ import annotations

import argparse
import os
from pathlib import Path
import sys

from ... import subcommand
from ...atomic import write_csv, write_text
from .moving_targets import analyze_moving, moving_plots, moving_report, moving_summary
from .per_wearer_gain import analyze_gain, gain_plots, gain_report, gain_summary

PROG = 'fabric-guidance beyond'
HELP = "beyond the paper, in simulation: a per-wearer gain G and moving targets, with the paper's statistics"


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


def analyze(results) -> dict:
    """Every analysis of a StudyResults: a dict of named parts for the report and the summary."""
    out: dict = {}
    analyze_gain(results, out)
    analyze_moving(results, out)
    return out


# ---------------------------------------------------------------------------------------------
# Plots


def make_plots(parts: dict, out: Path, trial_s: float | None = None) -> dict:
    """The violin plots; trial_s: the speed trials' length (the label of targets per trial)."""
    plots = {}
    gain_plots(parts, out, plots, trial_s)
    moving_plots(parts, out, plots)
    return plots


# ---------------------------------------------------------------------------------------------
# Text


def summary_lines(results, parts: dict) -> list[str]:
    """The findings as plain sentences with their numbers (the report's summary and stdout)."""
    lines = []
    gain_summary(results, parts, lines)
    moving_summary(results, parts, lines)
    return lines


def report_text(results, parts: dict, plots: dict, out: Path) -> str:
    sc = results.scene
    n_in, n_ex = len(results.included), len(results.exclusions)
    doc = ['# Beyond the paper: a per-wearer gain and moving targets (simulation)', '',
           f'Scene `{sc.name}` (seed {sc.seed}; effects: {", ".join(sc.effect_names) or "none"}); '
           f'{n_in} simulated wearers calibrated by Algorithm 1, {n_ex} excluded'
           + (': ' + '; '.join(f'{w}: {e}' for w, e in results.exclusions) if n_ex else '') + '. '
           f'{results.sim_s:.0f} simulated s in {results.wall_s:.1f} wall s. '
           'Set-up and keys of every trial: `fabric_guidance/experiments/discussion/per_wearer_gain.py`, '
           '`moving_targets.py`. Statistics: per-wearer means, '
           'Friedman test, Dunn-Bonferroni on the Friedman mean ranks (`fabric_guidance/experiments/stats.py`), '
           'as the paper.', '', '## Summary', '']
    doc += [f'- {line.strip()}' for line in summary_lines(results, parts)] + ['']
    doc += ['These are results of a model whose wearers, suit and effects are assumptions '
            '(config/scenes/paper-speed.yaml); they say what the options do in this model, not on people.', '']

    doc += gain_report(results, parts, plots, out)
    doc += moving_report(results, parts, plots, out)
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
    from .studies import QUICK, StudySettings, run_studies
    from ...sim.scene import SceneError, load_scene
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
    settings = QUICK if args.quick else StudySettings()

    def progress(done, total, subject):
        print(f'  wearer S{subject + 1:02d} done ({done}/{total})', file=sys.stderr, flush=True)

    results = run_studies(scene, subjects, settings, args.workers, progress)
    parts = analyze(results)
    out: Path = args.out
    try:
        out.mkdir(parents=True, exist_ok=True)
        for name in ('gain_grid', 'gain_trials', 'gain_choice', 'moving_trials'):
            write_csv(out / f'{name}.csv', parts[name])
        plots = make_plots(parts, out, results.scene.protocol.trial_s)
        write_text(out / 'beyond.md', report_text(results, parts, plots, out))
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
