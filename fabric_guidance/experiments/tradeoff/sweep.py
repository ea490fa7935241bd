"""The sweep: every knob value of the settings run on the same wearers, as rows."""
from __future__ import annotations

from dataclasses import dataclass, field
import math
import time
from typing import Callable

import numpy as np
import pandas as pd

from ...core.power_law import CalibrationFitError, fit_power_law
from ...sim.population import CalibrationOutcome
from ...sim.scene import Scene
from .rows import (Row, _join, accuracy_rows, calibration_rows, fit_tolerance_rows, plane_row,
                   speed_row)
from .runs import _Runner
from .settings import (BOTH, CALIBRATION, CONDITION_LABELS, CSV_COLUMNS, FIT, KNOB, KNOB_SYMBOLS, METRICS,
                       PLANE_CONDITIONS, SPEED, Settings, base_scenes, check_settings)


def _fmt(x: float) -> str:
    if x is None or not math.isfinite(x):
        return 'n/a'
    if x != 0 and (abs(x) < 1e-3 or abs(x) >= 1e5):
        return f'{x:.2e}'
    return f'{x:.3g}'


def _summary(row: Row) -> str:
    a, t = row.stats('accuracy'), row.stats('time')
    au, tu = METRICS[row.accuracy_metric][1], METRICS[row.time_metric][1]
    short = row.accuracy_metric.replace('_deg', '').replace('_', ' ')
    tshort = row.time_metric.rsplit('_', 1)[0].replace('_', ' ')
    return (f'{short} {_fmt(a["mean"])} +- {_fmt(a["sd"])} {au}, {tshort} {_fmt(t["mean"])} +- {_fmt(t["sd"])} {tu} '
            f'(n={a["n"]})')


@dataclass
class SweepResult:
    settings: Settings
    rows: list[Row]
    wall_s: float
    knob_wall_s: dict
    scenes: tuple[Scene, Scene]
    readings: dict = field(default_factory=dict)

    def frame(self) -> pd.DataFrame:
        recs = [r.as_record() for r in self.rows if r.stats('accuracy')['n'] and r.stats('time')['n']]
        return pd.DataFrame(recs, columns=list(CSV_COLUMNS))

    def curves(self) -> dict[tuple[str, str, str], list[Row]]:
        out: dict = {}
        for r in self.rows:
            out.setdefault(r.curve, []).append(r)
        return out


def refit_calibrations(cals: dict, tol: float, p_max: float) -> dict:
    """Each wearer's calibration with every direction's law refitted from Algorithm 1's
    recorded points at xtol = ftol = tol (a wearer whose fit fails at tol is excluded)."""
    from dataclasses import replace as dc_replace
    out = {}
    for subject, (o, took) in cals.items():
        if not o.ok:
            out[subject] = (o, took)
            continue
        dirs = {}
        try:
            for d, dc in o.calibration.directions.items():
                law = fit_power_law(np.array(dc.angles), np.array(dc.pressures), p_max, xtol=tol,
                                    ftol=tol).law
                dirs[d] = dc_replace(dc, law=law)
        except CalibrationFitError as exc:
            out[subject] = (CalibrationOutcome(subject, o.wearer, None,
                                               f'calibration failed: refit at {tol:g}: '
                                               f'{exc}'), took)
            continue
        out[subject] = (dc_replace(o, calibration=dc_replace(o.calibration, directions=dirs)),
                        took)
    return out


