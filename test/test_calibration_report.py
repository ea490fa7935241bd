"""The calibration workflow around Algorithm 1: the fit report (text and PNG) of a wearer's
calibration, its command line, and a failed calibration that writes nothing.

The core stays free of matplotlib; the report lives in fabric_guidance.lab.calibration_report.
pressure_controller writes the report next to <calibration_dir>/<wearer>.yaml (the last test,
as a process, reusing the fixture and the simulated wearer of test_node_pressure_controller).
"""
import math
import subprocess
import sys

import numpy as np
import pytest
from std_srvs.srv import Trigger

from fabric_guidance import interface

from fabric_guidance.lab.calibration_report import (direction_fits, draw_fit_figure, format_fit_report, main,
                                                    report_paths, write_fit_report)
from fabric_guidance.core.calibration import (DONE, FAILED, Calibration, CalibrationProcedure,
                                              DirectionCalibration)
from fabric_guidance.core.geometry import DIRECTIONS
from fabric_guidance.core.power_law import CalibrationFitError, PowerLaw, fit_power_law
from rosgraph import CONFIG, ROOT, wait_until
from test_node_pressure_controller import FAST_CAL, controller, wearer_answering  # noqa: F401 (fixture)

pytestmark = pytest.mark.graph  # starts a process graph with DDS

P_MAX = 375.0
SIM_CAL = CONFIG / 'calibrations' / 'sim-wearer.yaml'


@pytest.fixture(scope='module')
def noisy():
    """The simulated wearer's points with 2 deg of gaze noise, refitted: residuals worth reading."""
    base = Calibration.load(SIM_CAL)
    rng = np.random.default_rng(7)
    dirs, reports = {}, {}
    for d in DIRECTIONS:
        entry = base.directions[d]
        angles = np.asarray(entry.angles) + rng.normal(0.0, 2.0, len(entry.angles))
        report = fit_power_law(angles, entry.pressures, P_MAX)
        dirs[d] = DirectionCalibration(report.law, entry.pressures, tuple(map(float, angles)), report.as_dict())
        reports[d] = report
    return Calibration('noisy-wearer', P_MAX, dirs), reports


def _numbers(line):
    return [float(x) for x in line.split()]


def test_text_report_has_coefficients_fit_quality_and_every_residual(noisy):
    cal, reports = noisy
    text = format_fit_report(cal, source='somewhere/noisy-wearer.yaml')
    assert 'wearer noisy-wearer' in text and 'P_MAX 375 kPa' in text and 'somewhere/noisy-wearer.yaml' in text
    lines = text.splitlines()
    for d in DIRECTIONS:
        report = reports[d]
        # The summary row: a, b, c, points, RMSE, R^2, worst residual.
        row = next(line for line in lines if line.startswith(f'{d} ') and 'P =' not in line)
        a, b, c, n, rmse, r2, worst = _numbers(row[len(d):])
        assert (a, b, c) == (pytest.approx(report.law.a, rel=1e-3), pytest.approx(report.law.b, abs=1e-4),
                             pytest.approx(report.law.c, abs=1e-3))
        assert n == 10
        assert rmse == pytest.approx(report.rmse, abs=1e-3)
        assert r2 == pytest.approx(report.r2, abs=1e-4)
        assert worst == pytest.approx(np.max(np.abs(report.residuals)), abs=1e-3)
        # The section: the equation, then one row per point with its residual (measured - fitted).
        start = lines.index(next(line for line in lines if line.startswith(f'{d} (') and 'P =' in line))
        header = next(i for i in range(start, len(lines)) if lines[i].lstrip().startswith('step '))
        rows = [_numbers(line) for line in lines[header + 1:header + 11]]
        # The standard errors and the 95 % band at 10, 20 and 30 deg, as the fit gave them.
        se_line = next(line for line in lines[start:header] if 'standard errors' in line)
        for k in 'abc':
            assert f'{k} {report.std_errors[k]:.3g}' in se_line, se_line
        band_line = next(line for line in lines[start:header] if 'band' in line)
        for angle, (p, w) in report.band_kpa.items():
            assert f'{angle:g} deg {p:.1f} +- {w:.1f} kPa' in band_line, band_line
        assert [int(r[0]) for r in rows] == list(range(1, 11))
        np.testing.assert_allclose([r[1] for r in rows], cal.directions[d].pressures, atol=0.005)
        np.testing.assert_allclose([r[2] for r in rows], cal.directions[d].angles, atol=0.005)
        np.testing.assert_allclose([r[4] for r in rows], report.residuals, atol=0.0005)
        np.testing.assert_allclose([r[1] - r[3] for r in rows], report.residuals, atol=0.01)


