"""`fabric-guidance tradeoff --out DIR`: what accuracy costs in time, knob by knob.

Sweeps every knob of the package that buys accuracy with time, on the scene simulator
(fabric_guidance.sim: the paper's protocols on simulated wearers calibrated by Algorithm 1,
on the fitted population of config/scenes/paper-fitted-accuracy.yaml and paper-fitted-speed.yaml
by default, settings.DEFAULT_*_SCENE; --speed-scene/--accuracy-scene choose others), and
writes for each knob value the accuracy and the time it costs, with their spread:

  acceptance_deg        speed protocol: the true gaze error when a target counts (deg) against
                        the time to find a target (s, from its appearance to the count).
  gain                  Eq. 5's G. Accuracy protocol: guidance error (deg) against the time to
                        the key press (s); speed protocol: error when a target counts against
                        the time to find it.
  calibration_steps     Algorithm 1's pressure steps per direction. The calibration time
                        (simulated seconds Algorithm 1 ran: about 4 x (rest + steps x dwell))
                        against the accuracy protocol's guidance error, and against the fitted
                        law's angle error versus the wearer's true law
                        (sim.population.law_angle_error_deg, per direction).
  control_rate_hz       how often Eq. 5 runs (Hz). Accuracy protocol: guidance error against the
                        time to the key press. Eq. 5 adds G*(f(theta_t) - f(theta)) once per
                        control step, so the rate scales the law's effective gain per second
                        (G x rate); the grid stops at the scene's 60 Hz gaze rate, which the
                        scene files do not let the control rate exceed.
  fit_tolerance         the calibration fit's xtol = ftol (core.power_law.fit_power_law,
                        CalibrationProcedure's fit_tolerance). The points Algorithm 1 recorded
                        for each wearer at the scene's settings are refitted at each tolerance:
                        the fitted law's angle error (against the true law, and against the
                        fully converged fit) against the fit's measured wall time (ms per fit).

Guidance error of an accuracy trial: hypot of the horizontal and vertical absolute errors of the
true gaze at the key press (the paper reports the two separately). Spread: mean, SD (ddof 1),
10th and 90th percentiles over trials (accuracy protocol), found targets (speed protocol),
wearer x direction (calibration law) or fits. Every knob value runs on the same wearers and the
same targets (the simulator's common random numbers), so two values are compared on paired
samples where the samples pair up.

Outputs in DIR: tradeoff.csv (one row per knob value and curve: knob, value, accuracy_metric,
accuracy_mean/sd/p10/p90, time_metric, time_mean/sd/p10/p90, n (accuracy samples), n_time (time
samples), note: timeouts, targets found per trial, censored waits, excluded wearers, function
evaluations per fit), tradeoff.md (the table, a reading of each curve generated from the
numbers by the rules of read_curve(), the plots), <knob>.png (accuracy against time: mean,
+-SD bars, p10-p90 shading, each point labelled with its value, the Pareto front drawn). The
markdown table is printed; progress goes to stderr, one line per knob value.

Over seeds (--seeds N: the scene's seed and the N-1 after it; --seeds 2025,7,11: those): the
whole sweep runs on each seed (new wearers, targets and noise), and every figure of the table
and CSV is the mean over the seeds with its 95 % t interval over the seeds (columns <figure>_lo,
<figure>_hi; each seed's mean in accuracy_mean_seed<S>, time_mean_seed<S>; every seed's own
table in tradeoff_per_seed.csv); the plots draw the intervals, and the reading states a
difference only where its interval excludes zero and says which headline finding holds
across the seeds. One seed (the default) has no interval over seeds.

Over the fitted parameters (--scene-variants FILE, a YAML list of mappings `effect.param:
value`, e.g. bootstrap draws of a fit): conditions 1-4 at the package defaults run on each
variant at one seed (the first of --seeds), written to variants.csv, variants_per_run.csv,
variants.md and variants.png, with the same means and intervals over the variants.

Also runs alone: python -m fabric_guidance.experiments.tradeoff --out DIR [--quick]
"""
from __future__ import annotations

import argparse
from dataclasses import replace
import os
from pathlib import Path
import sys

from ... import subcommand
from .intervals import check_variants, parse_seeds, read_variants, run_seeds, run_variants
from .reading import headline_lines
from .report import markdown_table, variants_table, write_outputs, write_variant_outputs
from .settings import (DEFAULT_ACCURACY_SCENE, DEFAULT_SPEED_SCENE, KNOBS, Settings, base_scenes,
                       check_settings, quick_settings)


PROG = 'fabric-guidance tradeoff'
HELP = 'sweep the knobs that buy accuracy with time; table, plots and a reading of the curves'


