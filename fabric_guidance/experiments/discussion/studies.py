"""Both open points of the paper's Discussion on the same simulated wearers, in parallel over
wearers (`fabric-guidance beyond`): each wearer is calibrated by Algorithm 1, then runs the
per-wearer gain study (per_wearer_gain.py) and the moving-target study (moving_targets.py).

Random numbers: a trial is a pure function of (scene, wearer, phase, repetition, and its
settings); arms compared with each other share targets and effect streams (common random
numbers), so they differ only by the controller.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math
import time
from typing import Callable, Iterable

from ...sim.engine import package_channel_map
from ...sim.population import calibrate_wearer, sample_wearer, subject_indices
from ...sim.scene import Scene
from ...workers import WorkerPool
from .moving_targets import LAWS, SCENARIOS, moving_trial
from .per_wearer_gain import GAIN_GRID, choose_gain, gain_means, run_gain_grid, tune_gain
from .trials import TrialKey, evaluation_keys


@dataclass(frozen=True)
class StudySettings:
    """How much of both studies runs: the G grid and trial counts of the gain study, the speeds,
    trial counts, length and scenarios of the moving-target study."""

    grid: tuple[float, ...] = GAIN_GRID
    tuning_reps: int = 4             # tuning speed trials per G
    evaluation_reps: int = 6         # the paper: six speed trials per condition
    speeds_dps: tuple[float, ...] = (5.0, 10.0, 20.0)
    moving_reps: int = 6
    moving_s: float = 15.0
    scenarios: tuple[str, ...] = SCENARIOS

    def __post_init__(self):
        if not self.grid or any(not (math.isfinite(g) and g >= 0) for g in self.grid):
            raise ValueError(f'grid must hold finite gains >= 0, got {self.grid}')
        for name in ('tuning_reps', 'evaluation_reps', 'moving_reps'):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 1):
                raise ValueError(f'{name} must be a whole number >= 1, got {v!r}')
        if not self.speeds_dps or any(not (math.isfinite(s) and s >= 0) for s in self.speeds_dps):
            raise ValueError(f'speeds_dps must hold finite speeds >= 0, got {self.speeds_dps}')
        if not (math.isfinite(self.moving_s) and self.moving_s > 0):
            raise ValueError(f'moving_s must be > 0, got {self.moving_s}')
        unknown = [s for s in self.scenarios if s not in SCENARIOS]
        if unknown or not self.scenarios:
            raise ValueError(f'scenarios must be a non-empty subset of {SCENARIOS}, '
                             f'got {self.scenarios}')


#: A short run for tests and a first look.
QUICK = StudySettings(grid=(0.0, 0.05, 0.2, 0.5), tuning_reps=2, evaluation_reps=2,
                      speeds_dps=(10.0, 20.0), moving_reps=2, moving_s=8.0)


@dataclass
class WearerResult:
    subject: int
    wearer: str
    error: str | None = None
    tuned_gain: float | None = None
    oracle_gain: float | None = None
    gain_rows: list = field(default_factory=list)      # tuning and evaluation grid trials
    moving_rows: list = field(default_factory=list)
    sim_s: float = 0.0


def run_wearer(scene: Scene, subject: int,
               settings: StudySettings = StudySettings()) -> WearerResult:
    """Calibrate one wearer by Algorithm 1, tune their G, run the evaluation grid and the
    moving-target trials. A pure function of (scene, subject, settings)."""
    package_channel_map()
    wearer = sample_wearer(scene, subject)
    outcome = calibrate_wearer(scene, wearer)
    res = WearerResult(subject, wearer.name)
    if not outcome.ok:
        res.error = outcome.error
        return res
    cal = outcome.calibration
    grid = tuple(settings.grid)
    if scene.controller.gain not in grid:
        grid = tuple(sorted(grid + (scene.controller.gain,)))
    trial_s = 1.0 + scene.protocol.trial_s
    res.tuned_gain, tuning = tune_gain(scene, wearer, cal, grid, settings.tuning_reps)
    evaluation = run_gain_grid(scene, wearer, cal, grid, evaluation_keys(settings.evaluation_reps))
    res.oracle_gain = choose_gain(gain_means(evaluation), scene.controller.gain)
    res.gain_rows = tuning + evaluation
    res.sim_s += trial_s * len(res.gain_rows)
    for scenario in settings.scenarios:
        for speed in settings.speeds_dps:
            for r in range(settings.moving_reps):
                key = TrialKey('moving', r)
                for law in LAWS:
                    m = moving_trial(scene, wearer, cal, law, speed, key, settings.moving_s,
                                     scenario == 'seen')
                    res.moving_rows.append(dict(subject=subject, wearer=wearer.name,
                                                scenario=scenario, speed_dps=float(speed),
                                                law=law, repetition=r, **m))
                    res.sim_s += 1.0 + settings.moving_s
    return res


def _job(args):
    scene, subject, settings = args
    return run_wearer(scene, subject, settings)


@dataclass
class StudyResults:
    """Both studies' trials per wearer, with the frames the analyses read."""

    scene: Scene
    settings: StudySettings
    wearers: list                # WearerResult, by subject
    wall_s: float = 0.0

    @property
    def included(self) -> list:
        return [w for w in self.wearers if w.error is None]

    @property
    def exclusions(self) -> list:
        return [(w.wearer, w.error) for w in self.wearers if w.error is not None]

    @property
    def sim_s(self) -> float:
        return sum(w.sim_s for w in self.wearers)

    def gain_grid_frame(self):
        """Every tuning and evaluation trial of the grid, one row per trial."""
        import pandas as pd
        return pd.DataFrame([r for w in self.included for r in w.gain_rows])

    def gain_choice_frame(self):
        """Per wearer: the tuned and oracle G and the evaluation means at the paper's, the own
        and the oracle G."""
        import pandas as pd
        paper = self.scene.controller.gain
        rows = []
        for w in self.included:
            tune = gain_means(r for r in w.gain_rows if r['phase'] == 'tuning')
            ev = gain_means(r for r in w.gain_rows if r['phase'] == 'evaluation')
            rows.append(dict(subject=w.subject, wearer=w.wearer, tuned_gain=w.tuned_gain,
                             oracle_gain=w.oracle_gain,
                             tuning_identified_at_tuned=tune[w.tuned_gain][0],
                             tuning_identified_at_paper=tune[paper][0],
                             identified_paper_gain=ev[paper][0],
                             identified_own_gain=ev[w.tuned_gain][0],
                             identified_oracle_gain=ev[w.oracle_gain][0]))
        return pd.DataFrame(rows)

    def gain_trials_frame(self, names: dict | None = None):
        """The evaluation trials of the compared arms, one row per trial: condition = the arm
        ('paper', 'own', 'oracle' or their names), for experiments.stats.analyze_trials."""
        import pandas as pd
        names = names or {'paper': 'paper', 'own': 'own', 'oracle': 'oracle'}
        paper = self.scene.controller.gain
        rows = []
        for w in self.included:
            ev = [r for r in w.gain_rows if r['phase'] == 'evaluation']
            for arm, g in (('paper', paper), ('own', w.tuned_gain), ('oracle', w.oracle_gain)):
                for r in ev:
                    if r['gain'] == g:
                        rows.append({**r, 'condition': names[arm]})
        return pd.DataFrame(rows)

    def moving_frame(self):
        import pandas as pd
        return pd.DataFrame([r for w in self.included for r in w.moving_rows])


