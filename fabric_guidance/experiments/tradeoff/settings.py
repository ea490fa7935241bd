"""Settings of the sweep: the knobs, their grids, the reference values, the scenes it runs on."""
from __future__ import annotations

from dataclasses import dataclass, field, replace
import math
from typing import Callable
import warnings

from ...core.controller_parameters import default
from ...sim.scene import AccuracyProtocol, Scene, SpeedProtocol, load_scene


#: The scenes both the sweep and the sensitivity analysis run on by default: the one place to
#: switch them (e.g. to the fitted scenes).
DEFAULT_SPEED_SCENE = 'paper-fitted-speed'
DEFAULT_ACCURACY_SCENE = 'paper-fitted-accuracy'

#: The paper's conditions drawn on the plane, at the package defaults.
PLANE_CONDITIONS = (1, 2, 3, 4)
CONDITION_LABELS = {1: '1 suit, adjusted', 2: '2 suit, fixed', 3: '3 arm band, adjusted',
                    4: '4 speech'}


@dataclass(frozen=True)
class Knob:
    """One knob of the sweep: what it changes, its unit, the values it runs, the package's value."""
    name: str
    title: str
    symbol: str
    unit: str
    grid: tuple
    quick_grid: tuple
    reference: float
    source: str
    #: The values it can take (checked before a sweep runs); `acc` is the accuracy scene.
    valid: Callable[[float, Scene], bool]
    #: What the sweep measures at each value: SPEED (the speed protocol only), BOTH protocols,
    #: ACCURACY (the accuracy protocol), CALIBRATION (Algorithm 1's cost and the accuracy it
    #: buys) or FIT (the fit alone, on the accuracy scene's calibrations).
    measures: str
    #: What it changes: the value's path in a scene file (Scene.with_value); '' for a knob that
    #: is not a scene setting (fit_tolerance: the fit's own tolerance).
    key: str = ''
    #: A note for the accuracy row (scene at the value, value), or None.
    note: Callable[[Scene, float], str] | None = None

    def vary(self, scene: Scene, value: float) -> Scene:
        """The scene with this knob at `value`."""
        return scene.with_value(self.key, value)


SPEED, BOTH, ACCURACY, CALIBRATION, FIT = 'speed', 'both', 'accuracy', 'calibration', 'fit'


_THRESHOLD = default('rate_threshold_dps')
#: Every knob, in the sweep's order: the one table the settings, the sweep, the report, the
#: plots and the reading take their facts from.
KNOB_TABLE: tuple[Knob, ...] = (
    Knob('acceptance_deg', 'acceptance tolerance (deg)', 'tolerance', 'deg',
         (2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0), (2.0, 5.0, 10.0), 5.0, 'the paper',
         lambda v, acc: 0 < v <= 180, SPEED, 'protocol.acceptance_deg'),
    Knob('gain', 'adjustment gain G (Eq. 5)', 'G', '-', (0.0, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5), (0.0, 0.05, 0.5),
         default('gain'), 'the paper', lambda v, acc: 0 <= v <= 10, BOTH, 'controller.gain'),
    Knob('calibration_steps', 'calibration points per direction (Algorithm 1)', 'points', '-',
         (3, 4, 5, 6, 8, 10, 12, 15, 20), (3, 10, 20), default('calibration_steps'), 'the paper',
         lambda v, acc: float(v).is_integer() and 3 <= v <= 50, CALIBRATION, 'calibration.steps'),
    Knob('control_rate_hz', 'control rate (Hz)', 'rate', 'Hz', (5.0, 10.0, 15.0, 20.0, 30.0, 45.0, 60.0),
         (5.0, 30.0, 60.0), default('control_rate_hz'), 'node default',
         lambda v, acc: 0 < v <= acc.sim_rate_hz, ACCURACY, 'controller.control_rate_hz',
         lambda scene, v: f'G x rate = {scene.controller.gain * float(v):.3g} per s'),
    Knob('rate_threshold_dps', 'rate threshold of the feedback law (deg/s)', 'threshold', 'deg/s',
         (3.0, 7.0, _THRESHOLD, 30.0, 60.0, 120.0), (3.0, _THRESHOLD, 60.0), _THRESHOLD, 'core default',
         lambda v, acc: 0 < v <= 1000, BOTH, 'controller.rate_threshold_dps'),
    Knob('fit_tolerance', 'fit tolerance (xtol = ftol)', 'tol', '-',
         (1e-2, 1e-3, 1e-4, 1e-6, 1e-8, 1e-10, 1e-12), (1e-2, 1e-6, 1e-10), 1e-10, 'core default',
         lambda v, acc: 1e-15 < v < 1, FIT),
)
KNOB: dict[str, Knob] = {k.name: k for k in KNOB_TABLE}

KNOBS = tuple(KNOB)
#: Knob names before they were the parameters' own: still read, with one warning.
OLD_KNOB_NAMES = {'acceptance_tolerance': 'acceptance_deg', 'calibration_points': 'calibration_steps',
                  'control_rate': 'control_rate_hz', 'rate_threshold': 'rate_threshold_dps'}
