"""Algorithm 1 as a state machine, and the calibration file."""
import math
import os

import numpy as np
import pytest
import yaml

from fabric_guidance.core.calibration import (APPLY, DONE, FAILED, REST, Calibration, CalibrationFileError,
                                              CalibrationProcedure, pressure_schedule)
from fabric_guidance.core.geometry import DIRECTIONS
from fabric_guidance.core.power_law import CalibrationFitError, PowerLaw

P_MAX = 375.0
TRUE = {'left': PowerLaw(20.0, 0.65, 25.0), 'right': PowerLaw(22.0, 0.62, 20.0),
        'down': PowerLaw(40.0, 0.55, 30.0), 'up': PowerLaw(38.0, 0.58, 35.0)}
SIGN = {'left': (1, 0), 'right': (-1, 0), 'down': (0, -1), 'up': (0, 1)}


def gaze(yaw, pitch):
    y, p = math.radians(yaw), math.radians(pitch)
    return [math.cos(p) * math.cos(y), math.cos(p) * math.sin(y), math.sin(p)]


def run(proc, respond, dt=0.05, limit=1000.0):
    """Drive the procedure; `respond(cmd)` returns the gaze the wearer has under that command."""
    t, cmds, g = 0.0, [], gaze(0, 0)
    while proc.phase not in (DONE, FAILED) and t < limit:
        cmd = proc.tick(t, g)
        cmds.append(cmd)
        g = respond(cmd)
        t += dt
    return cmds


def ideal_wearer(cmd):
    """Turns at once to the angle their own power law gives the pressure."""
    if cmd.direction is None:
        return gaze(0, 0)
    sy, sp = SIGN[cmd.direction]
    angle = TRUE[cmd.direction].theta(cmd.pressure, P_MAX)
    return gaze(sy * angle, sp * angle)


def test_schedule_is_ten_increasing_steps_to_p_max():
    s = pressure_schedule(375.0, 10)
    np.testing.assert_allclose(s, np.arange(1, 11) * 37.5)
    assert pressure_schedule(300.0, 5, first=50.0).tolist() == [50.0, 112.5, 175.0, 237.5, 300.0]
    with pytest.raises(ValueError, match='at least 3'):
        pressure_schedule(375.0, 2)


def test_procedure_recovers_the_wearers_laws():
    proc = CalibrationProcedure('w', dwell_s=1.0, rest_s=1.0, record_window_s=0.2)
    cmds = run(proc, ideal_wearer)
    assert proc.phase == DONE, proc.error
    cal = proc.result()
    for d in DIRECTIONS:
        law = cal.directions[d].law
        assert (law.a, law.b, law.c) == (pytest.approx(TRUE[d].a, rel=1e-4), pytest.approx(TRUE[d].b, rel=1e-4),
                                         pytest.approx(TRUE[d].c, rel=1e-4, abs=1e-3))
        assert cal.directions[d].pressures == tuple(np.arange(1, 11) * 37.5)
    # Directions in the paper's order; each rests vented, then steps up through the schedule.
    applied = [(c.direction, c.pressure) for c in cmds if c.phase == APPLY]
    firsts = [d for i, (d, _) in enumerate(applied) if i == 0 or applied[i - 1][0] != d]
    assert firsts == list(DIRECTIONS)
    for d in DIRECTIONS:
        steps = sorted({p for dd, p in applied if dd == d})
        assert steps == list(np.arange(1, 11) * 37.5)
    assert all(c.pressure == 0.0 and c.direction is None for c in cmds if c.phase == REST)
    progress = [c.progress for c in cmds]
    assert progress == sorted(progress) and progress[-1] == 1.0
    assert all(0.0 <= c.pressure <= P_MAX for c in cmds)


def test_recorded_angle_is_the_median_of_the_window():
    # One wild sample at the end of each dwell does not become the calibration point.
    proc = CalibrationProcedure('w', dwell_s=1.0, rest_s=1.0, record_window_s=0.3, directions=['left'])
    state = {'n': 0}

    def wearer_with_glitch(cmd):
        state['n'] += 1
        g = ideal_wearer(cmd)
        return gaze(80.0, 0.0) if (cmd.phase == APPLY and state['n'] % 20 == 0) else g
    run(proc, wearer_with_glitch)
    assert proc.phase == DONE, proc.error
    _, angles = proc.points['left']
    np.testing.assert_allclose(angles, TRUE['left'].theta(np.arange(1, 11) * 37.5, P_MAX), atol=1e-9)


def test_wearer_who_does_not_move_fails_with_reason():
    proc = CalibrationProcedure('w', dwell_s=0.5, rest_s=0.5, record_window_s=0.1)
    run(proc, lambda cmd: gaze(0, 0))
    assert proc.phase == FAILED
    assert 'left' in proc.error and 'distinct angles' in proc.error
    with pytest.raises(CalibrationFitError, match='distinct angles'):
        proc.result()


def test_no_gaze_fails_with_reason():
    proc = CalibrationProcedure('w', dwell_s=0.5, rest_s=0.5, record_window_s=0.1)
    t = 0.0
    while proc.phase not in (DONE, FAILED) and t < 10:
        cmd = proc.tick(t, None)
        t += 0.05
    assert proc.phase == FAILED and 'no gaze sample' in proc.error
    assert cmd.pressure == 0.0


