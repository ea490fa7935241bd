"""The paper's two subject experiments as protocols on simulated wearers, headless and fast.

accuracy (the paper's Section V): per trial one random target within +-horizontal_deg and
    +-vertical_deg (the paper: 60 and 30), not visible. The wearer starts facing front and
    "presses the key" once they have acted on the guidance and their gaze has moved slower than
    settle_speed_dps for settle_s (or at timeout_s). Recorded: the horizontal and vertical
    absolute error between the true gaze and the target (and the tracker's, as the paper
    measured it), and the time. Ten trials per condition.
speed (Section VI): trial_s (40 s) trials. A random target (same ranges) appears; the 50 dummy
    objects matter only through visual capture (body_dynamics: the wearer identifies the
    target once it is in their central field). A target counts when the tracked gaze stays
    within acceptance_deg (5 deg) for dwell_s, judged as the target_selector node does; the
    suit then vents, the wearer returns to the front, and the next target appears once the
    tracked gaze is back within acceptance_deg of the front for dwell_s. Recorded: identified
    targets per trial. Six trials per condition.

Every wearer takes the scene's conditions in their own random order (seeded per wearer), all
repetitions of a condition in a row, after being calibrated by Algorithm 1 in the simulation.

Random numbers: the targets of repetition r of a wearer are the same in every condition
(common random numbers: the conditions are compared on the same targets, as a paired design);
each effect's streams are keyed by wearer, condition and repetition (effects.RunContext).
A trial is a pure function of (scene, wearer, condition, repetition), so results do not
depend on the number of worker processes or on which wearers run.

Command line: python -m fabric_guidance.sim.protocols paper-speed [--subjects N] [--workers W]
[--csv OUT.csv]; the paper's statistics (Friedman, Dunn-Bonferroni) on the same run:
fabric-guidance experiment --scene paper-speed --out DIR (experiments/experiment.py).
"""
from __future__ import annotations

import argparse
from dataclasses import asdict, dataclass
import math
import os
from pathlib import Path
import sys
import time
from typing import Callable, Iterable, Sequence

import numpy as np

from ..atomic import write_csv
from ..core.conditions import condition as condition_of
from ..core.geometry import wrap_deg
from ..workers import WorkerPool
from .effects import generator
from .engine import WARMUP_S, ClosedLoop, package_channel_map, trial_run
from .population import CalibrationOutcome, WearerSpec, calibrate_wearer, sample_wearer, subject_indices
from .scene import AccuracyProtocol, Scene, SpeedProtocol, load_scene
from .wearer import angle_between_deg, hav_limit, haversine


@dataclass(frozen=True)
class TrialRecord:
    """One trial. Fields of the other protocol are None."""

    scene: str
    protocol: str
    subject: int            # index in the scene's population
    wearer: str             # S01, ...
    condition: int
    repetition: int         # 0-based within the condition
    order: int              # 1-based position of the condition in this wearer's order
    # accuracy
    target_h_deg: float | None = None   # target from the front, positive left
    target_v_deg: float | None = None   # positive up
    h_error_deg: float | None = None    # |true gaze - target|, horizontal
    v_error_deg: float | None = None    # vertical
    tracked_h_error_deg: float | None = None  # the tracker's gaze (what the paper measured)
    tracked_v_error_deg: float | None = None
    time_s: float | None = None         # key press after the target appeared
    timed_out: bool | None = None
    # speed
    identified: int | None = None       # targets identified within trial_s
    presented: int | None = None        # targets that appeared
    mean_find_s: float | None = None    # mean time from appearance to identification

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class Exclusion:
    subject: int
    wearer: str
    reason: str


class ProtocolResults(list):
    """The TrialRecords of a run (a list, in subject, order, repetition order), with the
    wearers excluded and why, and each wearer's calibration outcome."""

    def __init__(self, records=(), exclusions=(), calibrations=(), wall_s: float = 0.0, sim_s: float = 0.0):
        super().__init__(records)
        self.exclusions: tuple[Exclusion, ...] = tuple(exclusions)
        self.calibrations: tuple[CalibrationOutcome, ...] = tuple(calibrations)
        self.wall_s = wall_s          # wall-clock seconds of the whole run
        self.sim_s = sim_s            # simulated seconds (calibrations and trials)


