"""`fabric-guidance sensitivity --out DIR`: which headline figures rest on which assumptions.

Every *assumed* human parameter of the scenes (every parameter of every effect the scenes list,
the population's spread a/b/c and arm_spread, and the speed protocol's dwell_s) is set low and
high (default x0.5 and x2 of the scene's value; a value of 0 goes to a small positive value;
both clipped to the parameter's valid range) one at a time, and both protocols run again on the
same wearers with the same seed (common random numbers, so every difference is paired). For
each run the headline figures:

  c1_targets       condition 1: targets found per 40 s (speed protocol; mean over wearers)
  c1_minus_c2      condition 1 minus condition 2, targets per 40 s (the paper: 1 > 2)
  c4_targets       condition 4 (speech): targets per 40 s
  c1_error_deg     condition 1: error of the true gaze at the key press (accuracy protocol,
                   hypot of h and v; before any visual capture)
  c4_error_deg     condition 4: the same

The baseline is also run with further seeds (--seeds k: other wearers, targets and noise): the
table gives each figure's mean over the k seeds with the 95 % t interval of that mean, and the
seed SD. A move is beyond noise when it exceeds the half-width of the 95 % prediction interval of
one seed's figure, t(0.975, k-1) x sqrt(1 + 1/k) seed SDs (4.97 for 3 seeds, 3.04 for 5): less
is not a finding on this many wearers. One seed has no interval, and no move is called beyond
noise.

An effect the scenes do not list cannot matter and is not swept. A parameter the scene marks
as measured or fitted is not an assumption and is not swept either: the scene's `measured` or
`fitted` attribute (names `effect.parameter`) when the scene format offers one, the
module-level MEASURED set, and --exclude.

Outputs in DIR: sensitivity.csv (one row per parameter and side: parameter, unit, scene value,
value run, the five figures and their change from the baseline, seeds, the figures it moves
beyond noise; the baseline rows first, one per seed, and last the baseline's mean over the
seeds and its interval, sides seeds_mean, seeds_lo, seeds_hi), sensitivity.md (the table sorted
by the largest move in seed SDs, with the baseline's interval over seeds), sensitivity.png (a
tornado plot per figure, the noise band and the interval drawn). One progress line per run
goes to stderr.

Also runs alone: python -m fabric_guidance.experiments.sensitivity --out DIR [--quick]
"""
from __future__ import annotations

import argparse
from dataclasses import replace
import math
import os
from pathlib import Path
import sys

from .. import subcommand
from .sensitivity_report import markdown_table, plot_tornado, write_outputs
from .sensitivity_runs import (HEADLINES, MEASURED, Parameter, SensitivityResult, Settings, apply,
                               assumed_parameters, check_settings, headlines, load_scenes,
                               quick_settings, run_sensitivity)
from .tradeoff import DEFAULT_ACCURACY_SCENE, DEFAULT_SPEED_SCENE

PROG = 'fabric-guidance sensitivity'
HELP = 'vary every assumed human parameter low and high: how much each moves the headline figures'


def _positive_int(option: str, text) -> int:
    """Parsed here, not by argparse, so a bad value gives one line naming the option."""
    try:
        v = int(str(text).strip())
    except ValueError:
        raise ValueError(f'{option} must be a whole number >= 1, got {text!r}') from None
    if v < 1:
        raise ValueError(f'{option} must be a whole number >= 1, got {v}')
    return v


def _factor(option: str, text) -> float:
    try:
        v = float(str(text).strip())
    except ValueError:
        raise ValueError(f'{option} must be a positive number, got {text!r}') from None
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f'{option} must be a positive finite factor, got {text}')
    return v


