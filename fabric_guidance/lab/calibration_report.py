"""The fit report of a wearer's calibration: a text file a person can read and one PNG.

For each direction (left, right, down, up) Algorithm 1 measured n (pressure, angle) points and
fitted P = a * theta^b + c by least squares (core/power_law.py). The report shows, per direction:

- text (<wearer>-fit.txt): the coefficients with their standard errors, the number of
  points, RMSE and R^2 of the fit, the fitted pressure at 10, 20 and 30 deg with its 95 %
  band, the solver's message, and every point with its fitted pressure and its residual
  (measured minus fitted, kPa);
- PNG (<wearer>-fit.png): four panels, one per direction, each with the measured points,
  the fitted curve up to P_MAX with its 95 % band and, in a strip below it, the residuals.

RMSE, R^2, the residuals, the standard errors and the band are recomputed from the points and
the coefficients in the file (core.power_law.law_uncertainty)
(so a hand-edited file is reported as it is, not as it was fitted). A direction without points
(coefficients given, e.g. Calibration.from_laws) is reported as not fitted.

pressure_controller writes the report next to <calibration_dir>/<wearer>.yaml after a
successful calibration; `fabric-guidance calibration-report FILE.yaml --out DIR` writes it for
any calibration file. Drawn on a bare matplotlib Figure (Agg canvas): no pyplot, no display.
The core (fabric_guidance.core) stays free of matplotlib: this module is outside it.
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass
import math
from pathlib import Path
import sys

import numpy as np

from .. import subcommand
from ..atomic import atomic_write, write_text
from ..paths import share_dir
from ..core.calibration import NOT_MEASURED, Calibration, CalibrationFileError
from ..core.geometry import DIRECTIONS
from ..core.power_law import PowerLaw, law_uncertainty
from ..core.plot_style import legend_clear, with_unit
from ..core.power_law_fit import BAND_COVERAGE
from ..core.safe_input import check_wearer

PROG = 'fabric-guidance calibration-report'
HELP = "write the fit report (text and PNG) of a wearer's calibration file"
#: What each direction's angle is: the torso movement of Eq. 1 and the gaze angle it moves.
MOVEMENT = {'left': 'left twist, gaze left', 'right': 'right twist, gaze right',
            'down': 'forward bend, gaze down', 'up': 'backward bend, gaze up'}


@dataclass(frozen=True)
class DirectionFit:
    """One direction's points against its curve. Empty arrays when it has no points."""

    direction: str
    a: float
    b: float
    c: float
    pressures: np.ndarray   # kPa, as measured (the step pressures)
    angles: np.ndarray      # deg, as measured
    fitted: np.ndarray      # kPa, f(angle)
    residuals: np.ndarray   # kPa, measured - fitted
    rmse: float             # kPa; NaN without points
    r2: float               # NaN without points
    solver_message: str
    #: {'a', 'b', 'c'} -> standard error (None: not estimable from n = 3 points, inf: not identified)
    std_errors: dict
    #: angle (deg) -> (fitted pressure, half-width of the 95 % band) in kPa, at BAND_ANGLES_DEG
    band_kpa: dict

    @property
    def has_points(self) -> bool:
        return self.pressures.size > 0


def direction_fits(calibration: Calibration) -> list[DirectionFit]:
    """Per direction (left, right, down, up): points, fitted pressures, residuals, RMSE, R^2."""
    out = []
    for d in DIRECTIONS:
        entry = calibration.directions[d]
        law = entry.law
        p = np.asarray(entry.pressures, dtype=float)
        t = np.asarray(entry.angles, dtype=float)
        if p.size:
            unc = law_uncertainty(law, t, p, calibration.p_max)
            se, band = unc.std_errors, unc.band_kpa
            fitted = np.atleast_1d(law.pressure(t))
            res = p - fitted
            rmse = float(np.sqrt(np.mean(res ** 2)))
            ss_tot = float(np.sum((p - p.mean()) ** 2))
            r2 = 1.0 - float(np.sum(res ** 2)) / ss_tot if ss_tot > 0 else float('nan')
        else:
            fitted = res = np.zeros(0)
            rmse = r2 = float('nan')
            se, band = {'a': None, 'b': None, 'c': None}, {}
        out.append(DirectionFit(d, law.a, law.b, law.c, p, t, fitted, res, rmse, r2,
                                str(entry.fit.get('solver_message', '')) if entry.fit else '', se, band))
    return out


