"""Settings of the sweep: the knobs, their grids, the reference values, the scenes it runs on."""
from __future__ import annotations

from dataclasses import dataclass, field, replace
import math

from ...core.feedback import RATE_THRESHOLD_DPS
from ...sim.scene import AccuracyProtocol, Scene, SpeedProtocol, load_scene


#: The scenes both the sweep and the sensitivity analysis run on by default: the one place to
#: switch them (e.g. to the fitted scenes).
DEFAULT_SPEED_SCENE = 'paper-fitted-speed'
DEFAULT_ACCURACY_SCENE = 'paper-fitted-accuracy'

KNOBS = ('acceptance_tolerance', 'gain', 'calibration_points', 'control_rate', 'rate_threshold',
         'fit_tolerance')
#: The paper's conditions drawn on the plane, at the package defaults.
PLANE_CONDITIONS = (1, 2, 3, 4)
CONDITION_LABELS = {1: '1 suit, adjusted', 2: '2 suit, fixed', 3: '3 arm band, adjusted',
                    4: '4 speech'}

DEFAULT_GRIDS = {
    'acceptance_tolerance': (2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0),
    'gain': (0.0, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5),
    'calibration_points': (3, 4, 5, 6, 8, 10, 12, 15, 20),
    'control_rate': (5.0, 10.0, 15.0, 20.0, 30.0, 45.0, 60.0),
    'rate_threshold': (3.0, 7.0, RATE_THRESHOLD_DPS, 30.0, 60.0, 120.0),
    'fit_tolerance': (1e-2, 1e-3, 1e-4, 1e-6, 1e-8, 1e-10, 1e-12),
}
QUICK_GRIDS = {
    'acceptance_tolerance': (2.0, 5.0, 10.0),
    'gain': (0.0, 0.05, 0.5),
    'calibration_points': (3, 10, 20),
    'control_rate': (5.0, 30.0, 60.0),
    'rate_threshold': (3.0, RATE_THRESHOLD_DPS, 60.0),
    'fit_tolerance': (1e-2, 1e-6, 1e-10),
}
#: The value the package runs with, and where it comes from.
REFERENCE = {'acceptance_tolerance': (5.0, 'the paper'), 'gain': (0.05, 'the paper'),
             'calibration_points': (10, 'the paper'), 'control_rate': (30.0, 'node default'),
             'rate_threshold': (RATE_THRESHOLD_DPS, 'core default'),
             'fit_tolerance': (1e-10, 'core default'),
             # not a knob: the plane's conditions have no package value to mark
             'condition': (math.nan, '')}
KNOB_TITLES = {'acceptance_tolerance': 'acceptance tolerance (deg)', 'gain': 'adjustment gain G (Eq. 5)',
               'calibration_points': 'calibration points per direction (Algorithm 1)',
               'control_rate': 'control rate (Hz)',
               'rate_threshold': 'rate threshold of the feedback law (deg/s)',
               'fit_tolerance': 'fit tolerance (LM xtol = ftol)',
               'condition': 'the paper\'s condition'}
KNOB_SYMBOLS = {'acceptance_tolerance': 'tolerance', 'gain': 'G', 'calibration_points': 'points',
                'control_rate': 'rate', 'rate_threshold': 'threshold', 'fit_tolerance': 'tol',
                'condition': 'condition'}
METRICS = {
    'guidance_error_deg': ('guidance error (deg, accuracy protocol)', 'deg'),
    'error_at_count_deg': ('gaze error when a target counts (deg, speed protocol)', 'deg'),
    'law_angle_error_deg': ('fitted law angle error vs true law (deg)', 'deg'),
    'fit_vs_converged_deg': ('fitted law angle error vs converged fit (deg)', 'deg'),
    'time_to_key_press_s': ('time to the key press (s)', 's'),
    'time_to_find_s': ('time to find a target (s)', 's'),
    'calibration_time_s': ('calibration time (s)', 's'),
    'fit_time_ms': ('fit wall time (ms per fit)', 'ms'),
}
CSV_COLUMNS = ('knob', 'value', 'accuracy_metric', 'accuracy_mean', 'accuracy_sd', 'accuracy_p10', 'accuracy_p90',
               'accuracy_se', 'time_metric', 'time_mean', 'time_sd', 'time_p10', 'time_p90',
               'time_se', 'n',
               'n_time', 'wearers', 'plane', 'note')