def test_recomputed_fit_quality_matches_the_fit(noisy):
    cal, reports = noisy
    for f in direction_fits(cal):
        r = reports[f.direction]
        assert f.rmse == pytest.approx(r.rmse, rel=1e-9)
        assert f.r2 == pytest.approx(r.r2, rel=1e-9)
        np.testing.assert_allclose(f.residuals, r.residuals, atol=1e-9)


def test_png_has_four_direction_panels_with_points_curve_and_residuals(noisy, tmp_path):
    cal, _ = noisy
    fig = draw_fit_figure(cal)
    axes = fig.get_axes()
    assert len(axes) == 8   # per direction: the points and the curve, and the residual strip under it
    mains, strips = axes[0::2], axes[1::2]
    for d, ax, strip in zip(DIRECTIONS, mains, strips):
        assert ax.get_title().startswith(f'{d} (') and 'RMSE' in ax.get_title()
        x, y = next(line.get_data() for line in ax.get_lines() if line.get_marker() == 'o')
        np.testing.assert_allclose(x, cal.directions[d].angles)
        np.testing.assert_allclose(y, cal.directions[d].pressures)
        curve = next(line for line in ax.get_lines() if line.get_linestyle() == '-')
        cx, cy = curve.get_data()
        np.testing.assert_allclose(cy, cal.directions[d].law.pressure(cx), rtol=1e-9)
        # The 95 % band of the fit around the curve, as wide as law_uncertainty says at 20 deg.
        band = next(col for col in ax.collections if 'band' in str(col.get_label()))
        verts = band.get_paths()[0].vertices
        near = verts[np.argmin(np.abs(verts[:, 0] - 20.0))][0]
        from fabric_guidance.core.power_law import law_uncertainty
        _, half = law_uncertainty(cal.directions[d].law, cal.directions[d].angles, cal.directions[d].pressures,
                                  cal.p_max, angles=[near]).band_kpa[near]
        at = verts[np.isclose(verts[:, 0], near)][:, 1]
        assert half > 0 and at.max() - at.min() == pytest.approx(2 * half, rel=1e-6)
        rx, ry = next(line.get_data() for line in strip.get_lines() if line.get_marker() == 'o')
        np.testing.assert_allclose(ry, np.asarray(cal.directions[d].pressures) - cal.directions[d].law.pressure(rx))

    txt, png = write_fit_report(cal, tmp_path / 'new' / 'folder')
    assert (txt, png) == report_paths(cal, tmp_path / 'new' / 'folder')
    assert txt.name == 'noisy-wearer-fit.txt' and png.name == 'noisy-wearer-fit.png'
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    from matplotlib.image import imread
    h, w = imread(png).shape[:2]
    assert (w, h) == (1100, 850)
    assert txt.read_text() == format_fit_report(cal)
    assert sorted(p.name for p in txt.parent.iterdir()) == ['noisy-wearer-fit.png', 'noisy-wearer-fit.txt']