def configure(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    d = Settings()
    parser.add_argument('--out', type=Path, required=True, metavar='DIR',
                        help='folder for the table, report, plot')
    parser.add_argument('--subjects', default=None,
                        help=f'wearers (default {d.subjects}; --quick 2)')
    parser.add_argument('--repetitions', default=None,
                        help=f'accuracy trials per wearer and condition (default {d.repetitions}; '
                             '--quick 2)')
    parser.add_argument('--speed-repetitions', default=None,
                        help=f'speed trials per wearer and condition '
                             f'(default {d.speed_repetitions}; --quick 1)')
    parser.add_argument('--seeds', default=None,
                        help=f'baseline seeds for the noise (default {d.seeds}; --quick 2)')
    parser.add_argument('--low', default=None, help=f'low factor (default {d.low:g})')
    parser.add_argument('--high', default=None, help=f'high factor (default {d.high:g})')
    parser.add_argument('--parameters', default='',
                        help='comma-separated subset of the parameter keys '
                             '(e.g. reaction_delay.mean_s); '
                             'default: every assumed one')
    parser.add_argument('--exclude', default='',
                        help='comma-separated parameter keys not to sweep (measured or fitted)')
    parser.add_argument('--speed-scene', default=DEFAULT_SPEED_SCENE,
                        help='scene for the speed protocol')
    parser.add_argument('--accuracy-scene', default=DEFAULT_ACCURACY_SCENE,
                        help='scene for the accuracy protocol')
    parser.add_argument('--workers', default=min(2, os.cpu_count() or 1),
                        help='processes (default 2)')
    parser.add_argument('--quick', action='store_true',
                        help='2 wearers, 2 seeds, 20 s speed trials: seconds per run, for a check')
    return parser


def add_parser(subparsers) -> argparse.ArgumentParser:
    return subcommand.add(subparsers, 'sensitivity', HELP, __doc__, configure, run)


def _keys(text: str) -> tuple[str, ...]:
    return tuple(k.strip() for k in text.split(',') if k.strip())


def settings_from_args(args: argparse.Namespace) -> Settings:
    base = quick_settings() if args.quick else Settings()
    changes = dict(speed_scene=args.speed_scene, accuracy_scene=args.accuracy_scene,
                   parameters=_keys(args.parameters), exclude=_keys(args.exclude))
    for name in ('subjects', 'repetitions', 'speed_repetitions', 'seeds', 'workers'):
        if getattr(args, name) is not None:
            changes[name] = _positive_int(f'--{name.replace("_", "-")}', getattr(args, name))
    for name in ('low', 'high'):
        if getattr(args, name) is not None:
            changes[name] = _factor(f'--{name}', getattr(args, name))
    return replace(base, **changes)


def run(args: argparse.Namespace) -> int:
    """0 done, 2 bad arguments or scene, 1 an output could not be written."""
    try:
        settings = settings_from_args(args)
        check_settings(settings)
        spd, acc = load_scenes(settings)
        params = assumed_parameters(spd, acc, settings.exclude)
        valid = {q.key for q in assumed_parameters(spd, acc)} | {f'{e}.{p}' for e, p in MEASURED}
        for option, keys, allowed in (('--exclude', settings.exclude, valid),
                                      ('--parameters', settings.parameters,
                                       {q.key for q in params})):
            unknown = [k for k in keys if k not in allowed]
            if unknown:
                raise ValueError(f'{option}: unknown or not swept {", ".join(unknown)}; valid: '
                                 f'{", ".join(sorted(allowed))}')
        print(f'{PROG}: {len(settings.parameters) or len(params)} parameter(s), '
              f'{settings.subjects} wearers, '
              f'{settings.seeds} baseline seed(s), {settings.workers} worker(s)', file=sys.stderr,
              flush=True)
        result = run_sensitivity(settings, progress=lambda line: print(line, file=sys.stderr,
                                                                       flush=True))
    except (ValueError, OSError) as exc:
        subcommand.error(PROG, exc)
        return 2
    try:
        paths = write_outputs(result, args.out)
    except OSError as exc:
        subcommand.error(PROG, f'cannot write {exc.filename or args.out}: {exc.strerror or exc}')
        return 1
    print(markdown_table(result))
    print(f'\nsensitivity: {result.wall_s:.1f} s wall\ntable: {paths["csv"]}\n'
          f'report: {paths["md"]}\n'
          f'plot: {paths["png"]}')
    return 0


def main(argv: list[str] | None = None) -> int:
    return subcommand.main(PROG, __doc__, configure, run, argv)


__all__ = ['HEADLINES', 'MEASURED', 'Parameter', 'SensitivityResult', 'Settings', 'add_parser',
           'apply',
           'assumed_parameters', 'headlines', 'main', 'quick_settings', 'run', 'run_sensitivity',
           'plot_tornado', 'markdown_table', 'write_outputs']


if __name__ == '__main__':
    sys.exit(main())
