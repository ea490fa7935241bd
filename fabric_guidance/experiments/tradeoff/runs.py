"""The simulation jobs of the sweep (top level: they run in worker processes)."""
from __future__ import annotations

from dataclasses import replace
import math

from ...core.geometry import DIRECTIONS
from ...sim.engine import CALIBRATION_RUN, ClosedLoop, package_channel_map, trial_run
from ...sim.population import CalibrationOutcome, law_angle_error_deg, law_error_kpa, sample_wearer
from ...sim.protocols import accuracy_trial, speed_loop, target_stream
from ...sim.scene import AccuracyProtocol, Scene
from ...workers import WorkerPool


def calibration_key(scene: Scene) -> Scene:
    """What a wearer's calibration depends on: the scene without its protocol, conditions,
    repetitions and gain (Algorithm 1 runs without the feedback law)."""
    return scene.replace(name='calibration', protocol=AccuracyProtocol(), conditions=(1,), repetitions=1,
                         controller=replace(scene.controller, gain=0.0), source='<calibration>')


def calibrate_measured(scene: Scene, subject: int) -> tuple[CalibrationOutcome, float]:
    """Algorithm 1 on wearer `subject` as sim.engine.run_calibration runs it, with the
    simulated seconds it took (0 for an `exact` calibration)."""
    package_channel_map()
    wearer = sample_wearer(scene, subject)
    if wearer.error:
        return CalibrationOutcome(subject, wearer.name, None, wearer.error), math.nan
    if scene.calibration.exact:
        from ...core.calibration import Calibration
        cal, took = Calibration.from_laws(wearer.name, wearer.suit_laws, scene.controller.p_max_kpa), 0.0
    else:
        loop = ClosedLoop(scene, wearer, CALIBRATION_RUN)
        loop.warm_up()
        t0 = loop.t
        try:
            cal = loop.calibrate(wearer.name)
        except ValueError as exc:
            return CalibrationOutcome(subject, wearer.name, None, f'calibration failed: {exc}'), loop.t - t0
        took = loop.t - t0
    p_max = scene.controller.p_max_kpa
    kpa = {d: law_error_kpa(t, f) for d, t, f in zip(DIRECTIONS, wearer.suit_laws, cal.laws)}
    deg = {d: law_angle_error_deg(t, f, p_max) for d, t, f in zip(DIRECTIONS, wearer.suit_laws, cal.laws)}
    return CalibrationOutcome(subject, wearer.name, cal, None, kpa, deg), took


def speed_trial_detail(scene: Scene, wearer, calibration, cond: int, repetition: int) -> dict:
    """sim.protocols.speed_trial with its detail: for every target found the time to find it
    and the true and tracked gaze error when it counted, and how long the last target had
    waited when the trial ended unfound (None: it was found)."""
    loop = ClosedLoop(scene, wearer, trial_run(cond, repetition), cond, calibration)
    loop.warm_up()
    detail = speed_loop(loop, target_stream(scene, wearer.index, repetition), scene.protocol)
    return dict(identified=len(detail['finds']), **detail)


def _calibration_job(args):
    scene, subject = args
    return subject, calibrate_measured(scene, subject)


def _trial_job(args):
    """All trials of one wearer at one knob value: a list of sample dicts."""
    scene, subject, calibration, kind = args
    package_channel_map()
    wearer = sample_wearer(scene, subject)
    cond = scene.conditions[0]
    out = []
    for rep in range(scene.repetitions):
        if kind == 'accuracy':
            r = accuracy_trial(scene, wearer, calibration, cond, rep)
            out.append(dict(subject=subject, rep=rep, error=math.hypot(r['h_error_deg'], r['v_error_deg']),
                            time=r['time_s'], timed_out=bool(r['timed_out'])))
        else:
            r = speed_trial_detail(scene, wearer, calibration, cond, rep)
            for i, (t_find, err, tracked) in enumerate(r['finds']):
                out.append(dict(subject=subject, rep=rep, find=i, error=err, tracked=tracked, time=t_find))
            out.append(dict(subject=subject, rep=rep, find=-1, identified=r['identified'],
                            presented=r['presented'], unfound_s=r['unfound_s']))
    return subject, out


class _Runner:
    """Runs jobs in a process pool (or in this process for one worker) and keeps every wearer's
    calibration per calibration setting, so a knob that does not change Algorithm 1 reuses it."""

    def __init__(self, workers: int, subjects: int):
        self.subjects = list(range(subjects))
        self.pool = WorkerPool(workers, subjects)
        self.calibrations: dict[Scene, dict[int, tuple[CalibrationOutcome, float]]] = {}

    def map(self, fn, jobs):
        return self.pool.map(fn, jobs)

    def close(self):
        self.pool.close()

    def calibrate(self, scene: Scene) -> dict[int, tuple[CalibrationOutcome, float]]:
        key = calibration_key(scene)
        if key not in self.calibrations:
            self.calibrations[key] = dict(self.map(_calibration_job, [(key, i) for i in self.subjects]))
        return self.calibrations[key]

    def trials(self, scene: Scene, kind: str, cals: dict | None = None
               ) -> tuple[list[dict], dict[int, tuple[CalibrationOutcome, float]]]:
        """Every wearer's trials of `kind` on `scene`, with Algorithm 1's calibrations of the
        scene, or `cals` (subject -> (outcome, seconds)) when given."""
        cals = self.calibrate(scene) if cals is None else cals
        jobs = [(scene, i, cals[i][0].calibration, kind) for i in self.subjects if cals[i][0].ok]
        samples = []
        for _, out in sorted(self.map(_trial_job, jobs), key=lambda x: x[0]):
            samples.extend(out)
        return samples, cals