def run_sweep(settings: Settings, progress: Callable[[str], None] | None = None) -> SweepResult:
    """Run every knob of settings.knobs over its grid, and (settings.plane) conditions 1-4 and
    the plane's point of every knob value; progress(line) once per knob value or condition."""
    say = progress or (lambda line: None)
    acc, spd = base_scenes(settings)
    check_settings(settings, acc)
    start = time.perf_counter()
    runner = _Runner(settings.workers, settings.subjects)
    rows: list[Row] = []
    knob_wall = {}
    timeout = acc.protocol.timeout_s
    try:
        if settings.plane:
            k_start = time.perf_counter()
            for i, cond in enumerate(PLANE_CONDITIONS, start=1):
                v_start = time.perf_counter()
                a_samples, cals = runner.trials(acc.replace(conditions=(cond,)), 'accuracy')
                s_samples, _ = runner.trials(spd.replace(conditions=(cond,)), 'speed')
                row = plane_row('condition', cond, a_samples, s_samples, cals,
                                CONDITION_LABELS[cond], timeout)
                rows.append(row)
                say(f'[condition {i}/{len(PLANE_CONDITIONS)}] {CONDITION_LABELS[cond]}: '
                    f'{_summary(row)} '
                    f'({time.perf_counter() - v_start:.1f} s)')
            knob_wall['condition'] = time.perf_counter() - k_start
        for knob in settings.knobs:
            k_start = time.perf_counter()
            grid = list(settings.grids[knob])
            if KNOB[knob].measures == FIT:
                v_start = time.perf_counter()
                cals = runner.calibrate(acc)
                new = fit_tolerance_rows(grid, cals, acc, settings.fit_repeats)
                rows += new
                per_value = (time.perf_counter() - v_start) / len(grid)
                for i, tol in enumerate(grid, start=1):
                    v_start = time.perf_counter()
                    r = [x for x in new if x.value == tol]
                    if settings.plane:
                        refit = refit_calibrations(cals, tol, acc.controller.p_max_kpa)
                        ms = r[0].stats('time')['mean']
                        pr = plane_row(knob, tol, runner.trials(acc, 'accuracy', refit)[0],
                                       runner.trials(spd, 'speed', refit)[0], refit,
                                       f'{_fmt(ms)} ms per fit', timeout)
                        rows.append(pr)
                        r.append(pr)
                    say(f'[{knob} {i}/{len(grid)}] {KNOB_SYMBOLS[knob]} = {tol:g}: '
                        + '; '.join(_summary(x) for x in r)
                        + f' ({per_value + time.perf_counter() - v_start:.1f} s)')
                knob_wall[knob] = time.perf_counter() - k_start
                continue
            for i, value in enumerate(grid, start=1):
                v_start = time.perf_counter()
                new: list[Row] = []
                a_samples = s_samples = None
                # The knob table (settings.KNOB_TABLE) says what the value changes in a scene
                # and what is measured at it.
                spec = KNOB[knob]
                if spec.measures == SPEED:     # a speed-protocol setting only
                    row = speed_row(knob, value, *runner.trials(spec.vary(spd, value), 'speed'))
                    # The accuracy protocol has no tolerance: on the plane, the error when a
                    # target counts stands in for the guidance error.
                    row.plane = settings.plane
                    new.append(row)
                else:
                    scene = spec.vary(acc, value)
                    a_samples, cals = runner.trials(scene, 'accuracy')
                    if spec.measures == CALIBRATION:
                        new += calibration_rows(int(value), a_samples, cals, timeout)
                    else:
                        row = accuracy_rows(knob, value, a_samples, cals, timeout)
                        if spec.note is not None:
                            row.note = _join(spec.note(scene, value), row.note)
                        new.append(row)
                    if spec.measures == BOTH or settings.plane:
                        s_samples, s_cals = runner.trials(spec.vary(spd, value), 'speed')
                        if spec.measures == BOTH:
                            new.append(speed_row(knob, value, s_samples, s_cals))
                            cals = s_cals
                if settings.plane and a_samples is not None and s_samples is not None:
                    cost = ''
                    if spec.measures == CALIBRATION:
                        cost = f'{_fmt(new[0].stats("time")["mean"])} s calibration'
                    new.append(plane_row(knob, value, a_samples, s_samples, cals, cost, timeout))
                rows += new
                say(f'[{knob} {i}/{len(grid)}] {KNOB_SYMBOLS[knob]} = {value:g}: '
                    + '; '.join(_summary(x) for x in new) + f' ({time.perf_counter() - v_start:.1f} s)')
            knob_wall[knob] = time.perf_counter() - k_start
    finally:
        runner.close()
    return SweepResult(settings, rows, time.perf_counter() - start, knob_wall, (acc, spd))