DEFAULT_GRIDS = {k.name: k.grid for k in KNOB_TABLE}
QUICK_GRIDS = {k.name: k.quick_grid for k in KNOB_TABLE}
#: The value the package runs with, and where it comes from (the plane's conditions have none).
REFERENCE = {**{k.name: (k.reference, k.source) for k in KNOB_TABLE}, 'condition': (math.nan, '')}
KNOB_TITLES = {**{k.name: k.title for k in KNOB_TABLE}, 'condition': "the paper's condition"}
KNOB_SYMBOLS = {**{k.name: k.symbol for k in KNOB_TABLE}, 'condition': 'condition'}
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
    seed: int | None = None             # the wearers, targets and noise; None: the speed scene's
    #: (scene path, value) pairs set in both scenes where they apply (a variant of the fitted
    #: parameters, intervals.read_variants)
    overrides: tuple = ()

    def __post_init__(self):
        # An old knob name (in knobs or grids) is read as its new one, with one warning each.
        old = [k for k in dict.fromkeys(tuple(self.knobs) + tuple(self.grids)) if k in OLD_KNOB_NAMES]
        for k in old:
            warnings.warn(f'tradeoff: knob "{k}" is deprecated, read as "{OLD_KNOB_NAMES[k]}"; rename it',
                          FutureWarning, stacklevel=3)
        if old:
            object.__setattr__(self, 'knobs', tuple(OLD_KNOB_NAMES.get(k, k) for k in self.knobs))
            object.__setattr__(self, 'grids', {OLD_KNOB_NAMES.get(k, k): v for k, v in self.grids.items()})


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


def paired_scenes(speed_scene: str, accuracy_scene: str, speed_conditions, accuracy_conditions,
                  speed_repetitions: int, repetitions: int, trial_s: float | None,
                  subjects: int) -> tuple[Scene, Scene]:
    """(speed scene, accuracy scene) of the sweep and of the sensitivity analysis: each with its
    protocol, conditions and repetitions, on the same wearers; trial_s: the speed trials' length
    (None: the scene's)."""
    spd = as_protocol(load_scene(speed_scene), 'speed')
    acc = as_protocol(load_scene(accuracy_scene), 'accuracy')
    # The plane puts one protocol's time against the other's error: both run on the same
    # wearers (the speed scene's seed and population; common random numbers), which also lets
    # the two share every calibration when the scenes list the same effects.
    acc = acc.replace(seed=spd.seed, population=spd.population)
    acc = acc.replace(conditions=tuple(accuracy_conditions), repetitions=repetitions)
    spd = spd.replace(conditions=tuple(speed_conditions), repetitions=speed_repetitions)
    if trial_s is not None:
        spd = spd.replace(protocol=replace(spd.protocol, trial_s=float(trial_s)))
    if not 1 <= subjects <= spd.population.subjects:
        raise ValueError(f'--subjects must be within 1..{spd.population.subjects} (scene {spd.name}), '
                         f'got {subjects}')
    return spd, acc


def base_scenes(settings: Settings) -> tuple[Scene, Scene]:
    """(accuracy scene, speed scene) restricted to the sweep's condition and repetitions, at the
    settings' seed and with its overrides."""
    spd, acc = paired_scenes(settings.speed_scene, settings.accuracy_scene, (settings.condition,),
                             (settings.condition,), settings.speed_repetitions, settings.repetitions,
                             settings.trial_s, settings.subjects)
    if settings.seed is not None:
        spd, acc = spd.replace(seed=settings.seed), acc.replace(seed=settings.seed)
    spd, acc = override(spd, acc, settings.overrides)
    return acc, spd


def override(spd: Scene, acc: Scene, overrides) -> tuple[Scene, Scene]:
    """Both scenes with every (path, value) of `overrides` set where the scene has the path (an
    effect or a protocol field only one scene has is set there); ValueError naming the path
    when neither scene has it or the value is not valid there."""
    for key, value in overrides:
        scenes, missing = [], []
        for scene in (spd, acc):
            try:
                scene = scene.with_value(key, value)
            except KeyError as exc:
                missing.append(str(exc.args[0] if exc.args else exc))
            except ValueError as exc:
                raise ValueError(f'{key} = {value!r}: {exc}') from None
            scenes.append(scene)
        if len(missing) == 2:
            raise ValueError(f'{missing[0]} (nor does {acc.name})')
        spd, acc = scenes
    return spd, acc


def check_settings(settings: Settings, acc: Scene) -> None:
    unknown = [k for k in settings.knobs if k not in KNOBS]
    if unknown or not (settings.knobs or settings.plane):
        raise ValueError(f'unknown knob(s) {unknown}; valid: {", ".join(KNOBS)}')
    if settings.condition not in (1, 2, 3):
        raise ValueError(f'condition must be 1, 2 or 3 (a haptic condition), got {settings.condition}')
    for name, n in (('repetitions', settings.repetitions), ('speed repetitions', settings.speed_repetitions),
                    ('workers', settings.workers), ('fit repeats', settings.fit_repeats)):
        if not (isinstance(n, int) and n >= 1):
            raise ValueError(f'{name} must be a whole number >= 1, got {n!r}')
    g = settings.grids
    for k in settings.knobs:
        values = g.get(k, ())
        if not values:
            raise ValueError(f'knob {k}: empty grid')
        bad = [v for v in values if not (isinstance(v, (int, float)) and math.isfinite(v) and KNOB[k].valid(v, acc))]
        if bad:
            extra = f' (the control rate cannot exceed the scene\'s sim_rate_hz {acc.sim_rate_hz:g})' \
                if k == 'control_rate_hz' else ''
            raise ValueError(f'knob {k}: values out of range: {bad}{extra}')