# ---------------------------------------------------------------------------------------------
# Per-wearer plan


def condition_order(scene: Scene, subject: int) -> tuple[int, ...]:
    """The wearer's own random order of the scene's conditions (seeded per wearer)."""
    perm = generator(scene.seed, 'condition_order', subject).permutation(len(scene.conditions))
    return tuple(scene.conditions[i] for i in perm)


def target_stream(scene: Scene, subject: int, repetition: int) -> np.random.Generator:
    """Targets of repetition r: the same sequence in every condition (common random numbers)."""
    return generator(scene.seed, 'targets', subject, (repetition,))


def draw_target(rng: np.random.Generator, protocol) -> tuple[float, float]:
    """The next target (yaw, pitch) in degrees, uniform over the protocol's ranges."""
    h, v = rng.uniform(-1.0, 1.0, 2)
    return float(h * protocol.horizontal_deg), float(v * protocol.vertical_deg)


# ---------------------------------------------------------------------------------------------
# Trials


def accuracy_trial(scene: Scene, wearer: WearerSpec, calibration, cond: int, repetition: int) -> dict:
    """One accuracy trial; the measures as a dict (TrialRecord's accuracy fields)."""
    proto: AccuracyProtocol = scene.protocol
    h_t, v_t = draw_target(target_stream(scene, wearer.index, repetition), proto)
    loop = ClosedLoop(scene, wearer, trial_run(cond, repetition), cond, calibration)
    loop.warm_up()
    w = loop.wearer
    t0 = loop.t
    loop.present(h_t, v_t, visible=False)
    end = t0 + proto.timeout_s - 1e-9
    dt = loop.dt
    limit = proto.settle_speed_dps * dt            # degrees per step
    still_since = None
    prev_y, prev_p = w.gaze_yaw, w.gaze_pitch
    timed_out = True
    while loop.t < end:
        loop.step()
        gy, gp = w.torso_yaw + w.head_yaw, w.torso_pitch + w.head_pitch
        moved = math.hypot((gy - prev_y) * math.cos(math.radians(gp)), gp - prev_p)
        prev_y, prev_p = gy, gp
        if not w.acting or moved >= limit:
            still_since = None
            continue
        if still_since is None:
            still_since = loop.t
        if loop.t - still_since >= proto.settle_s - 1e-9:
            # A wearer who misread the cue presses here too: they believe they are there
            # (only resistance or a rise of the pressure, during the move, corrects them).
            timed_out = False
            break
    gy, gp = w.gaze_yaw, w.gaze_pitch
    return dict(target_h_deg=h_t, target_v_deg=v_t,
                h_error_deg=abs(wrap_deg(gy - h_t)), v_error_deg=abs(gp - v_t),
                tracked_h_error_deg=abs(wrap_deg(loop.measured_yaw - h_t)),
                tracked_v_error_deg=abs(loop.measured_pitch - v_t),
                time_s=loop.t - t0, timed_out=timed_out)


def speed_loop(loop: ClosedLoop, rng: np.random.Generator, proto: SpeedProtocol) -> dict:
    """The speed task on a warmed-up loop: targets from `rng` for proto.trial_s; a target counts
    when the tracked gaze stays within the acceptance angle for the dwell (core.task's
    AcceptanceTracker rule, on each sample the selector receives); then back to the front.

    Returns presented, finds (per target found: time to find [s], true and tracked gaze error
    when it counted [deg]) and unfound_s (how long the last target had waited, None if found).
    """
    w = loop.wearer
    t0 = loop.t
    end = t0 + proto.trial_s - 1e-9
    acc_hav, dwell = hav_limit(proto.acceptance_deg), proto.dwell_s
    target = draw_target(rng, proto)
    loop.present(*target, visible=True)
    appeared, finds = t0, []
    presented = 1
    goal = target                  # what the tracked gaze must reach: the target, or the front
    inside_since = None
    step = loop.step
    while loop.t < end:
        step()
        if not loop.new_sample:
            continue
        s = loop.last_sample
        if haversine(s[2], s[3], goal[0], goal[1]) > acc_hav:
            inside_since = None
            continue
        t = loop.t
        if inside_since is None:
            inside_since = t
        if t - inside_since < dwell:
            continue
        if goal is target and t < loop.key_ready_t:
            continue                  # hololens_view: not yet found and confirmed
        inside_since = None
        if goal is target:
            finds.append((t - appeared, angle_between_deg(w.gaze_yaw, w.gaze_pitch, target[0], target[1]),
                          angle_between_deg(s[2], s[3], target[0], target[1])))
            loop.withdraw(front_visible=True)
            goal = (0.0, 0.0)
        else:
            target = draw_target(rng, proto)
            presented += 1
            appeared = t
            loop.present(*target, visible=True)
            goal = target
    return dict(presented=presented, finds=finds, unfound_s=(loop.t - appeared) if goal is target else None)


