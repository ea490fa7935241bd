"""Algorithm 1's fit and acceptance over many simulated calibrations, before and after.

    python -m fabric_guidance.experiments.calibration_sweep [--n 10000] [--seed 44] [--workers 2]

Each calibration: a true law P = a*theta^b + c with b uniform in [0.4, 3], c in [-10, 60] kPa
and P_MAX reached at an angle uniform in [25, 70] deg; the paper's 10 steps up to P_MAX = 375
kPa; at each step the angle the law gives plus tracker noise (sd 0.3 deg). Half of them are
"lagged": the wearer had not come back to rest, so step n's angle carries an extra
delta * r**(n-1), delta uniform in [2, 10] deg, r = exp(-1/k) with k uniform in [0.5, 2] steps
(the offset decays over the first steps). The rest are "clean".

Each is fitted and judged twice: "before" (calibration_legacy: LM on (ln a, ln b, c) and the
acceptance of R^2, RMSE, span and reversal) and "after" (core.power_law.fit_power_law and the
default core.calibration.Acceptance). The table: accepted, refused by reason, and the error of
the accepted fits, |f_fit(theta) - f_true(theta)| with both clamped to [0, P_MAX] as the
controller clamps them, at 10, 20 and 30 deg (p50, p99, max), and how many accepted fits are
off by more than one pressure step (37.5 kPa) at any of them, for clean and lagged apart.
The numbers are in docs/calibration.md. Deterministic in --seed.
"""
from __future__ import annotations

import argparse
from collections import Counter
import math
import sys
import time

import numpy as np

from ..core.calibration import Acceptance, pressure_schedule
from ..core.power_law import CalibrationFitError, PowerLaw, fit_power_law
from ..workers import WorkerPool
from .calibration_legacy import LEGACY_ACCEPTANCE, legacy_fit

P_MAX = 375.0
STEPS = 10
NOISE_DEG = 0.3
ERROR_ANGLES = (10.0, 20.0, 30.0)
#: One of the paper's pressure steps (P_MAX / 10): an accepted fit off by more at 10, 20 or
#: 30 deg is counted apart ("accepted, off > 1 step").
STEP_KPA = P_MAX / STEPS
#: Refusal reason -> the words of its message that name it (core.calibration.Acceptance).
REASONS = (('fit error', 'fit error:'), ('span', 'angle span'), ('reversal', 'not monotonic'),
           ('R^2', 'R^2'), ('RMSE', 'RMSE'), ('exponent b', 'exponent b'), ('|c|', 'offset |c|'),
           ('dead zone from rest', 'dead zone from rest'), ('dead zone', 'dead zone'),
           ('std error', 'uncertain'))
CHUNK = 250


def simulated_calibration(seed: int, index: int):
    """(true law, pressures, angles, lagged) of calibration `index`: deterministic in both."""
    rng = np.random.default_rng([seed, index])
    b = rng.uniform(0.4, 3.0)
    c = rng.uniform(-10.0, 60.0)
    reach = rng.uniform(25.0, 70.0)
    law = PowerLaw((P_MAX - c) / reach ** b, b, c)
    p = pressure_schedule(P_MAX, STEPS)
    theta = np.asarray(law.theta(p, P_MAX)) + rng.normal(0.0, NOISE_DEG, STEPS)
    lagged = index % 2 == 1
    if lagged:
        delta = rng.uniform(2.0, 10.0)
        r = math.exp(-1.0 / rng.uniform(0.5, 2.0))
        theta = theta + delta * r ** np.arange(STEPS)
    return law, p, theta, lagged


def reason_of(message: str) -> str:
    for name, words in REASONS:
        if words in message:
            return name
    return 'other'


def judge(fit, acceptance: Acceptance, law: PowerLaw, p, theta):
    """('accepted', errors at ERROR_ANGLES) or (reason, None)."""
    try:
        report = fit(theta, p, P_MAX)
    except CalibrationFitError as exc:
        return reason_of(f'fit error: {exc}'), None
    why = acceptance.refusal(theta, report)
    if why:
        return reason_of(why), None
    grid = np.asarray(ERROR_ANGLES)
    fitted = np.clip(report.law.pressure(grid), 0.0, P_MAX)
    true = np.clip(law.pressure(grid), 0.0, P_MAX)
    return 'accepted', np.abs(fitted - true)


def run_chunk(job):
    """Calibrations [start, stop) of `seed`: per calibration (lagged, before, after)."""
    seed, start, stop = job
    acceptance = Acceptance()
    out = []
    with np.errstate(over='raise', invalid='raise', divide='raise', under='ignore'):
        for i in range(start, stop):
            law, p, theta, lagged = simulated_calibration(seed, i)
            with np.errstate(over='ignore', invalid='ignore', divide='ignore'):  # the old code warned
                before = judge(legacy_fit, LEGACY_ACCEPTANCE, law, p, theta)
            after = judge(fit_power_law, acceptance, law, p, theta)
            out.append((lagged, before, after))
    return out


def sweep(n: int, seed: int, workers: int) -> list:
    jobs = [(seed, s, min(s + CHUNK, n)) for s in range(0, n, CHUNK)]
    with WorkerPool(workers, len(jobs)) as pool:
        return [row for chunk in pool.map(run_chunk, jobs) for row in chunk]


def _pct(errors: list, q: float) -> str:
    return f'{np.percentile(errors, q):.1f}' if errors else '-'


def table(rows: list) -> str:
    """A Markdown table: per group (clean, lagged, all) and version (before, after)."""
    reasons = [name for name, _ in REASONS] + ['other']
    head = ['group', 'version', 'n', 'accepted', 'accepted, off > 1 step'] + [f'refused: {r}' for r in reasons] + [
        f'err {t:g} deg p50/p99/max kPa' for t in ERROR_ANGLES]
    lines = ['| ' + ' | '.join(head) + ' |', '|' + '---|' * len(head)]
    for group in ('clean', 'lagged', 'all'):
        sel = [r for r in rows if group == 'all' or r[0] == (group == 'lagged')]
        for v, version in ((1, 'before'), (2, 'after')):
            outcomes = Counter(r[v][0] for r in sel)
            errs = [r[v][1] for r in sel if r[v][1] is not None]
            off = sum(1 for e in errs if np.max(e) > STEP_KPA)
            cells = [group, version, str(len(sel)), str(outcomes['accepted']), str(off)]
            cells += [str(outcomes[name]) if outcomes[name] else '' for name in reasons]
            for k in range(len(ERROR_ANGLES)):
                col = [e[k] for e in errs]
                cells.append(f'{_pct(col, 50)} / {_pct(col, 99)} / {max(col):.1f}' if col else '-')
            lines.append('| ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m fabric_guidance.experiments.calibration_sweep',
                                     description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--n', type=int, default=10000, help='simulated calibrations (default 10000)')
    parser.add_argument('--seed', type=int, default=44, help='seed of the draws (default 44)')
    parser.add_argument('--workers', type=int, default=2, help='processes (default 2)')
    args = parser.parse_args(argv)
    if args.n < 1 or args.workers < 1:
        parser.error('--n and --workers must be >= 1')
    t0 = time.monotonic()
    rows = sweep(args.n, args.seed, args.workers)
    print(table(rows))
    print(f'\n{args.n} calibrations, seed {args.seed}, {args.workers} workers, '
          f'{time.monotonic() - t0:.1f} s', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