def run_studies(scene: Scene, subjects: Iterable[int] | int | None = None,
                settings: StudySettings = StudySettings(), workers: int = 2,
                progress: Callable[[int, int, int], None] | None = None) -> StudyResults:
    """Both studies on the scene's wearers (all, the first n, or these indices), in parallel
    over wearers. Deterministic: the same for any number of workers."""
    if scene.protocol.kind != 'speed':
        raise ValueError(f'run_studies needs a speed scene (paper-speed), got a '
                         f'{scene.protocol.kind} scene')
    if not isinstance(workers, int) or workers < 1:
        raise ValueError(f'workers must be a whole number >= 1, got {workers!r}')
    indices = subject_indices(scene, subjects)
    start = time.perf_counter()
    jobs = [(scene, i, settings) for i in indices]
    results: dict[int, WearerResult] = {}
    with WorkerPool(workers, len(jobs)) as pool:
        for done, res in enumerate(pool.as_done(_job, jobs), start=1):
            results[res.subject] = res
            if progress is not None:
                progress(done, len(jobs), res.subject)
    return StudyResults(scene, settings, [results[i] for i in indices],
                        time.perf_counter() - start)


__all__ = ['StudyResults', 'StudySettings', 'QUICK', 'WearerResult', 'run_studies', 'run_wearer']