def test_invalid_gaze_and_clock_jump_abort():
    proc = CalibrationProcedure('w', dwell_s=0.5, rest_s=0.5, record_window_s=0.1)
    proc.tick(0.0, gaze(0, 0))
    assert proc.tick(0.1, [float('nan'), 0, 1]).phase == FAILED
    assert 'invalid gaze' in proc.error
    proc = CalibrationProcedure('w', dwell_s=0.5, rest_s=0.5, record_window_s=0.1)
    proc.tick(5.0, gaze(0, 0))
    assert proc.tick(4.0, gaze(0, 0)).phase == FAILED and 'clock' in proc.error


def test_partial_calibration_takes_the_rest_from_a_base():
    base = Calibration.from_laws('w', [TRUE[d] for d in DIRECTIONS])
    proc = CalibrationProcedure('w', dwell_s=0.5, rest_s=0.5, record_window_s=0.1, directions=['up'])
    run(proc, ideal_wearer)
    cal = proc.result(base)
    assert cal.directions['left'] is base.directions['left']
    assert cal.directions['up'].law.b == pytest.approx(TRUE['up'].b, rel=1e-4)
    with pytest.raises(CalibrationFitError, match='neither calibrated'):
        proc.result()


@pytest.fixture
def calibration():
    proc = CalibrationProcedure('wearer-A', dwell_s=0.5, rest_s=0.5, record_window_s=0.1)
    run(proc, ideal_wearer)
    return proc.result()


def test_file_round_trip_is_human_readable(tmp_path, calibration):
    path = calibration.save(tmp_path / 'wearer-A.yaml')
    text = path.read_text()
    assert 'units: {pressure: kPa, angle: deg}' in text and 'wearer: wearer-A' in text
    data = yaml.safe_load(text)
    assert data['schema_version'] == 1
    assert len(data['directions']['left']['points']['angle_deg']) == 10
    assert data['directions']['left']['fit']['n_points'] == 10
    loaded = Calibration.load(path)
    assert loaded.laws == calibration.laws
    assert loaded.directions['down'].angles == calibration.directions['down'].angles
    assert loaded.created == calibration.created


def test_failed_save_leaves_the_previous_file(tmp_path, calibration, monkeypatch):
    path = calibration.save(tmp_path / 'wearer-A.yaml')
    before = path.read_bytes()

    def broken_replace(src, dst):
        raise OSError('disk full')
    monkeypatch.setattr(os, 'replace', broken_replace)
    with pytest.raises(OSError, match='disk full'):
        Calibration.from_laws('wearer-A', [PowerLaw(1.0, 1.0, 0.0)] * 4).save(path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ['wearer-A.yaml']   # no temporary left behind


@pytest.mark.parametrize('mutate, match', [
    (lambda d: d.update(schema_version=2), 'field "schema_version"'),
    (lambda d: d.update(units={'pressure': 'psi', 'angle': 'deg'}), 'field "units"'),
    (lambda d: d.update(wearer=''), 'field "wearer"'),
    (lambda d: d.update(p_max_kpa=-1), 'field "p_max_kpa"'),
    (lambda d: d['directions'].pop('up'), 'field "directions"'),
    (lambda d: d['directions']['left'].update(b=-0.5), 'field "directions.left"'),
    (lambda d: d['directions']['down'].update(a='x'), 'field "directions.down"'),
    (lambda d: d['directions']['right']['points'].update(angle_deg=[1.0]), 'directions.right.points'),
])
def test_bad_files_name_the_field(tmp_path, calibration, mutate, match):
    data = calibration.to_dict()
    mutate(data)
    path = tmp_path / 'bad.yaml'
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(CalibrationFileError, match=match):
        Calibration.load(path)


def test_unreadable_file(tmp_path):
    with pytest.raises(CalibrationFileError, match='cannot read'):
        Calibration.load(tmp_path / 'missing.yaml')
    (tmp_path / 'junk.yaml').write_text('{a: [1, 2')
    with pytest.raises(CalibrationFileError, match='cannot read'):
        Calibration.load(tmp_path / 'junk.yaml')


def test_wearer_gain_round_trips_and_is_validated(tmp_path, calibration):
    assert calibration.adjustment_gain is None
    assert 'adjustment_gain' not in calibration.to_dict()
    path = calibration.with_gain(0.12).save(tmp_path / 'g.yaml')
    assert Calibration.load(path).adjustment_gain == 0.12
    data = yaml.safe_load(path.read_text())
    data['adjustment_gain'] = -1
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(CalibrationFileError, match='field "adjustment_gain"'):
        Calibration.load(path)
    with pytest.raises(ValueError):
        calibration.with_gain(float('nan'))


@pytest.mark.parametrize('field, value, limit, shown', [
    ('rmse', 37.54, 37.5, 'RMSE 37.54 kPa > max_rmse_kpa 37.5 kPa'),        # read '37.5 > 37.5' before
    ('rmse', 37.5000004, 37.5, 'RMSE 37.5000004 kPa > max_rmse_kpa 37.5 kPa'),
    ('r2', 0.79996, 0.8, 'R^2 0.79996 < min_r2 0.8'),
    ('rmse', 52.0, 37.5, 'RMSE 52 kPa > max_rmse_kpa 37.5 kPa'),           # no more digits than needed
])
def test_a_refusal_never_reads_a_value_equal_to_its_limit(field, value, limit, shown):
    import dataclasses
    from fabric_guidance.core.calibration import Acceptance
    from fabric_guidance.core.power_law import fit_power_law
    schedule = pressure_schedule(P_MAX, 10)
    theta = np.asarray(TRUE['left'].theta(schedule, P_MAX))
    report = dataclasses.replace(fit_power_law(theta, schedule, P_MAX), **{field: value})
    acceptance = Acceptance(max_rmse_kpa=limit) if field == 'rmse' else Acceptance(min_r2=limit)
    assert acceptance.refusal(theta, report) == shown