def test_a_calibration_without_points_is_reported_as_not_fitted(tmp_path):
    cal = Calibration.from_laws('given', [PowerLaw(20.0, 0.65, 25.0)] * 4)
    text = format_fit_report(cal)
    assert text.count('no points: coefficients given, not fitted') == 4
    txt, png = write_fit_report(cal, tmp_path)
    assert txt.exists() and png.exists()


def test_cli_writes_the_report_and_refuses_a_bad_file_with_its_reason(tmp_path, capsys):
    assert main([str(SIM_CAL), '--out', str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert 'wearer sim-wearer' in out and str(tmp_path / 'sim-wearer-fit.png') in out
    assert (tmp_path / 'sim-wearer-fit.txt').read_text() in out

    bad = tmp_path / 'bad.yaml'
    bad.write_text(SIM_CAL.read_text().replace('p_max_kpa: 375.0', 'p_max_kpa: -1'))
    assert main([str(bad)]) == 2
    err = capsys.readouterr().err
    assert 'p_max_kpa' in err and str(bad) in err
    assert not (tmp_path / 'sim-wearer-fit.txt').read_text() == ''
    assert sorted(p.name for p in tmp_path.iterdir()) == ['bad.yaml', 'sim-wearer-fit.png', 'sim-wearer-fit.txt']


def test_the_shipped_example_is_reported_into_the_users_folder_not_config_nor_the_current_one(
        tmp_path, monkeypatch, capsys):
    """Into the current folder it was: from the checkout's root, untracked files in the checkout."""
    before = sorted(p.name for p in SIM_CAL.parent.iterdir())
    cwd, home = tmp_path / 'cwd', tmp_path / 'home'
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    monkeypatch.setenv('HOME', str(home))
    assert main([str(SIM_CAL)]) == 0
    reports = home / '.fabric_guidance' / 'reports'
    assert (reports / 'sim-wearer-fit.png').is_file() and (reports / 'sim-wearer-fit.txt').is_file()
    assert not any(cwd.iterdir())
    assert sorted(p.name for p in SIM_CAL.parent.iterdir()) == before
    # A file of the user's own is still reported beside itself.
    own = tmp_path / 'own' / 'sim-wearer.yaml'
    own.parent.mkdir()
    own.write_text(SIM_CAL.read_text())
    assert main([str(own)]) == 0
    assert (own.parent / 'sim-wearer-fit.txt').is_file()


def test_the_module_runs_as_a_command(tmp_path):
    out = subprocess.run([sys.executable, '-m', 'fabric_guidance.lab.calibration_report', str(SIM_CAL), '--out',
                          str(tmp_path)], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    assert (tmp_path / 'sim-wearer-fit.png').exists()


def _gaze(yaw, pitch):
    y, p = math.radians(yaw), math.radians(pitch)
    return [math.cos(p) * math.cos(y), math.cos(p) * math.sin(y), math.sin(p)]


def test_a_failing_procedure_writes_nothing_and_keeps_the_previous_files(tmp_path, noisy):
    """What the node does on DONE (result, save, report) refuses a failed procedure with its
    reason before anything is written: the previous file and report stay byte for byte."""
    folder = tmp_path / 'calibrations'
    previous = noisy[0]
    previous.save(folder / 'noisy-wearer.yaml')
    write_fit_report(previous, folder)
    before = {p.name: p.read_bytes() for p in folder.iterdir()}

    # The wearer does not move with the pressure: the first direction cannot be fitted.
    proc = CalibrationProcedure('noisy-wearer', steps=5, dwell_s=0.2, rest_s=0.2, record_window_s=0.1)
    t = 0.0
    while proc.phase not in (DONE, FAILED) and t < 100.0:
        proc.tick(t, _gaze(0.0, 0.0))
        t += 0.02
    assert proc.phase == FAILED
    assert proc.error.startswith('left: ') and 'distinct angles' in proc.error
    with pytest.raises(CalibrationFitError, match='distinct angles'):
        cal = proc.result(base=previous)
        cal.save(folder / 'noisy-wearer.yaml')
        write_fit_report(cal, folder)
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before

    # A refused fit (R^2 below the floor) is refused the same way, naming the fit.
    proc = CalibrationProcedure('noisy-wearer', steps=5, dwell_s=0.2, rest_s=0.2, record_window_s=0.1,
                                min_r2=0.999)
    law = PowerLaw(20.0, 0.65, 25.0)
    angle, t = 0.0, 0.0
    while proc.phase not in (DONE, FAILED) and t < 100.0:
        cmd = proc.tick(t, _gaze(angle, 0.0))
        # The right angle for the pressure, give or take 6 deg every other step.
        angle = law.theta(cmd.pressure, P_MAX) + 6.0 * (-1) ** cmd.step if cmd.direction == 'left' else 0.0
        t += 0.02
    assert proc.phase == FAILED and 'R^2' in proc.error, proc.error
    with pytest.raises(CalibrationFitError):
        proc.result(base=previous)
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before


@pytest.mark.parametrize('controller', [FAST_CAL], indirect=True)
def test_pressure_controller_writes_the_report_next_to_the_wearers_file(controller, tmp_path):  # noqa: F811 (fixture)
    graph, probe, upstream, _ = controller
    folder = tmp_path / 'calibrations'
    with wearer_answering(controller) as status:
        wait_until(lambda: probe.call(Trigger, interface.START_CALIBRATION, Trigger.Request()).success, 15.0,
                   what='start_calibration accepted')
        wait_until(lambda: any(m.data.startswith(('done', 'failed')) for m in status), 60.0, what='calibration end')
    done = status[-1].data
    assert done.startswith('done'), [m.data for m in status]
    cal = Calibration.load(folder / 'alice.yaml')
    txt, png = report_paths(cal, folder)
    assert str(txt) in done and str(png) in done       # the status says where the report goes
    wait_until(lambda: png.exists() and txt.exists(), 15.0, what='the fit report next to alice.yaml')
    assert txt.read_text() == format_fit_report(cal, source=str(folder / 'alice.yaml'))
    # The node logs once both files are in place: the line may follow them by a moment.
    wait_until(lambda: 'fit report written' in graph.log('pressure_controller'), 10.0, what='the log line')
    # Progress said which direction, which step, which pressure and how far along.
    assert any(m.data.startswith('apply down step 2/5') and 'kPa' in m.data and m.data.endswith('%')
               for m in status)
    report_before = {p.name: p.read_bytes() for p in folder.iterdir()}

    # A wearer who does not move: refused with its reason, file and report untouched.
    upstream.yaw = upstream.pitch = 0.0
    n = len(status)
    assert probe.call(Trigger, interface.START_CALIBRATION, Trigger.Request()).success
    wait_until(lambda: any(m.data.startswith('failed') for m in status[n:]), 60.0, what='the refused calibration')
    assert 'distinct angles' in status[-1].data and 'previous calibration is kept' in status[-1].data
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == report_before


def test_the_figure_shows_which_direction_was_refused_and_why():
    """The operator looks at the PNG: a refused direction says so there, not only in the text."""
    import dataclasses
    cal = Calibration.load(CONFIG / 'calibrations' / 'sim-wearer.yaml')
    directions = dict(cal.directions)
    fit = dict(directions['left'].fit, refused='fit refused: angle span 0.3 deg < min_span_deg 5 deg')
    directions['left'] = dataclasses.replace(directions['left'], fit=fit)
    fig = draw_fit_figure(dataclasses.replace(cal, directions=directions))
    texts = {ax.get_title(): [t.get_text() for t in ax.texts] for ax in fig.axes}
    marked = [title for title, shown in texts.items() if any('REFUSED' in t for t in shown)]
    assert len(marked) == 1 and marked[0].startswith('left'), texts
    assert any('min_span_deg 5 deg' in t for t in sum(texts.values(), []))