def _se(v) -> str:
    return '-' if v is None else f'{v:.3g}'


def band_curve(calibration: Calibration, f: DirectionFit, theta: np.ndarray) -> np.ndarray | None:
    """Half-width of the 95 % band of the fitted pressure at `theta`, kPa; None when the points
    cannot estimate it (n = 3)."""
    unc = law_uncertainty(PowerLaw(f.a, f.b, f.c), f.angles, f.pressures, calibration.p_max, angles=theta)
    widths = [w for _, w in unc.band_kpa.values()]
    if not widths or any(w is None for w in widths):
        return None
    return np.asarray(widths, dtype=float)


def format_fit_report(calibration: Calibration, source: str | None = None) -> str:
    """The text report: a header, then per direction the coefficients, fit quality and points."""
    fits = direction_fits(calibration)
    lines = [
        f'Calibration fit report: wearer {calibration.wearer}',
        f'created {calibration.created or "-"}; P_MAX {calibration.p_max:g} kPa'
        + (f'; own adjustment gain G {calibration.adjustment_gain:g}' if calibration.adjustment_gain is not None
           else ''),
        *([f'file {source}'] if source else []),
        'model P = a * theta^b + c (Eq. 1), fitted by least squares (Algorithm 1, Eq. 4);',
        'P in kPa, theta in degrees from the gaze at rest; residual = measured - fitted pressure.',
        '',
        f'{"direction":<9} {"a":>10} {"b":>7} {"c":>8} {"points":>6} {"RMSE kPa":>9} {"R^2":>8} '
        f'{"max|res| kPa":>12}',
    ]
    for f in fits:
        if _not_measured(calibration, f):
            lines.append(f'{f.direction:<9} not measured: the calibration ended before this direction')
            continue
        worst = f'{np.max(np.abs(f.residuals)):12.3f}' if f.has_points else f'{"-":>12}'
        rmse = f'{f.rmse:9.3f}' if f.has_points else f'{"-":>9}'
        r2 = f'{f.r2:8.4f}' if f.has_points and math.isfinite(f.r2) else f'{"-":>8}'
        lines.append(f'{f.direction:<9} {f.a:10.4g} {f.b:7.4f} {f.c:8.3f} {f.pressures.size:6d} {rmse} {r2} {worst}')
    for f in fits:
        if _not_measured(calibration, f):
            continue
        lines += ['', f'{f.direction} ({MOVEMENT[f.direction]}): P = {f.a:.6g} * theta^{f.b:.6g} + {f.c:.6g}']
        if not f.has_points:
            lines.append('  no points: coefficients given, not fitted from measurements')
            continue
        reach = _reach(f, calibration.p_max)
        lines.append(f'  {f.pressures.size} points, RMSE {f.rmse:.3f} kPa, R^2 '
                     + (f'{f.r2:.5f}' if math.isfinite(f.r2) else '- (all pressures equal)')
                     + f'; P_MAX is reached at theta = {reach:.1f} deg')
        lines.append(f'  standard errors: a {_se(f.std_errors["a"])}, b {_se(f.std_errors["b"])}, '
                     f'c {_se(f.std_errors["c"])} kPa'
                     + (' (3 points: none can be estimated)' if f.std_errors['a'] is None else ''))
        if f.band_kpa and all(w is not None for _, w in f.band_kpa.values()):
            lines.append(f'  fitted pressure, {BAND_COVERAGE:.0%} band: ' + '; '.join(
                f'{t:g} deg {p:.1f} +- {w:.1f} kPa' for t, (p, w) in f.band_kpa.items()))
        refused = calibration.directions[f.direction].fit.get('refused')
        if refused:
            lines.append(f'  REFUSED (not used for guidance): {refused}')
        if f.solver_message:
            lines.append(f'  solver: {f.solver_message}')
        lines.append(f'  {"step":>4} {"pressure kPa":>12} {"angle deg":>10} {"fitted kPa":>10} {"residual kPa":>12}')
        for i, (p, t, fp, r) in enumerate(zip(f.pressures, f.angles, f.fitted, f.residuals), start=1):
            lines.append(f'  {i:4d} {p:12.2f} {t:10.2f} {fp:10.2f} {r:+12.3f}')
    return '\n'.join(lines) + '\n'