def sequence_loop(loop: ClosedLoop, targets: Sequence[tuple[float, float]],
                  acceptance_deg: float = 5.0, dwell_s: float = 0.3, timeout_s: float = 15.0,
                  visible: bool = True) -> list[float | None]:
    """Targets one after another with no return to the front (the micromanipulation
    demonstration: the next object appears as soon as one is found), on a warmed-up loop.
    Found by the speed task's rule on the tracked gaze. Per target: time to find [s], or None
    when not found within timeout_s (the sequence stops there). visible False: the wearer
    cannot see the objects (the suit alone guides: no visual capture)."""
    acc_hav = hav_limit(acceptance_deg)
    times: list[float | None] = []
    for target in targets:
        loop.present(*target, visible=visible)
        appeared, inside_since, found = loop.t, None, None
        while loop.t - appeared < timeout_s:
            loop.step()
            if not loop.new_sample:
                continue
            s = loop.last_sample
            if haversine(s[2], s[3], target[0], target[1]) > acc_hav:
                inside_since = None
                continue
            inside_since = loop.t if inside_since is None else inside_since
            if loop.t - inside_since >= dwell_s:
                found = loop.t - appeared
                break
        times.append(found)
        if found is None:
            break
    loop.withdraw(front_visible=True)
    return times


def speed_measures(detail: dict) -> dict:
    """TrialRecord's speed fields from speed_loop's detail."""
    times = [f[0] for f in detail['finds']]
    return dict(identified=len(times), presented=detail['presented'],
                mean_find_s=float(np.mean(times)) if times else None)


def speed_trial(scene: Scene, wearer: WearerSpec, calibration, cond: int, repetition: int) -> dict:
    """One speed trial; the measures as a dict (TrialRecord's speed fields)."""
    loop = ClosedLoop(scene, wearer, trial_run(cond, repetition), cond, calibration)
    loop.warm_up()
    return speed_measures(speed_loop(loop, target_stream(scene, wearer.index, repetition), scene.protocol))


TRIALS = {'speed': speed_trial, 'accuracy': accuracy_trial}


def trial_seconds(scene: Scene, record: TrialRecord) -> float:
    """Simulated seconds of a trial (with its warm-up)."""
    return WARMUP_S + (scene.protocol.trial_s if scene.protocol.kind == 'speed' else record.time_s)


def run_subject(scene: Scene, subject: int) -> tuple[CalibrationOutcome, list[TrialRecord]]:
    """Calibrate one wearer, then every trial in their condition order. A pure function of
    (scene, subject)."""
    package_channel_map()
    wearer = sample_wearer(scene, subject)
    outcome = calibrate_wearer(scene, wearer)
    if not outcome.ok:
        return outcome, []
    trial = TRIALS[scene.protocol.kind]
    records = []
    for order, cond in enumerate(condition_order(scene, subject), start=1):
        condition_of(cond)
        for rep in range(scene.repetitions):
            measures = trial(scene, wearer, outcome.calibration, cond, rep)
            records.append(TrialRecord(scene.name, scene.protocol.kind, subject, wearer.name, cond, rep, order,
                                       **measures))
    return outcome, records


#: The condition whose wearer law is the arm's (population.arm_spread acts there alone).
ARM_CONDITION = 3


