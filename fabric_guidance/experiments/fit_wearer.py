"""fit-wearer: fit the simulated population to the paper's whole speed table, across seeds.

The model (sim/effects/) has human parameters nobody measured, and people differ in them. The
fit gives each wearer their own values (population traits, sim.scene.TraitSpec) and fits six
traits (experiments/population_fit.py: how often the suit's and the arm band's cue is misread,
a person's search pace and their pace with speech, with medians and spreads; a familiarity with
haptic cues shared by conditions 1-3 and a reaction time shared by all four, spreads only) to
eighteen numbers of the paper's per-subject table (experiments/paper.py, or a CSV given with
--table): the four condition means, the four SDs of the subject means, the best-condition
counts and the six correlations between conditions. One more trait is assumed, not fitted.
How far the arm muscles' law of condition 3 differs from the suit's (population.arm_spread) is
profiled: a design per value (--arm-spread), the fit on each, the lowest objective kept.

The speed protocol runs once on a design population (--design-seeds, --wearers per seed; none
of them a seed of the validation; --rounds, each after the first around the fit so far), every
profiled arm_spread on the same wearers (condition 3 per value, the rest once), then every
candidate population is the design reweighted (importance weights): a fit takes seconds. A
bootstrap (--bootstrap N: design wearers and the paper's subjects resampled, the fit repeated
on every design, the best kept) gives each fitted number its interval and the variants file
(fit/variants.yaml in --out: one scene override set per bootstrap fit) that `tradeoff
--scene-variants` runs. The designs are saved
(fit/design-arm_spread-<value>.npz) and --design reuses them: the shipped scenes are reproduced
from the shipped designs in seconds. --scheduler runs the design and the bootstrap on a Dask
distributed cluster (workers.WorkerPool): the same results.

It writes the fitted scenes (paper-fitted-speed.yaml and paper-fitted-accuracy.yaml: the paper
scenes plus the model's effects at the fitted medians and the population's traits, the same in
both) with comments saying what was fitted, to what, on which seeds, and the statistics reached.
Validation on other seeds: `fabric-guidance compare-paper --seeds ...`.

    fabric-guidance fit-wearer [--out config/scenes] [--design-seeds 101,...,106] [--wearers 40] [--rounds 3]
                               [--arm-spread 0,0.1,0.2] [--bootstrap 200] [--design FILE ...]
                               [--workers 2] [--scheduler HOST:PORT] [--table CSV]
    python -m fabric_guidance.experiments.fit_wearer ...
"""
from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path
import re
import sys
import time
from typing import NamedTuple, Sequence

import numpy as np

from .. import subcommand
from ..atomic import write_text
from ..paths import config_path
from . import paper
from . import population_fit as pf

#: Its columns, in condition order 1-4 (sim.protocols.CONDITION_NAMES).
COLUMNS = tuple(paper.CONDITIONS[c] for c in sorted(paper.CONDITIONS))

#: The effects the wearer model adds to the paper scenes.
MODEL_EFFECTS = ('cue_misreading', 'surface_resistance', 'relative_perception', 'hololens_view')
#: Fixed, not fitted: the resistance a wrong move meets before the wearer notices it, kPa/deg
#: (the earlier four-parameter fit's value; at that size the mechanism rarely acts).
#: edge_deg: a wearer looking for an object turns no further than the region the objects are
#: in (the paper's +-60 / +-30 deg, which its participants saw), chosen, not fitted: without it a
#: misread under Eq. 5's rising pull runs to the seat's 120 deg and the lost trials, not the
#: person, decide a wearer's mean (seed 556-560, the 3.0 s fit: correlations 1-3 / 3-4 0.70 /
#: 0.66 without, 0.84 / 0.71 with, before any refit).
FIXED = {('surface_resistance', 'threshold_kpa_deg'): 26603.9, ('hololens_view', 'edge_deg'): 0.0}
#: The parameters the fit sets (their medians; sensitivity does not sweep them).
FITTED_PARAMS: tuple[tuple[str, str], ...] = tuple(
    tuple(q.split('.')) for t in pf.FITTED if t.design_values for q in t.params)