def _not_measured(calibration: Calibration, f: DirectionFit) -> bool:
    """A direction a failed first calibration never reached: its law is a placeholder."""
    return bool(calibration.directions[f.direction].fit.get(NOT_MEASURED))


def _reach(f: DirectionFit, p_max: float) -> float:
    """The angle where the curve reaches p_max (THETA_MAX if it never does; 0 below c)."""
    return float(PowerLaw(f.a, f.b, f.c).theta(p_max, p_max))


def draw_fit_figure(calibration: Calibration):
    """A matplotlib Figure: 2 x 2 direction panels, each points + fitted curve over a residual strip."""
    from matplotlib.figure import Figure
    from matplotlib.gridspec import GridSpecFromSubplotSpec

    fig = Figure(figsize=(11, 8.5), layout='constrained')
    outer = fig.add_gridspec(2, 2)
    with_legend = []        # the legends once the layout is whole: where each covers no data
    for i, f in enumerate(direction_fits(calibration)):
        inner = GridSpecFromSubplotSpec(2, 1, subplot_spec=outer[i // 2, i % 2], height_ratios=(3, 1), hspace=0.05)
        ax = fig.add_subplot(inner[0])
        ax_res = fig.add_subplot(inner[1], sharex=ax)
        if _not_measured(calibration, f):
            ax.set_title(f'{f.direction} ({MOVEMENT[f.direction]}): not measured', fontsize=10)
            ax.text(0.5, 0.5, 'the calibration ended\nbefore this direction', ha='center', va='center',
                    transform=ax.transAxes, color='0.4')
            ax.set_axis_off()
            ax_res.set_axis_off()
            continue
        top = max(_reach(f, calibration.p_max), float(np.max(f.angles)) if f.has_points else 0.0, 1.0)
        theta = np.linspace(0.0, top * 1.05, 300)
        curve = f.a * theta ** f.b + f.c
        ax.plot(theta, curve, color='tab:blue', lw=1.8,
                label=f'fit P = {f.a:.3g}·θ^{f.b:.3g} + {f.c:.3g}')
        half = band_curve(calibration, f, theta) if f.has_points else None
        if half is not None:
            ax.fill_between(theta, curve - half, curve + half, color='tab:blue', alpha=0.18, lw=0,
                            label=f'{BAND_COVERAGE:.0%} band of the fit')
        ax.axhline(calibration.p_max, color='0.5', ls=':', lw=1, label=f'P_MAX {calibration.p_max:g} kPa')
        if f.has_points:
            ax.vlines(f.angles, f.fitted, f.pressures, color='tab:red', lw=1)
            ax.plot(f.angles, f.pressures, 'o', color='tab:orange', mec='k', ms=5, label='measured points')
            ax_res.axhline(0.0, color='0.5', lw=1)
            ax_res.vlines(f.angles, 0.0, f.residuals, color='tab:red', lw=1)
            ax_res.plot(f.angles, f.residuals, 'o', color='tab:red', ms=3)
            r2 = f'{f.r2:.4f}' if math.isfinite(f.r2) else '-'
            quality = f'n {f.pressures.size}, RMSE {f.rmse:.2f} kPa, R² {r2}'
        else:
            ax_res.text(0.5, 0.5, 'no points', ha='center', va='center', transform=ax_res.transAxes)
            quality = 'no points (coefficients given)'
        ax.set_title(f'{f.direction} ({MOVEMENT[f.direction]}): {quality}', fontsize=10)
        refused = calibration.directions[f.direction].fit.get('refused')
        if refused:  # the operator sees why on the figure too, not only in the text report
            reason = str(refused).removeprefix('fit refused: ')[:60]
            # Bottom right: the rising curve leaves that corner empty.
            ax.text(0.98, 0.04, f'REFUSED\n{reason}', transform=ax.transAxes,
                    ha='right', va='bottom', color='tab:red', fontsize=8, fontweight='bold',
                    bbox=dict(facecolor='white', edgecolor='tab:red', alpha=0.9))
        ax.set_ylabel(with_unit('pressure P', 'kPa'))
        ax.set_ylim(bottom=0.0, top=calibration.p_max * 1.1)
        with_legend.append(ax)
        ax.grid(alpha=0.3)
        ax.tick_params(labelbottom=False)
        ax_res.set_ylabel(with_unit('residual', 'kPa').replace(' (', '\n('), fontsize=8)
        ax_res.set_xlabel(with_unit('gaze angle θ', 'deg'))
        ax_res.grid(alpha=0.3)
    fig.suptitle(f'Calibration of {calibration.wearer} ({calibration.created or "-"}): '
                 'measured points, fitted curve, residuals (measured - fitted)')
    renderer = _drawn(fig)
    for ax in with_legend:
        legend_clear(ax, fontsize=8, renderer=renderer)
    return fig


def _drawn(fig):
    """The renderer of a draw of the figure (on an Agg canvas)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return canvas.get_renderer()


def report_paths(calibration: Calibration, folder: str | Path) -> tuple[Path, Path]:
    """Where write_fit_report writes: <folder>/<wearer>-fit.txt and <folder>/<wearer>-fit.png."""
    folder = Path(folder)
    check_wearer(calibration.wearer, 'the calibration\'s wearer')
    return folder / f'{calibration.wearer}-fit.txt', folder / f'{calibration.wearer}-fit.png'


def write_fit_report(calibration: Calibration, folder: str | Path, source: str | None = None) -> tuple[Path, Path]:
    """Write the text report and the PNG into `folder` (created if needed); return their paths.

    Each file is written atomically: a reader sees the previous report or the new one.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    txt_path, png_path = report_paths(calibration, folder)
    txt_path.parent.mkdir(parents=True, exist_ok=True)
    text = format_fit_report(calibration, source)
    fig = draw_fit_figure(calibration)
    FigureCanvasAgg(fig)
    atomic_write(png_path, lambda f: fig.savefig(f, format='png', dpi=100))
    write_text(txt_path, text)
    return txt_path, png_path


# ---- command line: fabric-guidance calibration-report FILE.yaml --out DIR

def configure(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    parser.add_argument('file', type=Path, metavar='FILE.yaml', help="a wearer's calibration file")
    parser.add_argument('--out', type=Path, default=None, metavar='DIR',
                        help="folder for <wearer>-fit.txt and <wearer>-fit.png (default: the file's folder; "
                             "~/.fabric_guidance/reports for a file of the package's config/)")
    return parser


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the `calibration-report` subcommand to an argparse subparsers object; dispatch to run(args)."""
    return subcommand.add(subparsers, 'calibration-report', HELP, __doc__, configure, run)


#: Where the report of a file the package ships goes by default: beside the package's other
#: per-user folders (~/.fabric_guidance/calibrations, state), never into the checkout.
SHIPPED_REPORTS = Path('~/.fabric_guidance/reports')


def default_out(file: Path) -> Path:
    """The file's folder; ~/.fabric_guidance/reports for a file the package ships (config/), so
    that reading the shipped example writes nothing into the checkout (the current folder, from
    the checkout's root, did) or the install."""
    shipped = share_dir().resolve() / 'config'
    if file.resolve().is_relative_to(shipped):
        return SHIPPED_REPORTS.expanduser()
    return file.parent


def run(args: argparse.Namespace) -> int:
    """Load the file, print the text report, write both files. 2 on an unusable file or folder."""
    try:
        cal = Calibration.load(args.file)
        out = args.out if args.out is not None else default_out(args.file)
        txt, png = write_fit_report(cal, out, source=str(args.file))
    except (CalibrationFileError, OSError, ValueError, ArithmeticError) as exc:
        # ArithmeticError: a value the file's checks let through that the drawing cannot take
        subcommand.error(PROG, exc)
        return 2
    print(txt.read_text(), end='')
    print(f'\nreport: {txt}\nplot:   {png}', flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    return subcommand.main(PROG, __doc__, configure, run, argv)


if __name__ == '__main__':
    sys.exit(main())