def configure(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    parser.add_argument('--out', type=Path, required=True, metavar='DIR', help='folder for the table, report and plots')
    parser.add_argument('--overwrite', action='store_true',
                        help='write into an --out that holds files already (refused otherwise: two runs would mix)')
    parser.add_argument('--subjects', type=int, default=None,
                        help=f'wearers per scene (default {Settings.subjects}; --quick 2)')
    parser.add_argument('--repetitions', type=int, default=None,
                        help=f'accuracy-protocol trials per wearer and value (default {Settings.repetitions}; '
                             '--quick 2)')
    parser.add_argument('--speed-repetitions', type=int, default=None,
                        help=f'speed-protocol trials per wearer and value (default {Settings.speed_repetitions}; '
                             '--quick 1)')
    parser.add_argument('--knobs', default=','.join(KNOBS), help=f'comma-separated subset of {",".join(KNOBS)}')
    parser.add_argument('--condition', type=int, default=1, choices=(1, 2, 3),
                        help='guidance condition (1 suit adjusted, 2 suit fixed, 3 arm adjusted)')
    parser.add_argument('--accuracy-scene', default=DEFAULT_ACCURACY_SCENE,
                        help='scene for the accuracy-protocol curves (a speed scene gets the accuracy protocol\'s '
                             'defaults)')
    parser.add_argument('--speed-scene', default=DEFAULT_SPEED_SCENE,
                        help='scene for the speed-protocol curves (an accuracy scene gets the speed protocol\'s '
                             'defaults)')
    parser.add_argument('--workers', type=int, default=min(2, os.cpu_count() or 1), help='processes')
    parser.add_argument('--quick', action='store_true',
                        help='a tiny sweep: 2 wearers, 3 values per knob, 20 s speed trials (seconds, for a check)')
    parser.add_argument('--seeds', default=None, metavar='N|S1,S2,...',
                        help='run the whole sweep on N seeds (the scene\'s and the next ones) or on the listed '
                             'seeds; every figure then has a 95 %% t interval over the seeds (default: the scene\'s '
                             'seed alone, no interval)')
    parser.add_argument('--scene-variants', type=Path, default=None, metavar='FILE',
                        help='YAML list of scene-value overrides ("effect.param: value" per variant, e.g. bootstrap '
                             'draws of the fitted parameters): run conditions 1-4 at the package defaults on each '
                             'variant (at the first seed) instead of the knob sweep')
    parser.add_argument('--no-plane', action='store_true',
                        help='only the per-knob curves: no conditions 1-4, no plane.png (faster)')
    return parser


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the `tradeoff` subcommand to an argparse subparsers object; dispatch to run(args)."""
    return subcommand.add(subparsers, 'tradeoff', HELP, __doc__, configure, run)


def settings_from_args(args: argparse.Namespace) -> Settings:
    base = quick_settings() if args.quick else Settings()
    changes = dict(condition=args.condition, workers=args.workers, accuracy_scene=args.accuracy_scene,
                   plane=not args.no_plane,
                   speed_scene=args.speed_scene,
                   knobs=tuple(k.strip() for k in args.knobs.split(',') if k.strip()))
    for name in ('subjects', 'repetitions', 'speed_repetitions'):
        if getattr(args, name) is not None:
            changes[name] = getattr(args, name)
    return replace(base, **changes)


def run(args: argparse.Namespace) -> int:
    """0 done, 2 bad arguments, scene or variants file, 1 an output could not be written."""
    variants = None
    try:
        why = subcommand.results_folder(args.out, args.overwrite)
        if why:
            raise ValueError(why)
        settings = settings_from_args(args)
        acc, spd = base_scenes(settings)
        check_settings(settings, acc)
        seeds = (spd.seed,) if args.seeds is None else parse_seeds(args.seeds, spd.seed)
        if args.scene_variants is not None:
            if len(seeds) > 1:
                raise ValueError('--scene-variants runs every variant at one seed; give --seeds one seed '
                                 '(e.g. --seeds 7,)')
            variants = read_variants(args.scene_variants)
            try:
                check_variants(settings, variants, seeds[0])
            except ValueError as exc:
                raise ValueError(f'{args.scene_variants}: {exc}') from None
    except (ValueError, OSError) as exc:
        subcommand.error(PROG, exc)
        return 2
    say = lambda line: print(line, file=sys.stderr, flush=True)  # noqa: E731
    if variants is not None:
        print(f'{PROG}: conditions 1-4 on {len(variants)} variant(s) of {args.scene_variants}, seed {seeds[0]}, '
              f'{settings.subjects} wearers, {settings.workers} worker(s)', file=sys.stderr, flush=True)
        result = run_variants(settings, variants, seeds[0], say)
        try:
            paths = write_variant_outputs(result, args.out)
        except OSError as exc:
            subcommand.error(PROG, f'cannot write {exc.filename or args.out}: {exc.strerror or exc}')
            return 1
        print(variants_table(result))
        print(f'\nvariants: {result.wall_s:.1f} s wall\ntable: {paths["csv"]}\nreport: {paths["md"]}\n'
              f'plot: {paths["png"]}')
        return 0
    print(f'{PROG}: {len(settings.knobs)} knob(s), {settings.subjects} wearers, {len(seeds)} seed(s), '
          f'{settings.workers} worker(s)', file=sys.stderr, flush=True)
    result = run_seeds(settings, seeds, progress=say)
    try:
        paths = write_outputs(result, args.out)
    except OSError as exc:
        subcommand.error(PROG, f'cannot write {exc.filename or args.out}: {exc.strerror or exc}')
        return 1
    print(markdown_table(result.frame()))
    print()
    for (knob, am, tm), text in result.readings.items():
        print(f'{knob} ({am} vs {tm}): {text}\n')
    if result.runs > 1:
        print('\n'.join(['headline findings across the seeds:'] + headline_lines(result)) + '\n')
    print(f'sweep: {result.wall_s:.1f} s wall; ' + ', '.join(f'{k} {v:.1f} s' for k, v in result.knob_wall_s.items()))
    print(f'table: {paths["csv"]}\nreport: {paths["md"]}\nplots: '
          + ', '.join(str(paths[k]) for k in ('plane',) + settings.knobs if k in paths))
    return 0


def main(argv: list[str] | None = None) -> int:
    return subcommand.main(PROG, __doc__, configure, run, argv)


if __name__ == '__main__':
    sys.exit(main())