@dataclass(frozen=True)
class Settings:
    subjects: int = 10                  # the first N wearers of each scene's population
    repetitions: int = 10               # accuracy-protocol trials per wearer and value (the paper: 10)
    speed_repetitions: int = 3          # 40 s speed-protocol trials per wearer and value
    condition: int = 1                  # the paper's condition 1: suit, adjusted
    workers: int = 2
    accuracy_scene: str = DEFAULT_ACCURACY_SCENE
    speed_scene: str = DEFAULT_SPEED_SCENE
    knobs: tuple[str, ...] = KNOBS
    grids: dict = field(default_factory=lambda: dict(DEFAULT_GRIDS))
    fit_repeats: int = 15               # timed calls per fit and tolerance (the fastest is kept)
    trial_s: float | None = None        # speed trials' length; None: the scene's (the paper: 40 s)
    quick: bool = False
    plane: bool = True                  # run conditions 1-4 and both protocols per knob value


def quick_settings(**changes) -> Settings:
    """A tiny sweep (2 wearers, 3 values per knob, short trials) for tests and a first look."""
    base = dict(subjects=2, repetitions=2, speed_repetitions=1, grids=dict(QUICK_GRIDS), fit_repeats=3,
                trial_s=20.0, quick=True)
    base.update(changes)
    return Settings(**base)


def as_protocol(scene: Scene, kind: str) -> Scene:
    """The scene with a protocol of `kind`: its own, or that protocol's defaults (the paper's)."""
    if scene.protocol.kind == kind:
        return scene
    return scene.replace(protocol=AccuracyProtocol() if kind == 'accuracy' else SpeedProtocol(),
                         repetitions=scene.repetitions)


def base_scenes(settings: Settings) -> tuple[Scene, Scene]:
    """(accuracy scene, speed scene) restricted to the sweep's condition and repetitions."""
    acc = as_protocol(load_scene(settings.accuracy_scene), 'accuracy')
    spd = as_protocol(load_scene(settings.speed_scene), 'speed')
    # The plane puts one protocol's time against the other's error: both run on the same
    # wearers (the speed scene's seed and population; common random numbers), which also lets
    # the two share every calibration when the scenes list the same effects.
    acc = acc.replace(seed=spd.seed, population=spd.population)
    acc = acc.replace(conditions=(settings.condition,), repetitions=settings.repetitions)
    spd = spd.replace(conditions=(settings.condition,), repetitions=settings.speed_repetitions)
    if settings.trial_s is not None:
        spd = spd.replace(protocol=replace(spd.protocol, trial_s=float(settings.trial_s)))
    for s in (acc, spd):
        if not 1 <= settings.subjects <= s.population.subjects:
            raise ValueError(f'--subjects must be within 1..{s.population.subjects} (scene {s.name}), '
                             f'got {settings.subjects}')
    return acc, spd


def check_settings(settings: Settings, acc: Scene) -> None:
    unknown = [k for k in settings.knobs if k not in KNOBS]
    if unknown or not settings.knobs:
        raise ValueError(f'unknown knob(s) {unknown}; valid: {", ".join(KNOBS)}')
    if settings.condition not in (1, 2, 3):
        raise ValueError(f'condition must be 1, 2 or 3 (a haptic condition), got {settings.condition}')
    for name, n in (('repetitions', settings.repetitions), ('speed repetitions', settings.speed_repetitions),
                    ('workers', settings.workers), ('fit repeats', settings.fit_repeats)):
        if not (isinstance(n, int) and n >= 1):
            raise ValueError(f'{name} must be a whole number >= 1, got {n!r}')
    g = settings.grids
    checks = {
        'acceptance_tolerance': lambda v: 0 < v <= 180, 'gain': lambda v: 0 <= v <= 10,
        'calibration_points': lambda v: float(v).is_integer() and 3 <= v <= 50,
        'control_rate': lambda v: 0 < v <= acc.sim_rate_hz, 'fit_tolerance': lambda v: 1e-15 < v < 1,
        'rate_threshold': lambda v: 0 < v <= 1000,
    }
    for k in settings.knobs:
        values = g.get(k, ())
        if not values:
            raise ValueError(f'knob {k}: empty grid')
        bad = [v for v in values if not (isinstance(v, (int, float)) and math.isfinite(v) and checks[k](v))]
        if bad:
            extra = f' (the control rate cannot exceed the scene\'s sim_rate_hz {acc.sim_rate_hz:g})' \
                if k == 'control_rate' else ''
            raise ValueError(f'knob {k}: values out of range: {bad}{extra}')