def run_subject_arms(scenes: Sequence[Scene], subject: int) -> list[tuple[CalibrationOutcome, list[TrialRecord]]]:
    """run_subject in each of `scenes`, which differ only in population.arm_spread, at the cost
    of one: the arm's law acts in condition 3 alone (the calibration and the other conditions
    use the suit's law), so the wearer is calibrated once, the other conditions run once and
    only condition 3 runs in every scene. The same records as run_subject per scene
    (test_sim_protocols)."""
    first = scenes[0]
    outcome, records = run_subject(first, subject)
    out = [(outcome, records)]
    for scene in scenes[1:]:
        if not outcome.ok:
            out.append((outcome, []))
            continue
        wearer = sample_wearer(scene, subject)
        trial = TRIALS[scene.protocol.kind]
        recs = []
        for r in records:
            if r.condition != ARM_CONDITION:
                recs.append(r)
                continue
            measures = trial(scene, wearer, outcome.calibration, r.condition, r.repetition)
            recs.append(TrialRecord(scene.name, scene.protocol.kind, subject, wearer.name, r.condition,
                                    r.repetition, r.order, **measures))
        out.append((outcome, recs))
    return out


def _run_subject_job(args):
    scene, subject = args
    return subject, run_subject(scene, subject)


def run_protocol(scene: Scene, subjects: Iterable[int] | int | None = None, workers: int = 2,
                 progress: Callable[[int, int, int], None] | None = None) -> ProtocolResults:
    """Run the scene's protocol: every wearer (or `subjects`: the first n, or these indices)
    calibrated by Algorithm 1, then their trials; in parallel over wearers with `workers`
    processes. progress(done, total, subject) is called as each wearer finishes.

    Returns the TrialRecords (a ProtocolResults list, sorted by subject, order, repetition)
    with .exclusions (wearers whose calibration failed, with the reason) and .calibrations.
    Deterministic: the same for any number of workers.
    """
    if not isinstance(workers, int) or workers < 1:
        raise ValueError(f'workers must be a whole number >= 1, got {workers!r}')
    indices = subject_indices(scene, subjects)
    start = time.perf_counter()
    results: dict[int, tuple[CalibrationOutcome, list[TrialRecord]]] = {}
    jobs = [(scene, i) for i in indices]
    with WorkerPool(workers, len(jobs)) as pool:
        for done, (subject, result) in enumerate(pool.as_done(_run_subject_job, jobs), start=1):
            results[subject] = result
            if progress is not None:
                progress(done, len(jobs), subject)
    records, exclusions, outcomes = [], [], []
    sim_s = 0.0
    for i in indices:
        outcome, recs = results[i]
        outcomes.append(outcome)
        if not outcome.ok:
            exclusions.append(Exclusion(i, outcome.wearer, outcome.error))
        elif not scene.calibration.exact:
            cal = scene.calibration
            sim_s += 4 * (cal.rest_s + cal.steps * cal.dwell_s)
        records.extend(recs)
        sim_s += sum(trial_seconds(scene, r) for r in recs)
    return ProtocolResults(records, exclusions, outcomes, time.perf_counter() - start, sim_s)


# ---------------------------------------------------------------------------------------------
# Summary

#: The names fabric_guidance.experiments.stats gives the paper's conditions.
CONDITION_NAMES = {1: 'surface_adjusted', 2: 'surface_fixed', 3: 'simple_adjusted', 4: 'speech'}
#: Each protocol's main measures and whether higher is better (for the statistics).
MEASURES = {'speed': {'identified': True}, 'accuracy': {'h_error_deg': False, 'v_error_deg': False}}


def trials_frame(records: Iterable[TrialRecord], condition_names: bool = True):
    """The records as a pandas DataFrame, one row per trial, the columns of TrialRecord; with
    condition_names the condition column holds the names experiments.stats uses
    ('surface_adjusted', ...), ready for experiments.stats.analyze_trials."""
    import pandas as pd
    frame = pd.DataFrame([r.as_dict() for r in records])
    if condition_names and len(frame):
        frame['condition'] = frame['condition'].map(CONDITION_NAMES)
    return frame


