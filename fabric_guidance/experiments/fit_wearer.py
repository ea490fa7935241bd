"""fit-wearer: fit the simulated wearer's free human parameters to the paper's speed results.

The model (sim/effects/) has four human parameters nobody measured: how often the wearer
misreads the suit's direction (cue_misreading.direction_p), how much resistance tells them a
move is wrong (surface_resistance.threshold_kpa_deg), how long confirming a found target takes
(hololens_view.confirm_s), and how long the synthesized speech takes per word
(speech_latency.per_word_s). They are fitted to the paper's four per-condition mean numbers of
identified targets and nothing else: the means of the columns of the paper's table
(experiments/paper.py, transcribed from the paper; or a CSV given with --table). Computed from
the table, never typed in.

Objective: sum over the conditions of ((model mean - paper mean) / paper SE)^2, with
SE = paper SD / sqrt(15). One evaluation is the full speed protocol of the scene (15 wearers,
4 conditions, 6 repetitions) with the scene seed fixed (common random numbers), so the
objective is a deterministic function of the parameters. The search runs in the unit cube of
the parameters (threshold on a log scale): the nominal start and a seeded Latin hypercube of
starting points (a fifth of --budget; the objective has local minima), then scipy's bounded
Nelder-Mead from the best of them, for --budget evaluations in all. One line per evaluation:
parameters, means, objective.

It writes the fitted scenes (paper-fitted-speed.yaml and paper-fitted-accuracy.yaml: the
paper scenes plus the new effects, the same human parameters in both) with comments saying
what was fitted, to what, on which seed, and the objective reached.

    fabric-guidance fit-wearer [--budget 60] [--out config/scenes] [--seed 2025] [--workers 2]
    python -m fabric_guidance.experiments.fit_wearer ...
"""
from __future__ import annotations

import argparse
import csv
import math
from dataclasses import dataclass
from pathlib import Path
import re
import sys
import time

import numpy as np

from .. import subcommand
from ..atomic import write_text
from ..paths import config_path
from . import paper

#: Its columns, in condition order 1-4 (sim.protocols.CONDITION_NAMES).
COLUMNS = tuple(paper.CONDITIONS[c] for c in sorted(paper.CONDITIONS))


@dataclass(frozen=True)
class Free:
    """One fitted parameter: effect, parameter, bounds, start; log: searched on a log scale."""

    effect: str
    param: str
    lo: float
    hi: float
    start: float
    log: bool = False

    def value(self, x: float) -> float:
        x = min(max(float(x), 0.0), 1.0)
        if self.log:
            return float(math.exp(math.log(self.lo) + x * (math.log(self.hi) - math.log(self.lo))))
        return float(self.lo + x * (self.hi - self.lo))

    def unit(self, value: float) -> float:
        if self.log:
            return (math.log(value) - math.log(self.lo)) / (math.log(self.hi) - math.log(self.lo))
        return (value - self.lo) / (self.hi - self.lo)


FREE = (
    Free('cue_misreading', 'direction_p', 0.0, 0.5, 0.2),
    Free('surface_resistance', 'threshold_kpa_deg', 300.0, 30000.0, 3000.0, log=True),
    Free('hololens_view', 'confirm_s', 0.0, 3.0, 0.8),
    Free('speech_latency', 'per_word_s', 0.1, 1.2, 0.5),
)

#: The new effects with their fixed (not fitted) parameters: their defaults (sim/effects/).
MODEL_EFFECTS = ('cue_misreading', 'surface_resistance', 'relative_perception', 'hololens_view')


