"""Algorithm 1 of the paper as a state machine that needs no ROS, and the calibration file.

For each direction k (left, right, down, up): vent and let the wearer face front (rest), take
the initial gaze g0 (with rest_tolerance_deg: only once the gaze is steady and back at the rest
gaze, else rest again, so a wearer still coming back from the last direction does not feed the
fit a rest offset), then
apply n increasing pressures up to P_MAX, each for a dwell; at the end of each dwell record the
angle reached from g0 in direction k (the median over a short window, so one noisy gaze sample
does not become a calibration point). After the last step fit P = a*theta^b + c by least
squares (core.power_law) and judge the fit (Acceptance). Any direction that cannot be fitted,
or is refused, fails the whole procedure with its reason; nothing is written then.

The caller drives it: tick(t, gaze) with the latest gaze direction (REP 103) returns the
pressure to apply to which direction now. It is the same code in a node, in the headless
simulator and in tests.

The calibration file is YAML a person can read: schema version, units, wearer, date, P_MAX,
and per direction the coefficients, the raw points and the fit report. It is written
atomically (temporary file, fsync, rename) so a crash never leaves half a file, and read back
with validation that names the field at fault.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime, timezone
import math
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import yaml

from ..atomic import write_text
from .feedback import FRONT, PAPER_P_MAX
from .safe_input import WEARER_PATTERN, WEARER_RULE, excerpt, got, load_yaml
from .geometry import DIRECTIONS, GeometryError, angles_between, unit_vector
from .power_law import CalibrationFitError, FitReport, PowerLaw, fit_power_law
from .power_law_fit import FIT_B_MAX, FIT_B_MIN

SCHEMA_VERSION = 1
#: The paper's 10 steps per direction.
PAPER_STEPS = 10


#: Bounds of a calibration file's values: the controller's own p_max_kpa range, and a gaze angle
#: (beyond them a hand-edited file overflows the report's arithmetic).
P_MAX_LIMIT_KPA = 1000.0
ANGLE_LIMIT_DEG = 180.0


def _number(x) -> bool:
    """A finite int or float, not a bool (True is an int to Python, not a number to a file)."""
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        return False
    try:
        return math.isfinite(x)
    except OverflowError:  # an int too large for a float
        return False


class CalibrationFileError(ValueError):
    """A calibration file that cannot be used, naming the file, the field and the reason."""


def pressure_schedule(p_max: float = PAPER_P_MAX, steps: int = PAPER_STEPS, first: float | None = None) -> np.ndarray:
    """Increasing pressures ending at p_max (Algorithm 1: 0 <= P_k1 < ... < P_kn <= P_MAX).

    By default evenly spaced from p_max/steps; `first` sets the lowest step instead.
    """
    if not (isinstance(steps, (int, np.integer)) and steps >= 3):
        raise ValueError(f'a calibration needs at least 3 steps, got {excerpt(steps)}')
    if not (math.isfinite(p_max) and p_max > 0):
        raise ValueError(f'p_max must be finite and > 0 kPa, got {p_max}')
    lo = p_max / steps if first is None else float(first)
    if not 0.0 <= lo < p_max:
        raise ValueError(f'the first step must lie in [0, {p_max}) kPa, got {lo}')
    return np.linspace(lo, p_max, steps)


@dataclass(frozen=True)
class Acceptance:
    """When a direction's fit is good enough to guide with: useless ones are refused.

    The thresholds and why they are where they are: docs/calibration.md, "Acceptance".
    min_r2 [-]: the fit explains this share of the pressure variance (0.8).
    min_span_deg [deg]: the angles reached span at least this (5 deg, the paper's acceptance).
    max_reversal_deg [deg]: no angle falls more than this below an earlier one (2 deg).
    max_rmse_kpa [kPa]: residuals within one of the paper's pressure steps (37.5 kPa).
    min_b, max_b [-]: the exponent lies well inside the solver's bounds
    (power_law_fit.FIT_B_MIN 0.05, FIT_B_MAX 10): a fit at or near a bound is not a power law
    of these points (a logarithm in disguise at the lower one).
    max_abs_c_fraction [-]: |c| <= this * P_MAX; beyond it the law is the difference of two
    large terms.
    max_negative_c_fraction [-]: a c below -this * P_MAX is refused when the law then commands
    nothing over more than max_dead_zone_deg from rest (without pressure the wearer was at rest).
    max_dead_zone_deg [deg]: the law commands less than the first step's pressure over at most
    this many degrees beyond the smallest angle measured (where that pressure already moved
    the wearer).
    max_se_steps [-]: the standard error of the fitted pressure at every measured angle is
    within this many pressure steps (the schedule's spacing).
    None disables a threshold.
    """

    min_r2: float | None = 0.8
    min_span_deg: float | None = 5.0
    max_reversal_deg: float | None = 2.0
    max_rmse_kpa: float | None = 37.5
    min_b: float | None = 0.2
    max_b: float | None = 5.0
    max_abs_c_fraction: float | None = 0.25
    max_negative_c_fraction: float | None = 0.1
    max_dead_zone_deg: float | None = 3.0
    max_se_steps: float | None = 1.0

    def __post_init__(self):
        for name in ('min_r2', 'min_span_deg', 'max_reversal_deg', 'max_rmse_kpa', 'min_b', 'max_b',
                     'max_abs_c_fraction', 'max_negative_c_fraction', 'max_dead_zone_deg', 'max_se_steps'):
            v = getattr(self, name)
            if v is not None and not math.isfinite(v):
                raise ValueError(f'calibration acceptance {name} must be finite or None, got {v}')

    def refusal(self, angles: Sequence[float], report: FitReport) -> str:
        """'' when acceptable, else which threshold the fit misses, with the values."""
        t = np.asarray(angles, dtype=float)
        span = float(np.ptp(t)) if t.size else 0.0
        if self.min_span_deg is not None and not span >= self.min_span_deg:
            return f'angle span {_past(span, self.min_span_deg)} deg < min_span_deg {self.min_span_deg:g} deg'
        if self.max_reversal_deg is not None and t.size:
            drop = float(np.max(np.maximum.accumulate(t) - t))
            if drop > self.max_reversal_deg:
                return (f'angles not monotonic: one falls {_past(drop, self.max_reversal_deg)} deg below an '
                        f'earlier one > max_reversal_deg {self.max_reversal_deg:g} deg')
        if self.min_r2 is not None and not report.r2 >= self.min_r2:
            return f'R^2 {_past(report.r2, self.min_r2)} < min_r2 {self.min_r2:g}'
        if self.max_rmse_kpa is not None and not report.rmse <= self.max_rmse_kpa:
            return f'RMSE {_past(report.rmse, self.max_rmse_kpa)} kPa > max_rmse_kpa {self.max_rmse_kpa:g} kPa'
        return self.shape_refusal(t, report)

    def shape_refusal(self, angles: np.ndarray, report: FitReport) -> str:
        """The law's shape: exponent, offset, dead zone, and how well the points determine it."""
        law, p, p_max = report.law, np.asarray(report.pressure, dtype=float), report.p_max
        if self.min_b is not None and not law.b >= self.min_b:
            return (f'exponent b {_past(law.b, self.min_b)} < min_b {self.min_b:g} (the fit sits at or near its lower '
                    f'bound {FIT_B_MIN:g}: not a power law of these points)')
        if self.max_b is not None and not law.b <= self.max_b:
            return (f'exponent b {_past(law.b, self.max_b)} > max_b {self.max_b:g} (the fit sits at or near its upper '
                    f'bound {FIT_B_MAX:g})')
        if not (p.size and math.isfinite(p_max)):
            return ''   # a report without its points: nothing more to check
        if self.max_abs_c_fraction is not None and not abs(law.c) <= self.max_abs_c_fraction * p_max:
            return (f'offset |c| {abs(law.c):.4g} kPa > max_abs_c_fraction {self.max_abs_c_fraction:g} '
                    f'* P_MAX ({self.max_abs_c_fraction * p_max:.4g} kPa)')
        step = float(np.median(np.diff(p))) if p.size >= 2 else p_max
        if self.max_dead_zone_deg is not None and angles.size:
            # Less than the first step by more than half a step: a law near P_1 at small angles
            # (a wearer who did not move at P_1, large b) is not a dead zone, whatever its angle.
            floor = float(p[0]) - DEAD_ZONE_SLACK_STEPS * step
            start = max(float(np.min(angles)), 0.0)
            dead = float(law.theta(floor, p_max)) - start
            if dead > self.max_dead_zone_deg:
                return (f'dead zone: the law commands less than {floor:.4g} kPa (the first step '
                        f'{p[0]:.4g} kPa - {DEAD_ZONE_SLACK_STEPS:g} step) up to {start + dead:.3g} deg, '
                        f'{dead:.3g} deg beyond the smallest angle measured > max_dead_zone_deg '
                        f'{self.max_dead_zone_deg:g} deg')
        if (self.max_negative_c_fraction is not None and self.max_dead_zone_deg is not None
                and law.c < -self.max_negative_c_fraction * p_max):
            # Without pressure the wearer is at rest: a law that commands nothing over more than
            # a few degrees fitted something else (a rest offset). A small b reaches 0 within a
            # fraction of a degree even with such a c: that is no dead zone.
            zero = float(law.theta(0.0, p_max))
            if zero > self.max_dead_zone_deg:
                return (f'dead zone from rest: offset c {law.c:.4g} kPa < -max_negative_c_fraction '
                        f'{self.max_negative_c_fraction:g} * P_MAX and the law commands nothing up to '
                        f'{zero:.3g} deg > max_dead_zone_deg {self.max_dead_zone_deg:g} deg')
        se = report.max_se_at_points_kpa
        if self.max_se_steps is not None and se is not None and p.size >= 2:
            if not se <= self.max_se_steps * step:
                return (f'uncertain: the fitted pressure at a measured angle has a standard error of '
                        f'{se:.3g} kPa > max_se_steps {self.max_se_steps:g} * step {step:.3g} kPa')
        return ''


#: The fit key of a direction a failed calibration never reached (CalibrationProcedure.attempt).
NOT_MEASURED = 'not_measured'


def _past(value: float, limit: float) -> str:
    """value in as few significant digits (3 or more) as read differently from limit as printed:
    a refusal never reads 'RMSE 37.5 kPa > max_rmse_kpa 37.5 kPa'."""
    for digits in range(3, 18):
        text = f'{value:.{digits}g}'
        if not math.isfinite(value) or float(text) != float(f'{limit:g}'):
            return text
    return text


#: How far below the first step's pressure the law must command to count as a dead zone, in
#: pressure steps (Acceptance.max_dead_zone_deg).
DEAD_ZONE_SLACK_STEPS = 0.5

#: Accept every fit the solver produced (the behaviour before fits were checked; for experiments).
ACCEPT_ALL = Acceptance(*[None] * 10)


@dataclass(frozen=True)
class DirectionCalibration:
    law: PowerLaw
    pressures: tuple[float, ...]  # kPa
    angles: tuple[float, ...]     # deg
    fit: Mapping                  # FitReport.as_dict()


@dataclass(frozen=True)
class Calibration:
    """A wearer's power laws, one per direction, with the points they came from."""

    wearer: str
    p_max: float
    directions: Mapping[str, DirectionCalibration]
    created: str = field(default_factory=lambda: datetime.now(timezone.utc).isoformat(timespec='seconds'))
    #: This wearer's own adjustment gain G (beyond the paper: its Discussion found the best G
    #: differed between subjects); None: use the controller's.
    adjustment_gain: float | None = None
    #: The wearer's rest gaze (unit vector, immersive frame, REP 103) that Algorithm 1 measured
    #: every angle from; the origin of Eq. 5's angles. None: not recorded (an older file).
    rest_gaze: tuple[float, float, float] | None = None

    def with_gain(self, gain: float | None) -> 'Calibration':
        """The same calibration with this wearer's own adjustment gain."""
        if gain is not None and not (math.isfinite(gain) and gain >= 0):
            raise ValueError(f'adjustment gain must be finite and >= 0, got {gain}')
        return Calibration(self.wearer, self.p_max, self.directions, self.created, gain,
                           self.rest_gaze)

    @property
    def origin(self) -> tuple[float, float, float]:
        """The origin of Eq. 5's angles: the rest gaze, or the front when none was recorded."""
        return self.rest_gaze if self.rest_gaze is not None else FRONT

    @property
    def origin_warning(self) -> str:
        """'' when the rest gaze was recorded, else the warning to show once."""
        if self.rest_gaze is not None:
            return ''
        return (f'calibration of {self.wearer!r} records no rest_gaze: angles are measured '
                f'from the front of the immersive frame {list(FRONT)}; recalibrate to record it')

    @property
    def laws(self) -> list[PowerLaw]:
        """Power laws in direction order (left, right, down, up)."""
        return [self.directions[d].law for d in DIRECTIONS]

    @classmethod
    def from_laws(cls, wearer: str, laws: Sequence[PowerLaw], p_max: float = PAPER_P_MAX) -> 'Calibration':
        """A calibration from known laws (no points): for defaults and simulation."""
        dirs = {d: DirectionCalibration(law, (), (), {}) for d, law in zip(DIRECTIONS, laws)}
        return cls(wearer, p_max, dirs)

    def to_dict(self) -> dict:
        return {
            'schema_version': SCHEMA_VERSION,
            'units': {'pressure': 'kPa', 'angle': 'deg'},
            'model': 'P = a * theta^b + c',
            'wearer': self.wearer,
            'created': self.created,
            'p_max_kpa': float(self.p_max),
            **({'adjustment_gain': float(self.adjustment_gain)} if self.adjustment_gain is not None else {}),
            **({'rest_gaze': [float(x) for x in self.rest_gaze]}
               if self.rest_gaze is not None else {}),
            'directions': {
                d: {
                    'a': c.law.a, 'b': c.law.b, 'c': c.law.c,
                    'points': {'pressure_kpa': [float(x) for x in c.pressures],
                               'angle_deg': [float(x) for x in c.angles]},
                    'fit': dict(c.fit),
                } for d, c in self.directions.items()
            },
        }

    def save(self, path: str | Path) -> Path:
        """Write atomically: readers see the old file or the new one, never a partial one."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        text = yaml.safe_dump(self.to_dict(), sort_keys=False, default_flow_style=None)
        return write_text(path, text)

    @classmethod
    def from_dict(cls, data, source: str = 'calibration') -> 'Calibration':
        def fail(fieldname: str, reason: str):
            raise CalibrationFileError(f'{source}: field "{fieldname}" {reason}')

        if not isinstance(data, Mapping):
            raise CalibrationFileError(f'{source}: expected a YAML mapping at the top level')
        if data.get('schema_version') != SCHEMA_VERSION:
            fail('schema_version', f'must be {SCHEMA_VERSION}, {got(data, "schema_version")}')
        units = data.get('units')
        if units != {'pressure': 'kPa', 'angle': 'deg'}:
            fail('units', f'must be {{pressure: kPa, angle: deg}}, {got(data, "units")}')
        wearer = data.get('wearer')
        if not isinstance(wearer, str) or not WEARER_PATTERN.fullmatch(wearer):
            fail('wearer', f'{WEARER_RULE}, {got(data, "wearer")}')
        p_max = data.get('p_max_kpa')
        if not (_number(p_max) and 0 < p_max <= P_MAX_LIMIT_KPA):
            fail('p_max_kpa', f'must be a number in (0, {P_MAX_LIMIT_KPA:g}] kPa, {got(data, "p_max_kpa")}')
        dirs = data.get('directions')
        if not isinstance(dirs, Mapping) or set(dirs) != set(DIRECTIONS):
            held = (f'got {excerpt(sorted(map(str, dirs)))}' if isinstance(dirs, Mapping)
                    else got(data, 'directions'))
            fail('directions', f'must hold exactly {list(DIRECTIONS)}, {held}')
        out = {}
        for d in DIRECTIONS:
            entry = dirs[d]
            if not isinstance(entry, Mapping):
                fail(f'directions.{d}', 'must be a mapping with a, b, c')
            for k in ('a', 'b', 'c'):
                if k not in entry:
                    fail(f'directions.{d}.{k}', 'is missing')
            try:
                law = PowerLaw(entry.get('a'), entry.get('b'), entry.get('c'))
            except (TypeError, ValueError) as exc:
                fail(f'directions.{d}', f'has unusable coefficients: {exc}')
            points = entry.get('points') or {}
            pressures = points.get('pressure_kpa', []) if isinstance(points, Mapping) else None
            angles = points.get('angle_deg', []) if isinstance(points, Mapping) else None
            if (not isinstance(pressures, list) or not isinstance(angles, list) or len(pressures) != len(angles)
                    or not all(_number(x) and 0 <= x <= p_max for x in pressures)
                    or not all(_number(x) and abs(x) <= ANGLE_LIMIT_DEG for x in angles)):
                fail(f'directions.{d}.points', 'must hold equal-length lists of pressure_kpa in [0, p_max_kpa] '
                     f'and angle_deg in [-{ANGLE_LIMIT_DEG:g}, {ANGLE_LIMIT_DEG:g}]')
            fit = entry.get('fit') or {}
            if not isinstance(fit, Mapping):
                fail(f'directions.{d}.fit', 'must be a mapping')
            out[d] = DirectionCalibration(law, tuple(map(float, pressures)), tuple(map(float, angles)), dict(fit))
        created = data.get('created', '')
        gain = data.get('adjustment_gain')
        if gain is not None and not (_number(gain) and 0 <= gain <= 1e6):
            fail('adjustment_gain', f'must be a finite number >= 0 when present, got {excerpt(gain)}')
        rest = data.get('rest_gaze')
        if rest is not None:
            if not isinstance(rest, list) or len(rest) != 3 or not all(_number(x) for x in rest):
                fail('rest_gaze', f'must be a list of 3 finite numbers (x, y, z) when present, '
                                  f'got {excerpt(rest)}')
            try:
                rest = tuple(float(x) for x in unit_vector(rest, 'rest_gaze'))
            except GeometryError as exc:
                fail('rest_gaze', f'is not a direction: {excerpt(str(exc))}')
        return cls(wearer, float(p_max), out, str(created),
                   None if gain is None else float(gain), rest)

    @classmethod
    def load(cls, path: str | Path) -> 'Calibration':
        return cls.from_dict(load_yaml(path, 'calibration file', CalibrationFileError), source=str(path))


#: CalibrationProcedure(rest_tolerance_deg=...): a direction's steps start only when the gaze at
#: the end of its rest is steady and within this of the first direction's rest gaze (deg; 2x
#: the HoloLens 2's 1.5 deg accuracy); otherwise the rest is repeated, up to MAX_REST_S in all,
#: and then the calibration fails. pressure_controller's default (calibration_rest_tolerance_deg);
#: the class's own default (None, no check) is the simulator engine's, whose scenes' calibrations
#: stay as they were fitted (docs/calibration.md).
REST_TOLERANCE_DEG = 3.0
MAX_REST_S = 30.0


def _angle_deg(u: np.ndarray, v: np.ndarray) -> float:
    """The angle between two directions (any length), degrees; 0 for a zero vector."""
    return math.degrees(math.atan2(float(np.linalg.norm(np.cross(u, v))), float(np.dot(u, v))))


# Phases of the procedure.
REST = 'rest'      # vented, wearer returns to face front; g0 is taken at its end
APPLY = 'apply'    # a pressure step is applied for a dwell; the angle is recorded at its end
DONE = 'done'
FAILED = 'failed'


@dataclass(frozen=True)
class CalibrationCommand:
    """What to do now: apply `pressure` (kPa) to `direction` (None: vent everything)."""

    phase: str
    direction: str | None
    pressure: float
    step: int          # 1-based step within the direction; 0 while resting
    progress: float    # 0..1 over the whole procedure


class CalibrationProcedure:
    """Algorithm 1, driven by tick(t, gaze). Times in seconds, pressures in kPa."""

    def __init__(self, wearer: str, p_max: float = PAPER_P_MAX, steps: int = PAPER_STEPS,
                 dwell_s: float = 3.0, rest_s: float = 3.0, record_window_s: float = 0.5,
                 directions: Sequence[str] = DIRECTIONS, first_pressure: float | None = None,
                 fit_tolerance: float = 1e-10, min_r2: float | None = None,
                 acceptance: Acceptance = Acceptance(), rest_tolerance_deg: float | None = None,
                 max_rest_s: float = MAX_REST_S):
        for name, value in (('dwell_s', dwell_s), ('rest_s', rest_s), ('record_window_s', record_window_s),
                            ('max_rest_s', max_rest_s), ('rest_tolerance_deg', rest_tolerance_deg or 0.0)):
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f'{name} must be finite and >= 0 s, got {value}')
        if record_window_s > dwell_s or record_window_s > rest_s:
            raise ValueError('record_window_s must not exceed dwell_s or rest_s')
        unknown = [d for d in directions if d not in DIRECTIONS]
        if unknown or not directions:
            raise ValueError(f'directions must be a non-empty subset of {DIRECTIONS}, got {list(directions)}')
        self.wearer = wearer
        self.p_max = float(p_max)
        self.schedule = pressure_schedule(p_max, steps, first_pressure)
        self.dwell_s, self.rest_s, self.window_s = dwell_s, rest_s, record_window_s
        self.directions = list(directions)
        self.fit_tolerance, self.min_r2 = fit_tolerance, min_r2
        self.acceptance = acceptance
        self.rest_tolerance_deg, self.max_rest_s = rest_tolerance_deg, max_rest_s
        self._rest_began: float | None = None   # when this direction's rest began (repeats included)
        self.fits: dict[str, FitReport] = {}
        #: direction -> why its fit was refused (the fit itself stays in `fits` for the report)
        self.refused: dict[str, str] = {}
        self.points: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self.error: str | None = None
        self._dir_index = 0
        self._step = 0           # 0: resting before the direction's first step
        self._phase_start: float | None = None
        self._g0: np.ndarray | None = None
        self._rests: list[np.ndarray] = []    # g0 of every direction: the rest gaze
        self._window: list[tuple[float, np.ndarray]] = []
        self._angles: list[float] = []
        self._phase = REST
        self._last_t: float | None = None

    @property
    def phase(self) -> str:
        return self._phase

    @property
    def direction(self) -> str | None:
        """The direction being calibrated, or rested for before its first step; None once ended."""
        return None if self._phase in (DONE, FAILED) else self.directions[self._dir_index]

    @property
    def duration_s(self) -> float:
        """Planned length of the whole procedure."""
        return len(self.directions) * (self.rest_s + len(self.schedule) * self.dwell_s)

    def _command(self, t: float) -> CalibrationCommand:
        if self._phase in (DONE, FAILED):
            return CalibrationCommand(self._phase, None, 0.0, 0, 1.0 if self._phase == DONE else self._progress(t))
        direction = self.directions[self._dir_index]
        pressure = 0.0 if self._phase == REST else float(self.schedule[self._step - 1])
        return CalibrationCommand(self._phase, direction if self._phase == APPLY else None, pressure,
                                  self._step, self._progress(t))

    def _progress(self, t: float) -> float:
        per_dir = self.rest_s + len(self.schedule) * self.dwell_s
        done = self._dir_index * per_dir + (self.rest_s + (self._step - 1) * self.dwell_s if self._step else 0.0)
        if self._phase_start is not None:
            limit = self.dwell_s if self._phase == APPLY else self.rest_s
            done += min(max(t - self._phase_start, 0.0), limit)
        return min(done / self.duration_s, 1.0) if self.duration_s > 0 else 1.0

    def fail(self, reason: str) -> CalibrationCommand:
        """Abort (e.g. the gaze went stale): vent, record the reason, write nothing."""
        self.error = reason
        self._phase = FAILED
        return CalibrationCommand(FAILED, None, 0.0, 0, 0.0)

    def tick(self, t: float, gaze: Sequence[float] | None) -> CalibrationCommand:
        """Advance to time t with the latest gaze direction (None: no valid gaze this tick)."""
        if self._phase in (DONE, FAILED):
            return self._command(t)
        if not math.isfinite(t):
            return self.fail(f'time is not finite: {t}')
        if self._last_t is not None and t < self._last_t:
            return self.fail('the clock jumped back during calibration')
        self._last_t = t
        if self._phase_start is None:
            self._phase_start = t
        if self._rest_began is None:
            self._rest_began = t
        if gaze is not None:
            try:
                self._window.append((t, unit_vector(gaze, 'gaze')))
            except GeometryError as exc:
                return self.fail(f'invalid gaze during calibration: {exc}')
        length = self.rest_s if self._phase == REST else self.dwell_s
        # Keep only the samples of the recording window at the end of this phase.
        self._window = [(ts, g) for ts, g in self._window if ts >= self._phase_start + length - self.window_s]
        if t - self._phase_start < length:
            return self._command(t)
        # The phase is over: record what it measured and move on.
        if not self._window:
            return self.fail(f'no gaze sample at the end of {self._phase} step {self._step} '
                             f'({self.directions[self._dir_index]})')
        try:
            if self._phase == REST:
                # Mean of unit vectors: a wearer looking about wildly at rest has no mean direction.
                samples = [g for _, g in self._window]
                g0 = np.mean(samples, axis=0)
                angles_between(g0, g0)
                away = self._away_from_rest(samples, g0)
                if away:
                    # Not back at rest: rest again rather than feed the fit a rest offset.
                    if t - self._rest_began + self.rest_s > self.max_rest_s:
                        return self.fail(f'{self.directions[self._dir_index]}: the gaze did not come back to '
                                         f'rest within {self.max_rest_s:g} s ({away})')
                    self._window = []
                    self._phase_start = t
                    return self._command(t)
                self._g0 = g0
                self._rests.append(g0)
                self._angles = []
            else:
                k = DIRECTIONS.index(self.directions[self._dir_index])
                reached = [angles_between(self._g0, g).by_direction()[k] for _, g in self._window]
                self._angles.append(float(np.median(reached)))
        except GeometryError as exc:
            return self.fail(f'no usable gaze direction at the end of {self._phase} step {self._step} '
                             f'({self.directions[self._dir_index]}): {exc}')
        self._window = []
        self._phase_start = t
        if self._step < len(self.schedule):
            self._step += 1
            self._phase = APPLY
            return self._command(t)
        return self._finish_direction(t)

    def _away_from_rest(self, samples: list, g0: np.ndarray) -> str:
        """'' when the rest window's gaze is steady and (after the first direction) within
        rest_tolerance_deg of the first direction's rest gaze; else how far it is."""
        tol = self.rest_tolerance_deg
        if tol is None:
            return ''
        half = len(samples) // 2
        if half:
            moved = _angle_deg(np.mean(samples[:half], axis=0), np.mean(samples[half:], axis=0))
            if moved > tol:
                return f'still moving: {moved:.3g} deg within the rest window > {tol:g} deg'
        if self._rests:
            off = _angle_deg(g0, self._rests[0])
            if off > tol:
                return f'{off:.3g} deg from the rest gaze > {tol:g} deg'
        return ''

    def _finish_direction(self, t: float) -> CalibrationCommand:
        direction = self.directions[self._dir_index]
        angles = np.array(self._angles)
        try:
            report = fit_power_law(angles, self.schedule, self.p_max, xtol=self.fit_tolerance,
                                   ftol=self.fit_tolerance, min_r2=self.min_r2)
        except CalibrationFitError as exc:
            self.points[direction] = (self.schedule.copy(), angles)
            return self.fail(f'{direction}: {exc}')
        self.fits[direction] = report
        self.points[direction] = (self.schedule.copy(), angles)
        why = self.acceptance.refusal(angles, report)
        if why:
            self.refused[direction] = why
            return self.fail(f'{direction}: fit refused: {why}')
        self._dir_index += 1
        self._step = 0
        self._rest_began = t
        if self._dir_index == len(self.directions):
            self._phase = DONE
        else:
            self._phase = REST
        return self._command(t)

    def attempt(self, base: Calibration | None = None) -> Calibration | None:
        """What was measured so far, refused fits included (marked `refused` in their fit), for
        the fit report of a calibration that failed; directions not fitted come from `base`, or
        are marked NOT_MEASURED (a first calibration); None when nothing was fitted."""
        dirs = dict(base.directions) if base is not None else {}
        for d, report in self.fits.items():
            p, a = self.points[d]
            fit = report.as_dict()
            if d in self.refused:
                fit['refused'] = self.refused[d]
            dirs[d] = DirectionCalibration(report.law, tuple(map(float, p)),
                                           tuple(map(float, a)), fit)
        if not self.fits:
            return None
        for d in DIRECTIONS:      # a placeholder law, never guided with: the report says so
            dirs.setdefault(d, DirectionCalibration(PowerLaw(1.0, 1.0, 0.0), (), (), {NOT_MEASURED: True}))
        return Calibration(self.wearer, self.p_max, {d: dirs[d] for d in DIRECTIONS})

    def result(self, base: Calibration | None = None) -> Calibration:
        """The calibration after DONE. Directions not calibrated now are taken from `base`."""
        if self._phase != DONE:
            raise CalibrationFitError(self.error or f'calibration is not finished (phase {self._phase})')
        dirs = dict(base.directions) if base is not None else {}
        for d, report in self.fits.items():
            p, a = self.points[d]
            dirs[d] = DirectionCalibration(report.law, tuple(map(float, p)), tuple(map(float, a)), report.as_dict())
        missing = [d for d in DIRECTIONS if d not in dirs]
        if missing:
            raise CalibrationFitError(f'directions {missing} were neither calibrated nor given by a base calibration')
        rest = np.mean(self._rests, axis=0)
        rest = tuple(float(x) for x in unit_vector(rest, 'rest gaze'))
        return Calibration(self.wearer, self.p_max, {d: dirs[d] for d in DIRECTIONS},
                           adjustment_gain=base.adjustment_gain if base is not None else None,
                           rest_gaze=rest)