def read_table(path: Path | None = None) -> np.ndarray:
    """The per-subject table (subjects x conditions 1-4): the paper's, or the CSV at `path`."""
    if path is None:
        return pf.paper_table()
    try:
        with open(path, newline='') as f:
            rows = list(csv.DictReader(f))
    except OSError as exc:
        raise SystemExit(f'{path}: cannot read the paper table: {exc.strerror}')
    missing = [c for c in COLUMNS if not rows or c not in rows[0]]
    if missing:
        raise SystemExit(f'{path}: column "{missing[0]}" is missing (need {", ".join(COLUMNS)})')
    try:
        table = np.array([[float(r[c]) for c in COLUMNS] for r in rows])
    except (TypeError, ValueError) as exc:
        raise SystemExit(f'{path}: a value is not a number: {exc}')
    if table.shape[0] < 4:
        raise SystemExit(f'{path}: need at least four subjects, got {table.shape[0]}')
    return table


def paper_targets(path: Path | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """(means, standard errors, subjects) of the table, per condition 1-4."""
    table = read_table(path)
    n = table.shape[0]
    return table.mean(axis=0), table.std(axis=0, ddof=1) / math.sqrt(n), n


def model_scene(base, values: dict[tuple[str, str], float], seed: int | None = None):
    """The base scene with the model's effects and the given parameter values."""
    entries = []
    for spec in base.effects:
        params = dict(spec.params)
        params.update({p: v for (e, p), v in values.items() if e == spec.name})
        entries.append({spec.name: params})
    listed = {spec.name for spec in base.effects}
    for name in MODEL_EFFECTS:
        if name not in listed:
            entries.append({name: {p: v for (e, p), v in values.items() if e == name}})
    scene = base.with_effects(entries)
    return scene if seed is None else scene.replace(seed=int(seed))


def base_scene(protocol: str = 'speed', arm_spread: float | None = None):
    """paper-<protocol> with the model's effects listed, the fixed values and arm_spread (None:
    the paper scene's)."""
    from ..sim.scene import load_scene
    scene = model_scene(load_scene(f'paper-{protocol}'), FIXED)
    return scene if arm_spread is None else scene.with_value('population.arm_spread', float(arm_spread))


# ---------------------------------------------------------------------------------------------
# Reporting

STAT_NAMES = {'means': 'mean', 'sds': 'SD of subject means', 'best': 'best-condition count',
              'corr': 'correlation', 'trial_sds': 'SD over all trials (reported, not fitted)'}
PAIRS = ('1-2', '1-3', '1-4', '2-3', '2-4', '3-4')


def statistics_lines(model: dict, target: dict) -> list[str]:
    lines = []
    for key, label in STAT_NAMES.items():
        if key not in model or key not in target:      # trial SDs: a design that recorded its trials
            continue
        names = PAIRS if key == 'corr' else [f'c{c}' for c in pf.CONDITIONS]
        lines.append(f'{label}: ' + ', '.join(f'{nm} {m:.2f} vs {t:.2f}'
                                              for nm, m, t in zip(names, model[key], target[key])))
    return lines


def phi_lines(phi, boot: np.ndarray | None) -> list[str]:
    mus, sds = pf.split(phi)
    if boot is not None and len(boot):
        bmu, bsd = np.array([pf.split(b)[0] for b in boot]), np.array([pf.split(b)[1] for b in boot])
    lines = []
    for i, t in enumerate(pf.FITTED):
        medians = {q: pf.shifted(v, mus[i], t.scale) for q, v in zip(t.params, t.design_values)}
        interval = ''
        if boot is not None and len(boot):
            lo_sd, hi_sd = np.percentile(bsd[:, i], [2.5, 97.5])
            interval = f'; 95 % bootstrap: sd [{lo_sd:.3g}, {hi_sd:.3g}]'
            if t.design_values:
                lo_mu, hi_mu = np.percentile(bmu[:, i], [2.5, 97.5])
                q0, v0 = t.params[0], t.design_values[0]
                interval = (f'; 95 % bootstrap: {q0} [{pf.shifted(v0, lo_mu, t.scale):.4g}, '
                            f'{pf.shifted(v0, hi_mu, t.scale):.4g}], sd [{lo_sd:.3g}, {hi_sd:.3g}]')
        where = ', '.join(f'{q} = {v:.4g}' for q, v in medians.items()) or f'on {", ".join(t.params)}'
        lines.append(f'{t.name} ({t.scale}): {where}, sd {sds[i]:.3g}{interval}')
    return lines


# ---------------------------------------------------------------------------------------------
# Writing the fitted scenes

def _effect_line(name: str, params: dict, comment: str) -> str:
    inner = ', '.join(f'{k}: {v:g}' if isinstance(v, float) else f'{k}: {v}'
                      for k, v in params.items())
    return f'  - {name}: {{{inner}}}   # {comment}'


ARM_SPREAD_LINES = re.compile(r'^  # Condition 3 drives arm muscles.*\n(?:  # .*\n)*  arm_spread: .*$', re.M)


def fitted_text(base_name: str, new_name: str, phi, header: list[str], arm_spread: float) -> str:
    """The base scene file's text with the fitted population: a header, the new name, the
    profiled arm_spread, the traits in the population section, the speech line's median
    per_word_s and the model's effects appended."""
    from ..sim.effects import effect_class
    values = pf.trait_values(phi)
    medians = {tuple(q.split('.')): v for m, _ in values.values() for q, v in m.items()}
    medians.update(FIXED)
    text = config_path(f'scenes/{base_name}.yaml').read_text()
    text = re.sub(r'^name: .*$', f'name: {new_name}', text, count=1, flags=re.M)
    for (effect, param), value in medians.items():
        if effect in MODEL_EFFECTS:         # appended below
            continue
        text, n = re.subn(rf'(- {effect}: \{{[^}}]*{param}: )[0-9.]+', rf'\g<1>{value:.6g}', text)
        if n != 1:
            raise ValueError(f'{base_name}: no {effect} line with {param} to set')
        text = re.sub(rf'(- {effect}: .*)$', rf'\1 [{param}: fitted median]', text, count=1, flags=re.M)
    arm = ["  # Condition 3 drives the arm muscles with the suit's calibration (the paper); how far the",
           "  # arm's law differs from the suit's (lognormal sigma on a) is profiled by fit-wearer (header).",
           f'  arm_spread: {arm_spread:g}']
    text, n = ARM_SPREAD_LINES.subn(lambda m: '\n'.join(arm), text, count=1)
    if n != 1:
        raise ValueError(f'{base_name}: no "# Condition 3 drives arm muscles" comment and arm_spread line to set')
    traits = ['  # Between-person traits (fabric-guidance fit-wearer): each wearer draws u ~ N(0, sd) per',
              "  # trait and every listed parameter moves by u on the trait's scale around the value",
              '  # this scene gives it (the population median).',
              '  traits:']
    sds = {name: sd for name, (_, sd) in values.items()}
    for t in pf.FITTED:
        traits.append(f'    {t.name}: {{sd: {sds[t.name]:.4g}, scale: {t.scale}, params: [{", ".join(t.params)}], '
                      f'source: "{t.source}"}}')
    for t in pf.ASSUMED:
        traits.append(f'    {t.name}: {{sd: {t.sd:g}, scale: {t.scale}, params: [{", ".join(t.params)}], '
                      f'source: "{t.source}"}}')
    text, n = re.subn(r'^(  arm_spread: .*)$', lambda m: m.group(1) + '\n' + '\n'.join(traits), text,
                      count=1, flags=re.M)
    if n != 1:
        raise ValueError(f'{base_name}: no population.arm_spread line to put the traits after')
    lines = text.rstrip('\n').split('\n')
    for name in MODEL_EFFECTS:
        # An optional parameter left at its default (None: off) is not written: YAML would read
        # the word None as a string, and leaving it out is that default.
        params = {p: v for p, (v, _) in effect_class(name).parameters().items() if v is not None}
        set_here = {p: v for (e, p), v in medians.items() if e == name}
        params.update(set_here)
        fitted_here = [p for p in set_here if (name, p) in FITTED_PARAMS]
        fixed_here = [p for p in set_here if (name, p) in FIXED]
        note = '; '.join(([f'fitted medians: {", ".join(fitted_here)}'] if fitted_here else [])
                         + ([f'fixed: {", ".join(fixed_here)}'] if fixed_here else [])
                         + ['the rest defaults (sim/effects/)'])
        lines.append(_effect_line(name, {k: round(v, 6) if isinstance(v, float) else v
                                         for k, v in params.items()}, note))
    return '\n'.join(header + lines) + '\n'


def _write(path: Path, text: str, check=None) -> Path:
    """Atomically, after check(the written file) passed: never a scene that does not load."""
    return write_text(path, text, check=check)


def write_scenes(out: Path, phi, header: list[str], arm_spread: float) -> list[Path]:
    """paper-fitted-speed.yaml and paper-fitted-accuracy.yaml; `header` may name {name} and
    {base}, the scene and its base."""
    from ..sim.scene import load_scene
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for protocol in ('speed', 'accuracy'):
        name, base = f'paper-fitted-{protocol}', f'paper-{protocol}'
        head = [h.replace('{name}', name).replace('{base}', base) for h in header]
        paths.append(_write(out / f'{name}.yaml', fitted_text(base, name, phi, head, arm_spread), load_scene))
    return paths


def variants_text(boot: np.ndarray, arm_spreads: Sequence[float]) -> str:
    """One override set per bootstrap fit: effect.parameter medians, population.arm_spread and
    population.traits sds."""
    import yaml
    rows = []
    for phi, arm in zip(boot, arm_spreads):
        values = pf.trait_values(phi)
        row = {q: round(v, 6) for m, _ in values.values() for q, v in m.items()}
        row['population.arm_spread'] = float(arm)
        row.update({f'population.traits.{name}.sd': round(sd, 6) for name, (_, sd) in values.items()})
        rows.append(row)
    return ('# Bootstrap fits of fabric-guidance fit-wearer: each entry is one plausible population\n'
            '# (design wearers and paper subjects resampled, the fit repeated).\n'
            + yaml.safe_dump(rows, sort_keys=True))


# ---------------------------------------------------------------------------------------------
# Command line

PROG = 'fabric-guidance fit-wearer'
HELP = "fit the simulated population to the paper's whole speed table across seeds"


def _comma_list(text: str, convert, option: str, kind: str) -> tuple:
    try:
        values = tuple(convert(s) for s in str(text).split(',') if s.strip())
    except ValueError:
        raise SystemExit(f'{option} must be {kind} separated by commas, got {text!r}')
    return values


def _seeds(text: str) -> tuple[int, ...]:
    seeds = _comma_list(text, int, '--design-seeds', 'whole numbers')
    if not seeds or any(s < 0 for s in seeds):
        raise SystemExit(f'--design-seeds must be whole numbers >= 0, got {text!r}')
    return seeds


def _arm_spreads(text: str) -> tuple[float, ...]:
    values = _comma_list(text, float, '--arm-spread', 'numbers')
    if not values or any(not 0.0 <= v <= 3.0 for v in values) or len(set(values)) != len(values):
        raise SystemExit(f'--arm-spread must be distinct numbers in [0, 3], got {text!r}')
    return values


def design_path(out: Path, arm_spread: float) -> Path:
    return out / 'fit' / f'design-arm_spread-{arm_spread:g}.npz'


def configure(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    p.add_argument('--out', type=Path, default=None,
                   help='folder for the fitted scenes and the variants file (default config/scenes)')
    p.add_argument('--design-seeds', default=','.join(map(str, pf.DESIGN_SEEDS)),
                   help='seeds of the design population (default %(default)s)')
    p.add_argument('--wearers', type=int, default=pf.DESIGN_WEARERS,
                   help='design wearers per seed (default %(default)s)')
    p.add_argument('--rounds', type=int, default=pf.DESIGN_ROUNDS,
                   help='design rounds, the seeds split among them in order (default %(default)s; at most '
                        'one per seed)')
    p.add_argument('--arm-spread', default=','.join(f'{v:g}' for v in pf.ARM_SPREADS),
                   help='values of population.arm_spread to profile, a design each (default %(default)s; '
                        'with --design, the designs\' own)')
    p.add_argument('--design', type=Path, nargs='+', default=None,
                   help='design files of an earlier run to reuse, one per arm_spread (skips the simulation)')
    p.add_argument('--bootstrap', type=int, default=200, help='bootstrap refits (default 200; 0: none)')
    p.add_argument('--workers', type=int, default=2, help='processes for the design and the bootstrap (default 2)')
    p.add_argument('--scheduler', default=None,
                   help='address of a Dask distributed scheduler (host:port) to run the design and the '
                        'bootstrap on instead of local processes (needs the distributed package)')
    p.add_argument('--table', type=Path, default=None,
                   help="a per-subject table of identified targets (CSV; default: the paper's, "
                        "experiments/paper.py)")
    return p


def add_parser(subparsers) -> argparse.ArgumentParser:
    return subcommand.add(subparsers, 'fit-wearer', HELP, __doc__, configure, run)


def load_design(path: Path) -> pf.Design:
    try:
        design = pf.Design.load(path)
    except (OSError, KeyError, ValueError) as exc:
        raise SystemExit(f'{path}: not a design file of fit-wearer: {exc}')
    if design.u.ndim != 2 or design.u.shape[1] != len(pf.FITTED) or design.y.shape != (len(design.u), 4):
        raise SystemExit(f'{path}: a design of {design.u.shape} traits and {design.y.shape} means does not '
                         f'match the {len(pf.FITTED)} fitted traits')
    if design.arm_spread is None:
        raise SystemExit(f'{path}: the design does not record its arm_spread (made before the profile); '
                         'run fit-wearer without --design')
    return design


def load_designs(paths: Sequence[Path]) -> list[pf.Design]:
    designs, first = [], {}
    for path in paths:
        design = load_design(path)
        if design.arm_spread in first:
            raise SystemExit(f'{path}: a second design of arm_spread {design.arm_spread:g} (the first: '
                             f'{first[design.arm_spread]}); give one per value')
        first[design.arm_spread] = path
        designs.append(design)
    return designs


class ProfileFit(NamedTuple):
    """The fit on one profiled design: phi, objective, effective design wearers, and the
    statistics the weighted design reaches for n people."""

    phi: np.ndarray
    objective: float
    ess: float
    model: dict


def simulate_designs(bases, seeds, wearers: int, workers: int, target: dict, n: int, say,
                     scheduler: str | None = None, rounds: int = pf.DESIGN_ROUNDS) -> list[pf.Design]:
    """One design per base scene (a value of arm_spread each), simulated together (each wearer's
    calibration and conditions 1, 2, 4 once: pf.run_designs), in `rounds` rounds on the seeds
    split in order. Round 1: wide spreads around the design values; each later round: around the
    best fit on the rounds so far (the lowest objective over the profiled values), so that the
    fitted population has design wearers near it, not only the few far out in round 1's tails
    whose own trials happened to suit the table."""
    groups = [tuple(int(s) for s in g) for g in np.array_split(np.array(seeds), min(rounds, len(seeds)))]
    arms = ', '.join(f'{b.population.arm_spread:g}' for b in bases)
    print(f'design round 1 of {len(groups)}: the speed protocol on {wearers} wearers of each seed '
          f'{", ".join(map(str, groups[0]))}, condition 3 at arm_spread {arms}', flush=True)
    designs = pf.run_designs(bases, groups[0], wearers, workers, say, scheduler=scheduler)
    for r, group in enumerate(groups[1:], start=2):
        fits = [pf.fit_population(d, target, n, restarts=0) for d in designs]     # only to place the round
        mu, sd = pf.focused(min(fits, key=lambda f: f[1])[0])
        print(f'design round {r} of {len(groups)}, around the best fit so far: {wearers} wearers of each seed '
              f'{", ".join(map(str, group))}', flush=True)
        more = pf.run_designs(bases, group, wearers, workers, say, mu, sd, scheduler=scheduler)
        designs = [d.joined(m) for d, m in zip(designs, more)]
    return designs


def fit_design(design: pf.Design, target: dict, n: int) -> ProfileFit:
    phi, obj = pf.fit_population(design, target, n)
    w = pf.weights(design, phi)
    return ProfileFit(phi, obj, 1.0 / float(np.sum(w ** 2)), pf.weighted_statistics(design, w, n))


def run(args) -> int:
    from ..sim.scene import SceneError
    for name in ('wearers', 'workers', 'rounds'):
        if getattr(args, name) < 1:
            print(f'--{name} must be >= 1, got {getattr(args, name)}', file=sys.stderr)
            return 2
    if args.bootstrap < 0:
        print(f'--bootstrap must be >= 0, got {args.bootstrap}', file=sys.stderr)
        return 2
    seeds = _seeds(args.design_seeds)
    if args.design is None and args.rounds > len(seeds):
        print(f'--rounds {args.rounds} needs at least as many --design-seeds, got {len(seeds)}', file=sys.stderr)
        return 2
    arm_spreads = _arm_spreads(args.arm_spread)
    table = read_table(args.table)
    n = table.shape[0]
    target = pf.table_statistics(table)
    out = args.out if args.out is not None else config_path('scenes')
    (out / 'fit').mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    if args.design is not None:
        designs = load_designs(args.design)
        for path, design in zip(args.design, designs):
            print(f'design: {len(design.y)} wearers of arm_spread {design.arm_spread:g} from {path}', flush=True)
    else:
        def say(s):
            print(f'  {time.perf_counter() - start:6.0f} s  {s}', flush=True)

        try:
            bases = [base_scene('speed', arm) for arm in arm_spreads]
        except (SceneError, ValueError) as exc:
            print(exc, file=sys.stderr)
            return 2
        designs = simulate_designs(bases, seeds, args.wearers, args.workers, target, n, say, args.scheduler,
                                   args.rounds)
        for arm, design in zip(arm_spreads, designs):
            design.save(design_path(out, arm))
    designs.sort(key=lambda d: d.arm_spread)     # the profile's order, whatever the command line's
    design_s = time.perf_counter() - start
    t0 = time.perf_counter()
    fits = []
    for design in designs:
        fit = fit_design(design, target, n)
        fits.append(fit)
        print(f'fit at arm_spread {design.arm_spread:g}: objective {fit.objective:.2f} over 18 statistics, '
              f'{len(pf.bounds())} parameters; effective design wearers {fit.ess:.0f}', flush=True)
        for line in statistics_lines(fit.model, target):
            print('    ' + line)
    best = int(np.argmin([f.objective for f in fits]))
    phi, obj, ess, model = fits[best]
    design, arm = designs[best], designs[best].arm_spread
    fit_s = time.perf_counter() - t0
    print(f'kept arm_spread {arm:g} ({fit_s:.1f} s)')
    boot, kept = None, None
    if args.bootstrap:
        boot, kept = pf.bootstrap(designs, table, [f.phi for f in fits], args.bootstrap, seed=1,
                                  progress=lambda r, k: print(f'  bootstrap {r}/{k}', flush=True)
                                  if r % 20 == 0 or r == k else None, workers=args.workers,
                                  scheduler=args.scheduler)
        _write(out / 'fit' / 'variants.yaml', variants_text(boot, [designs[i].arm_spread for i in kept]))
    for line in phi_lines(phi, boot):
        print('  ' + line)
    for line in statistics_lines(model, target):
        print('  ' + line)
    profile = ', '.join(f'{d.arm_spread:g}: {f.objective:.2f}' for d, f in zip(designs, fits))
    chosen = '' if kept is None else (
        f'; the bootstrap kept {arm:g} in {int(np.sum(kept == best))} of {len(kept)} refits ('
        + ', '.join(f'{d.arm_spread:g}: {int(np.sum(kept == i))}' for i, d in enumerate(designs)) + ')')
    header = [
        '# {name}: {base} plus a wearer model with people who differ, fitted by `fabric-guidance',
        "# fit-wearer` (fabric_guidance/experiments/fit_wearer.py, population_fit.py) to the paper's",
        '# per-subject speed table: 4 means, 4 SDs of subject means, 4 best-condition counts, 6 correlations',
        f'# between conditions (18 numbers, {len(pf.bounds())} fitted parameters and arm_spread profiled), '
        'on a design of',
        f'# {len(design.y)} wearers from seeds {", ".join(map(str, sorted(set(int(s) for s in design.seeds))))}'
        f' (importance-weighted; effective wearers {ess:.0f}).',
        f'# Objective (sum of squared standardized distances) {obj:.2f}. Validate on other seeds:',
        '# fabric-guidance compare-paper --seeds ...',
        f'# arm_spread profiled (a design per value, objective): {profile}; kept {arm:g}{chosen}',
    ] + ['# ' + line for line in phi_lines(phi, boot)] + [
        '# Reached, model vs paper:'] + ['#   ' + line for line in statistics_lines(model, target)] + [
        "# Every other number is the base scene's or the effect's default (sim/effects/).", '#']
    paths = write_scenes(out, phi, header, arm)
    print(f'design {design_s:.0f} s, fit {fit_s:.1f} s, total {time.perf_counter() - start:.0f} s')
    for path in paths:
        print(f'wrote {path}')
    return 0


def main(argv: list[str] | None = None) -> int:
    return subcommand.main(PROG, __doc__, configure, run, argv)


if __name__ == '__main__':
    sys.exit(main())