def paper_targets(path: Path | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """(means, standard errors, subjects) of the paper's table (experiments.paper, or the CSV at
    `path`), per condition 1-4."""
    if path is None:
        means, ses = paper.speed_means(), paper.speed_standard_errors()
        conditions = sorted(paper.CONDITIONS)
        return (np.array([means[c] for c in conditions]), np.array([ses[c] for c in conditions]),
                len(paper.SPEED_TABLE_ROWS))
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
    n = table.shape[0]
    if n < 2:
        raise SystemExit(f'{path}: need at least two subjects, got {n}')
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


def speed_means(scene, subjects=None, workers: int = 2) -> np.ndarray:
    from ..sim.protocols import run_protocol, summarize
    summary = summarize(run_protocol(scene, subjects, workers))
    return np.array([summary.get(c, {}).get('identified', 0.0) for c in (1, 2, 3, 4)])


def objective(means: np.ndarray, target: np.ndarray, se: np.ndarray) -> float:
    return float(np.sum(((means - target) / se) ** 2))


def fit(base, budget: int, seed: int | None, workers: int, subjects=None, stream=sys.stdout,
        table: Path | None = None):
    """Nelder-Mead on the unit cube; returns (best values, best means, best objective, log)."""
    from scipy.optimize import minimize

    target, se, _ = paper_targets(table)
    cache: dict[tuple, tuple[float, np.ndarray]] = {}
    log: list[tuple[dict, np.ndarray, float]] = []
    best: list = [None, None, math.inf]

    def values_of(x) -> dict:
        return {(f.effect, f.param): round(f.value(xi), 6) for f, xi in zip(FREE, x)}

    def f(x) -> float:
        values = values_of(x)
        key = tuple(sorted(values.items()))
        if key in cache:
            return cache[key][0]
        if len(cache) >= budget:
            return best[2] + 1e6           # out of budget: refuse further points
        start = time.perf_counter()
        means = speed_means(model_scene(base, values, seed), subjects, workers)
        obj = objective(means, target, se)
        cache[key] = (obj, means)
        log.append((values, means, obj))
        if obj < best[2]:
            best[:] = [values, means, obj]
        shown = ' '.join(f'{p}={v:.4g}' for (_, p), v in values.items())
        took = time.perf_counter() - start
        print(f'eval {len(cache):3d}: {shown} | means {" ".join(f"{m:.2f}" for m in means)} | '
              f'objective {obj:.2f} ({took:.1f} s)', file=stream, flush=True)
        return obj

    # A seeded Latin hypercube of starting points (a fifth of the budget; the objective has
    # local minima), then Nelder-Mead from the best of them and the nominal start.
    from scipy.stats import qmc
    x0 = np.array([fr.unit(fr.start) for fr in FREE])
    n_design = min(max(budget // 5, 0), budget - 1)
    design = [x0] + list(qmc.LatinHypercube(d=len(FREE), seed=int(seed or 0)).random(n_design))
    scores = [f(x) for x in design[:budget]]
    x_best = design[int(np.argmin(scores))]
    simplex = [x_best] + [np.clip(x_best + 0.1 * np.eye(len(FREE))[i], 0.0, 1.0)
                          for i in range(len(FREE))]
    if len(cache) < budget:
        minimize(f, x_best, method='Nelder-Mead', bounds=[(0.0, 1.0)] * len(FREE),
                 options={'maxfev': budget, 'initial_simplex': np.array(simplex), 'xatol': 1e-3,
                          'fatol': 0.05})
    return best[0], best[1], best[2], log


# ---------------------------------------------------------------------------------------------
# Writing the fitted scenes

def _effect_line(name: str, params: dict, comment: str) -> str:
    inner = ', '.join(f'{k}: {v:g}' if isinstance(v, float) else f'{k}: {v}'
                      for k, v in params.items())
    return f'  - {name}: {{{inner}}}   # {comment}'


def fitted_text(base_name: str, new_name: str, values: dict, means, target, se, obj: float,
                seed: int, budget: int) -> str:
    """The base scene file's text with the fitted model: a header, the new name, the speech
    line's fitted per_word_s and the model's effects appended."""
    from ..sim.effects import effect_class
    text = config_path(f'scenes/{base_name}.yaml').read_text()
    fitted = ', '.join(f'{e}.{p} = {v:g}' for (e, p), v in values.items())
    header = [
        f'# {new_name}: {base_name} plus a wearer who can be wrong, its free human',
        '# parameters fitted by `fabric-guidance fit-wearer` '
        '(fabric_guidance/experiments/fit_wearer.py)',
        "# to the paper's four per-condition mean numbers of identified targets (the means of its",
        '# per-subject table) and nothing else, on the speed protocol with seed '
        f'{seed} ({budget} evaluations',
        '# at most: Latin hypercube, then Nelder-Mead). '
        f'Objective: sum of ((model - paper) / SE)^2 = {obj:.2f}.',
        f'# Fitted: {fitted}.',
        '# Speed means (fitted seed) vs paper (SE): ' + ', '.join(
            f'c{c} {m:.2f} vs {t:.2f} ({s:.2f})'
            for c, m, t, s in zip((1, 2, 3, 4), means, target, se)),
        '# Every other number is the base scene\'s or the effect\'s default (sim/effects/).',
        '#',
    ]
    text = re.sub(r'^name: .*$', f'name: {new_name}', text, count=1, flags=re.M)
    per_word = values[('speech_latency', 'per_word_s')]
    text, n = re.subn(r'(- speech_latency: \{[^}]*per_word_s: )[0-9.]+', rf'\g<1>{per_word:g}',
                      text)
    if n != 1:
        raise ValueError(f'{base_name}: no speech_latency line with per_word_s to set')
    text = re.sub(r'(- speech_latency: .*)$', r'\1 [per_word_s fitted]', text, count=1, flags=re.M)
    lines = text.rstrip('\n').split('\n')
    for name in MODEL_EFFECTS:
        params = {p: v for p, (v, _) in effect_class(name).parameters().items()}
        fitted_here = [p for (e, p) in values if e == name]
        params.update({p: v for (e, p), v in values.items() if e == name})
        note = (f'fitted: {", ".join(fitted_here)}; the rest defaults' if fitted_here
                else 'defaults (sim/effects/)')
        lines.append(_effect_line(name, params, note))
    return '\n'.join(header + lines) + '\n'


def write_scenes(out: Path, values: dict, means, obj: float, seed: int, budget: int,
                 table: Path | None = None) -> list[Path]:
    from ..sim.scene import load_scene
    target, se, _ = paper_targets(table)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for protocol in ('speed', 'accuracy'):
        name = f'paper-fitted-{protocol}'
        text = fitted_text(f'paper-{protocol}', name, values, means, target, se, obj, seed, budget)
        path = out / f'{name}.yaml'
        write_text(path, text, check=load_scene)   # never write a scene that does not load
        written.append(path)
    return written


# ---------------------------------------------------------------------------------------------
# Command line

PROG = 'fabric-guidance fit-wearer'
HELP = "fit the simulated wearer's human parameters to the paper's speed means"


def configure(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    p.add_argument('--budget', type=int, default=60,
                   help='objective evaluations at most (default 60)')
    p.add_argument('--out', type=Path, default=None,
                   help='folder for the fitted scenes (default config/scenes)')
    p.add_argument('--seed', type=int, default=None,
                   help="the speed scene's seed (default: paper-speed's)")
    p.add_argument('--workers', type=int, default=2, help='processes per evaluation (default 2)')
    p.add_argument('--subjects', type=int, default=None,
                   help='only the first N wearers (for a quick check)')
    p.add_argument('--table', type=Path, default=None,
                   help="a per-subject table of identified targets (CSV; default: the paper's, "
                        "experiments/paper.py)")
    return p


def add_parser(subparsers) -> argparse.ArgumentParser:
    return subcommand.add(subparsers, 'fit-wearer', HELP, __doc__, configure, run)


def run(args) -> int:
    from ..sim.scene import SceneError, load_scene
    if args.budget < 1:
        print(f'--budget must be >= 1, got {args.budget}', file=sys.stderr)
        return 2
    if args.workers < 1:
        print(f'--workers must be >= 1, got {args.workers}', file=sys.stderr)
        return 2
    try:
        base = load_scene('paper-speed')
    except SceneError as exc:
        print(exc, file=sys.stderr)
        return 2
    seed = base.seed if args.seed is None else args.seed
    if seed < 0:
        print(f'--seed must be >= 0, got {seed}', file=sys.stderr)
        return 2
    target, se, n = paper_targets(args.table)
    print(f'paper ({n} subjects): means {" ".join(f"{m:.2f}" for m in target)}, '
          f'SE {" ".join(f"{s:.2f}" for s in se)}; seed {seed}, budget {args.budget}', flush=True)
    values, means, obj, log = fit(base, args.budget, seed, args.workers, args.subjects,
                                  table=args.table)
    out = args.out if args.out is not None else config_path('scenes')
    paths = write_scenes(out, values, means, obj, seed, args.budget, args.table)
    print(f'best of {len(log)} evaluations: objective {obj:.2f}; '
          + ', '.join(f'{p} = {v:g}' for (_, p), v in values.items()))
    within = np.abs(means - target) <= se
    for c in range(4):
        print(f'  condition {c + 1}: model {means[c]:.2f}, paper {target[c]:.2f} '
              f'+- {se[c]:.2f} (SE): {"within" if within[c] else "outside"}')
    for path in paths:
        print(f'wrote {path}')
    return 0


def main(argv: list[str] | None = None) -> int:
    return subcommand.main(PROG, __doc__, configure, run, argv)


if __name__ == '__main__':
    sys.exit(main())
