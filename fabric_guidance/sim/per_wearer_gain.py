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
"""
from __future__ import annotations

import math
from typing import Iterable, Sequence

from ..core.calibration import Calibration
from ..core.feedback import PAPER_GAIN
from .node_loop import NodeLoop
from .protocols import speed_loop, speed_measures
from .scene import Scene
from .study_trials import CONDITION, TrialKey, tuning_keys

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


__all__ = ['GAIN_GRID', 'choose_gain', 'gain_means', 'run_gain_grid', 'speed_trial', 'tune_gain']