def summarize(records: Iterable[TrialRecord]) -> dict[int, dict[str, float]]:
    """Per condition: the mean over wearers of each wearer's mean (as the paper's tables), the
    sd across wearers, and the number of wearers and trials."""
    by_cond: dict[int, dict[str, list]] = {}
    for r in records:
        by_cond.setdefault(r.condition, {}).setdefault(r.subject, []).append(r)
    out = {}
    for cond in sorted(by_cond):
        subjects = by_cond[cond]
        row: dict[str, float] = {'wearers': len(subjects), 'trials': sum(len(v) for v in subjects.values())}
        keys = ('identified', 'presented', 'mean_find_s') if next(iter(subjects.values()))[0].protocol == 'speed' \
            else ('h_error_deg', 'v_error_deg', 'tracked_h_error_deg', 'tracked_v_error_deg', 'time_s', 'timed_out')
        for key in keys:
            per_subject = []
            for recs in subjects.values():
                vals = [float(getattr(r, key)) for r in recs if getattr(r, key) is not None]
                if vals:
                    per_subject.append(float(np.mean(vals)))
            if per_subject:
                row[key] = float(np.mean(per_subject))
                row[f'{key}_sd'] = float(np.std(per_subject, ddof=1)) if len(per_subject) > 1 else 0.0
        if keys[0] == 'h_error_deg':
            for key in ('h_error_deg', 'v_error_deg'):
                row[f'{key}_median'] = float(np.median([getattr(r, key) for v in subjects.values() for r in v]))
        out[cond] = row
    return out


def format_summary(scene: Scene, results: ProtocolResults) -> str:
    lines = [f'scene {scene.name}: {scene.protocol.kind} protocol, {len({r.subject for r in results})} wearers '
             f'included, {len(results.exclusions)} excluded, effects: {", ".join(scene.effect_names) or "none"}']
    for e in results.exclusions:
        lines.append(f'  excluded {e.wearer}: {e.reason}')
    for cond, row in summarize(results).items():
        name = condition_of(cond).name
        if scene.protocol.kind == 'speed':
            lines.append(f'  condition {cond} ({name}): identified {row["identified"]:.2f} '
                         f'(sd across wearers {row["identified_sd"]:.2f}) of {row["presented"]:.2f} presented')
        else:
            lines.append(f'  condition {cond} ({name}): |error| h {row["h_error_deg"]:.2f} deg '
                         f'(median {row["h_error_deg_median"]:.2f}), v {row["v_error_deg"]:.2f} deg '
                         f'(median {row["v_error_deg_median"]:.2f}), time {row["time_s"]:.2f} s, '
                         f'timed out {100 * row["timed_out"]:.0f} %')
    lines.append(f'  {results.sim_s:.0f} simulated s in {results.wall_s:.1f} wall s')
    return '\n'.join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m fabric_guidance.sim.protocols', description=__doc__.split('\n')[0])
    parser.add_argument('scene', help='a scene file, or the name of one in config/scenes (paper-speed, ...)')
    parser.add_argument('--subjects', type=int, default=None, help='only the first N wearers')
    parser.add_argument('--workers', type=int, default=min(2, os.cpu_count() or 1), help='processes')
    parser.add_argument('--csv', type=Path, metavar='OUT.csv', help='write one row per trial here')
    parser.add_argument('--stats', action='store_true',
                        help="where the paper's statistics are: `fabric-guidance experiment --scene SCENE "
                             "--out DIR` (the simulator sits below experiments/)")
    args = parser.parse_args(argv)
    scene = load_scene(args.scene)

    def progress(done, total, subject):
        print(f'  wearer {subject + 1} done ({done}/{total})', file=sys.stderr, flush=True)

    results = run_protocol(scene, args.subjects, args.workers, progress)
    print(format_summary(scene, results))
    if args.csv is not None:
        write_csv(args.csv, trials_frame(results, condition_names=False))
        print(f'trials: {args.csv}')
    if args.stats:
        print(f'statistics: fabric-guidance experiment --scene {args.scene} --out DIR')
    return 0


__all__ = ['CONDITION_NAMES', 'Exclusion', 'MEASURES', 'ProtocolResults', 'TRIALS', 'TrialRecord', 'accuracy_trial',
           'condition_order', 'format_summary', 'run_protocol', 'run_subject', 'sequence_loop',
           'speed_trial', 'draw_target', 'target_stream',
           'summarize',
           'trials_frame']

if __name__ == '__main__':
    sys.exit(main())
