"""Scene files: what a simulated experiment runs (config/scenes/*.yaml).

A scene names its protocol and parameters, the conditions, the repetitions, the population of
simulated wearers, the controller and calibration settings, the simulation rate and the
explicit list of effects to simulate. load_scene() reads and validates a file into frozen
dataclasses; every error is a SceneError naming the file and the field at fault.

    name: paper-speed
    seed: 2025
    protocol: {kind: speed, trial_s: 40, acceptance_deg: 5, dwell_s: 0.3,
               horizontal_deg: 60, vertical_deg: 30}
    conditions: [1, 2, 3, 4]
    repetitions: 6                      # default: the protocol's (speed 6, accuracy 10)
    population:
      subjects: 15
      laws:                             # each direction's nominal (median) law P = a*theta^b + c
        left: {a: 20.0, b: 0.65, c: 25.0}
        right: {a: 22.0, b: 0.62, c: 20.0}
        down: {a: 40.0, b: 0.55, c: 30.0}
        up: {a: 38.0, b: 0.58, c: 35.0}
      spread: {a: 0.3, b: 0.1, c: 0.3}  # relative lognormal sigma of each coefficient
      arm_spread: 0.0                   # the arm's own law vs the suit's (condition 3)
      traits:                           # effect parameters that differ between people
        movement: {sd: 0.2, scale: log, params: [body_dynamics.torso_tau_s, body_dynamics.head_tau_s]}
    controller: {gain: 0.05, control_rate_hz: 30, p_max_kpa: 375, gaze_timeout_s: 0.3}
    calibration: {steps: 10, dwell_s: 3.0, rest_s: 3.0, window_s: 0.5}
    sim_rate_hz: 60
    effects:
      - regulator_lag: {tau_s: 0.15}
      - body_dynamics                   # a bare name: the effect with its defaults
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields, make_dataclass, replace
import math
from pathlib import Path
from typing import Any, Mapping, Sequence

from ..core.safe_input import excerpt, load_yaml
from ..core.conditions import CONDITIONS
from ..core.controller_parameters import SCENE as SCENE_PARAMETERS, default, renamed
from ..core.geometry import DIRECTIONS
from ..core.power_law import PowerLaw
from ..paths import config_path
from .effects import REGISTRY, Effect, EffectError, make_effect
from .effects.base import logit_shifted


class SceneError(ValueError):
    """A scene that cannot be used, naming the file, the field and the reason (also kept apart,
    so that a command can name its own option for a field it set)."""

    def __init__(self, message: str, field: str = '', reason: str = ''):
        super().__init__(message)
        self.field, self.reason = field, reason


# ---------------------------------------------------------------------------------------------
# Sections


def _num(default, unit: str, lo=None, hi=None, lo_open=False, integer=False, optional=False):
    return field(default=default, metadata={'unit': unit, 'lo': lo, 'hi': hi, 'lo_open': lo_open,
                                            'integer': integer, 'optional': optional})


def _choice(default: str, choices: Sequence[str]):
    return field(default=default, metadata={'choices': tuple(choices)})


@dataclass(frozen=True)
class SpeedProtocol:
    """The paper's speed experiment: find as many targets as possible in trial_s."""

    kind = 'speed'
    default_repetitions = 6          # the paper: six trials per condition

    trial_s: float = _num(40.0, 's', lo=0.0, lo_open=True)              # the paper: 40 s
    acceptance_deg: float = _num(5.0, 'deg', lo=0.0, hi=180.0, lo_open=True)  # the paper: 5 deg
    dwell_s: float = _num(0.3, 's', lo=0.0)        # assumption: time to confirm and press the key
    horizontal_deg: float = _num(60.0, 'deg', lo=0.0, hi=170.0)         # the paper: +-60 deg
    vertical_deg: float = _num(30.0, 'deg', lo=0.0, hi=80.0)            # the paper: +-30 deg


@dataclass(frozen=True)
class AccuracyProtocol:
    """The paper's accuracy experiment: one random target per trial, the key pressed when the
    wearer believes they are aligned."""

    kind = 'accuracy'
    default_repetitions = 10         # the paper: ten trials per condition

    horizontal_deg: float = _num(60.0, 'deg', lo=0.0, hi=170.0)         # the paper: +-60 deg
    vertical_deg: float = _num(30.0, 'deg', lo=0.0, hi=80.0)            # the paper: +-30 deg
    settle_speed_dps: float = _num(1.0, 'deg/s', lo=0.0, lo_open=True)  # assumption: "still"
    settle_s: float = _num(0.5, 's', lo=0.0)                           # assumption: for this long
    timeout_s: float = _num(15.0, 's', lo=0.0, lo_open=True)            # assumption: gives up


PROTOCOLS = {cls.kind: cls for cls in (SpeedProtocol, AccuracyProtocol)}


#: How a trait moves its parameters: on the log scale (a positive value times exp(u)) or on the
#: logit scale (a probability, logit(p) + u).
TRAIT_SCALES = ('log', 'logit')


@dataclass(frozen=True)
class TraitSpec:
    """A way people differ, fixed for each wearer over all their trials: u ~ N(0, sd) per wearer
    (its own random stream), added to every listed effect parameter on the trait's scale; the
    scene's value is the population's median. `params` are 'effect.parameter' names."""

    name: str
    sd: float
    scale: str
    params: tuple[str, ...]
    source: str = ''

    def apply(self, value: float, u: float) -> float:
        """One wearer's value of a parameter whose median is `value`. A value at the end of its
        scale (0; a probability of 0 or 1: a sweep may set one) is the same for everyone."""
        if self.scale == 'log':
            return value * math.exp(u) if value > 0 else value
        return logit_shifted(value, u)


@dataclass(frozen=True)
class PopulationSpec:
    """Simulated wearers: each direction's nominal law, sampled per wearer with a relative
    lognormal spread (median = nominal). arm_spread: the arm muscles' law (condition 3) is the
    suit's law with a multiplied by exp(N(0, arm_spread)) per direction; 0 = the same law.
    traits: effect parameters that differ between people (TraitSpec)."""

    subjects: int = 15
    laws: tuple[PowerLaw, ...] = ()
    spread: tuple[float, float, float] = (0.0, 0.0, 0.0)
    arm_spread: float = 0.0
    traits: tuple[TraitSpec, ...] = ()

    def trait(self, name: str) -> TraitSpec | None:
        return next((tr for tr in self.traits if tr.name == name), None)

    def law(self, direction: str) -> PowerLaw:
        return self.laws[DIRECTIONS.index(direction)]


def _table_field(p):
    """A scene field of a controller parameter (core/controller_parameters.py): its default,
    unit, range and choices."""
    if p.choices:
        return p.name, str, _choice(p.default, p.choices)
    return p.name, p.type, _num(p.default, p.unit, lo=p.low, hi=p.high, lo_open=p.low_open,
                                integer=p.type is int)


#: A scene's controller section: the controller parameters the simulator honours (the table's
#: scene entries, core/controller_parameters.py), with their defaults and ranges.
ControllerSpec = make_dataclass('ControllerSpec', [_table_field(p) for p in SCENE_PARAMETERS],
                                frozen=True)
ControllerSpec.__module__ = __name__


@dataclass(frozen=True)
class CalibrationSpec:
    """Algorithm 1 as the pressure_controller node runs it. exact: skip it and give the
    controller the wearer's true suit law (an oracle, for tests and for separating calibration
    error from guidance error)."""

    # The node's defaults (core/controller_parameters.py calibration_*); the paper: 10 steps.
    steps: int = _num(default('calibration_steps'), '-', lo=3, hi=50, integer=True)
    dwell_s: float = _num(default('calibration_dwell_s'), 's', lo=0.0, lo_open=True)
    rest_s: float = _num(default('calibration_rest_s'), 's', lo=0.0, lo_open=True)
    window_s: float = _num(default('calibration_window_s'), 's', lo=0.0, lo_open=True)
    min_r2: float | None = _num(None, '-', lo=-1e9, hi=1.0, optional=True)
    exact: bool = False


@dataclass(frozen=True)
class EffectSpec:
    """One entry of the scene's effect list: a registered name and its parameters."""

    name: str
    params: tuple[tuple[str, Any], ...] = ()

    @property
    def params_dict(self) -> dict:
        return dict(self.params)

    def build(self, overrides: Mapping | None = None) -> Effect:
        """The effect with the scene's parameters, `overrides` (one wearer's traits) over them."""
        return make_effect(self.name, {**self.params_dict, **(overrides or {})})


@dataclass(frozen=True)
class Scene:
    name: str
    seed: int
    protocol: SpeedProtocol | AccuracyProtocol
    conditions: tuple[int, ...]
    repetitions: int
    population: PopulationSpec
    controller: ControllerSpec = ControllerSpec()
    calibration: CalibrationSpec = CalibrationSpec()
    sim_rate_hz: float = 60.0
    effects: tuple[EffectSpec, ...] = ()
    source: str = '<scene>'

    @property
    def effect_names(self) -> tuple[str, ...]:
        return tuple(e.name for e in self.effects)

    def effect(self, name: str) -> EffectSpec | None:
        for e in self.effects:
            if e.name == name:
                return e
        return None

    def with_effects(self, effects) -> 'Scene':
        """The same scene with another effect list (same forms as the file's `effects:`)."""
        return replace(self, effects=_parse_effects(effects, self.source))

    def replace(self, **changes) -> 'Scene':
        return replace(self, **changes)

    def with_value(self, key: str, value) -> 'Scene':
        """The same scene with one number changed, named by its path in a scene file:
        'controller.gain', 'calibration.steps', 'protocol.acceptance_deg',
        'population.spread.a', 'population.arm_spread', 'population.traits.<trait>.sd' or
        '<effect>.<parameter>' (an effect the
        scene lists). The knobs of the trade-off and the sensitivity analysis change scenes
        through this. KeyError for a path the scene has not."""
        section, _, name = key.partition('.')
        if section in ('controller', 'calibration', 'protocol'):
            part = getattr(self, section)
            f = next((f for f in fields(part) if f.name == name), None)
            if f is None:
                raise KeyError(f'{key}: {section} has no field {name!r}')
            if 'unit' in f.metadata:    # a number: of the field's kind, as a scene file gives it
                value = int(value) if f.metadata.get('integer') else float(value)
            return replace(self, **{section: replace(part, **{name: value})})
        if section == 'population':
            pop = self.population
            if name == 'arm_spread':
                return replace(self, population=replace(pop, arm_spread=value))
            if name.startswith('traits.') and name.endswith('.sd'):
                trait = name[len('traits.'):-len('.sd')]
                if pop.trait(trait) is None:
                    raise KeyError(f'{key}: the population has no trait {trait!r}')
                traits = tuple(replace(tr, sd=float(value)) if tr.name == trait else tr for tr in pop.traits)
                return replace(self, population=replace(pop, traits=traits))
            coef = name.rpartition('.')[2]
            if not name.startswith('spread.') or coef not in 'abc' or len(coef) != 1:
                raise KeyError(f'{key}: population has spread.a, spread.b, spread.c and arm_spread')
            spread = list(pop.spread)
            spread['abc'.index(coef)] = value
            return replace(self, population=replace(pop, spread=tuple(spread)))
        if self.effect(section) is None:
            raise KeyError(f'{key}: the scene lists no effect {section!r}')
        effects = []
        for e in self.effects:
            params = e.params_dict
            if e.name == section:
                params[name] = value
            effects.append({e.name: params})
        return self.with_effects(effects)


# ---------------------------------------------------------------------------------------------
# Parsing


def _fail(source: str, where: str, reason: str):
    raise SceneError(f'{source}: field "{where}" {reason}', where, reason)


def _number(value, source: str, where: str, meta: Mapping) -> float | int | None:
    if value is None and meta.get('optional'):
        return None
    if value is None:
        _fail(source, where, 'is missing')
    unit = meta.get('unit', '')
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        _fail(source, where, f'must be a number ({unit}), got {excerpt(value)}')
    if meta.get('integer'):
        if isinstance(value, float) and not value.is_integer():
            _fail(source, where, f'must be a whole number, got {excerpt(value)}')
        value = int(value)
    elif not math.isfinite(value):
        _fail(source, where, f'must be finite, got {excerpt(value)}')
    lo, hi = meta.get('lo'), meta.get('hi')
    if lo is not None and (value <= lo if meta.get('lo_open') else value < lo):
        _fail(source, where, f'must be {">" if meta.get("lo_open") else ">="} {lo:g} {unit}, got {excerpt(value)}')
    if hi is not None and value > hi:
        _fail(source, where, f'must be <= {hi:g} {unit}, got {excerpt(value)}')
    return value if meta.get('integer') else float(value)


def _mapping(value, source: str, where: str) -> Mapping:
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        _fail(source, where, f'must be a mapping, got {type(value).__name__}')
    return value


def _section(cls, data, source: str, where: str, **extra):
    """A dataclass section from a mapping: unknown keys are errors, numbers are checked."""
    data = _mapping(data, source, where)
    names = [f.name for f in fields(cls) if f.name not in extra]
    unknown = sorted(set(data) - set(names))
    if unknown:
        _fail(source, f'{where}.{unknown[0]}', f'is not a parameter of {where}; valid: {", ".join(names)}')
    kwargs = dict(extra)
    for f in fields(cls):
        if f.name in extra or f.name not in data:
            continue
        value = data[f.name]
        if 'choices' in f.metadata:
            if value not in f.metadata['choices']:
                choices = list(f.metadata['choices'])
                _fail(source, f'{where}.{f.name}', f'must be one of {choices}, got {value!r}')
            kwargs[f.name] = value
        elif f.type in ('bool', bool):
            if not isinstance(value, bool):
                _fail(source, f'{where}.{f.name}', f'must be true or false, got {excerpt(value)}')
            kwargs[f.name] = value
        else:
            kwargs[f.name] = _number(value, source, f'{where}.{f.name}', f.metadata)
    return cls(**kwargs)


def _parse_protocol(data, source: str):
    data = dict(_mapping(data, source, 'protocol'))
    if not data:
        _fail(source, 'protocol', f'is required: a mapping with kind ({" | ".join(PROTOCOLS)}) and its parameters')
    kind = data.pop('kind', None)
    if kind not in PROTOCOLS:
        _fail(source, 'protocol.kind', f'must be one of {list(PROTOCOLS)}, got {excerpt(kind)}')
    return _section(PROTOCOLS[kind], data, source, 'protocol')


def _parse_law(data, source: str, where: str) -> PowerLaw:
    data = _mapping(data, source, where)
    missing = [k for k in ('a', 'b', 'c') if k not in data]
    if missing:
        _fail(source, f'{where}.{missing[0]}', 'is missing')
    if set(data) != {'a', 'b', 'c'}:
        _fail(source, where, f'must give exactly a, b and c, got {excerpt(sorted(data))}')
    vals = [_number(data[k], source, f'{where}.{k}', {'unit': u}) for k, u in
            (('a', 'kPa/deg^b'), ('b', '-'), ('c', 'kPa'))]
    try:
        return PowerLaw(*vals)
    except ValueError as exc:
        _fail(source, where, f'is not a usable power law: {exc}')


def _parse_population(data, source: str) -> PopulationSpec:
    data = _mapping(data, source, 'population')
    valid = ('subjects', 'laws', 'spread', 'arm_spread', 'traits')
    unknown = sorted(set(data) - set(valid))
    if unknown:
        _fail(source, f'population.{unknown[0]}', f'is not a parameter of population; valid: {", ".join(valid)}')
    subjects = _number(data.get('subjects', 15), source, 'population.subjects',
                       {'unit': 'wearers', 'lo': 1, 'hi': 10000, 'integer': True})
    laws_data = data.get('laws')
    if laws_data is None:
        _fail(source, 'population.laws', f'is missing (a law a, b, c for each of {list(DIRECTIONS)})')
    if not isinstance(laws_data, Mapping) or set(laws_data) != set(DIRECTIONS):
        got = sorted(laws_data) if isinstance(laws_data, Mapping) else laws_data
        _fail(source, 'population.laws', f'must give a law for exactly {list(DIRECTIONS)}, got {excerpt(got)}')
    laws = tuple(_parse_law(laws_data[d], source, f'population.laws.{d}') for d in DIRECTIONS)
    spread_data = _mapping(data.get('spread'), source, 'population.spread')
    unknown = sorted(set(spread_data) - {'a', 'b', 'c'})
    if unknown:
        _fail(source, f'population.spread.{unknown[0]}', 'is not a coefficient; valid: a, b, c')
    spread = tuple(_number(spread_data.get(k, 0.0), source, f'population.spread.{k}',
                           {'unit': '(log) -', 'lo': 0.0, 'hi': 3.0}) for k in 'abc')
    arm = _number(data.get('arm_spread', 0.0), source, 'population.arm_spread', {'unit': '(log) -', 'lo': 0.0,
                                                                                 'hi': 3.0})
    traits = _parse_traits(data.get('traits'), source)
    return PopulationSpec(subjects, laws, spread, arm, traits)


def _parse_traits(data, source: str) -> tuple[TraitSpec, ...]:
    """population.traits: name -> {sd, scale, params: [effect.parameter, ...], source}. The
    parameters are checked against the effects once those are read (_check_traits)."""
    out = []
    for name, entry in _mapping(data, source, 'population.traits').items():
        where = f'population.traits.{name}'
        entry = _mapping(entry, source, where)
        unknown = sorted(set(entry) - {'sd', 'scale', 'params', 'source'})
        if unknown:
            _fail(source, f'{where}.{unknown[0]}', 'is not a field of a trait; valid: sd, scale, params, source')
        sd = _number(entry.get('sd'), source, f'{where}.sd', {'unit': '-', 'lo': 0.0, 'hi': 5.0})
        scale = entry.get('scale', 'log')
        if scale not in TRAIT_SCALES:
            _fail(source, f'{where}.scale', f'must be one of {", ".join(TRAIT_SCALES)}, got {excerpt(scale)}')
        params = entry.get('params')
        if (not isinstance(params, Sequence) or isinstance(params, str) or not params
                or not all(isinstance(q, str) and q.count('.') == 1 for q in params)):
            _fail(source, f'{where}.params', f'must list effect.parameter names, got {excerpt(params)}')
        out.append(TraitSpec(str(name), float(sd), scale, tuple(params), str(entry.get('source', ''))))
    return tuple(out)


def _check_traits(traits, effects, source: str) -> None:
    """Every trait parameter names a listed effect's number whose scene value suits the scale;
    no parameter belongs to two traits."""
    seen = {}
    for tr in traits:
        for q in tr.params:
            where = f'population.traits.{tr.name}.params'
            effect, _, param = q.partition('.')
            spec = next((e for e in effects if e.name == effect), None)
            if spec is None:
                _fail(source, where, f'names {q!r}, but the scene lists no effect {effect!r}')
            effect_obj = spec.build()
            value = getattr(effect_obj, param) if param in effect_obj.parameters() else None
            if not isinstance(value, (int, float)) or isinstance(value, bool):
                _fail(source, where, f'names {q!r}, which is not a number of {effect}')
            ok = value > 0 if tr.scale == 'log' else 0 < value < 1
            if not ok:
                _fail(source, where, f'{q} = {value:g} cannot vary on the {tr.scale} scale '
                                     f'({"> 0" if tr.scale == "log" else "0 < p < 1"} needed)')
            # Two traits on one parameter add on its scale: only on the same scale.
            if q in seen and seen[q][1] != tr.scale:
                _fail(source, where, f'{q} is already varied by trait {seen[q][0]!r} on the {seen[q][1]} '
                                     f'scale, not {tr.scale}')
            seen[q] = (tr.name, tr.scale)


def _parse_effects(data, source: str) -> tuple[EffectSpec, ...]:
    if data is None:
        return ()
    if not isinstance(data, Sequence) or isinstance(data, (str, bytes)):
        _fail(source, 'effects', 'must be a list of effect names or {name: {parameters}} entries')
    out, seen = [], set()
    for i, entry in enumerate(data):
        where = f'effects[{i}]'
        if isinstance(entry, str):
            name, params = entry, {}
        elif isinstance(entry, Mapping) and len(entry) == 1:
            name, params = next(iter(entry.items()))
            params = params if params is not None else {}
            if not isinstance(params, Mapping):
                _fail(source, f'{where}.{name}', f'must map parameter names to values, got {excerpt(params)}')
        elif isinstance(entry, EffectSpec):
            name, params = entry.name, entry.params_dict
        else:
            _fail(source, where, 'must be an effect name or a single {name: {parameters}} mapping, '
                                 f'got {excerpt(entry)}')
        if name not in REGISTRY:
            _fail(source, where, f'names unknown effect {excerpt(name)}; valid effects: {", ".join(sorted(REGISTRY))}')
        if name in seen:
            _fail(source, where, f'lists effect {excerpt(name)} a second time')
        seen.add(name)
        try:
            make_effect(name, params)   # validates names and values of the parameters
        except EffectError as exc:
            _fail(source, f'{where}.{name}', str(exc))
        out.append(EffectSpec(name, tuple(sorted(params.items()))))
    return tuple(out)


TOP_LEVEL = ('name', 'seed', 'protocol', 'conditions', 'repetitions', 'population', 'controller', 'calibration',
             'sim_rate_hz', 'effects')


def scene_from_dict(data, source: str = '<scene>') -> Scene:
    """A validated Scene from the mapping of a scene file."""
    if not isinstance(data, Mapping):
        raise SceneError(f'{source}: expected a YAML mapping at the top level')
    unknown = sorted(set(data) - set(TOP_LEVEL))
    if unknown:
        _fail(source, unknown[0], f'is not a scene field; valid: {", ".join(TOP_LEVEL)}')
    name = data.get('name')
    if not isinstance(name, str) or not name:
        _fail(source, 'name', 'must be a non-empty string')
    seed = data.get('seed')
    if seed is None:
        _fail(source, 'seed', "is missing (a whole number >= 0: the run's random seed)")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        _fail(source, 'seed', f'must be a whole number >= 0, got {excerpt(seed)}')
    protocol = _parse_protocol(data.get('protocol'), source)
    conds = data.get('conditions', [1, 2, 3, 4])
    if (not isinstance(conds, Sequence) or isinstance(conds, str) or not conds
            or not all(isinstance(c, int) and not isinstance(c, bool) and c in CONDITIONS for c in conds)
            or len(set(conds)) != len(conds)):
        _fail(source, 'conditions', f'must be a non-empty list of distinct conditions from {sorted(CONDITIONS)}, '
                                    f'got {excerpt(conds)}')
    reps = _number(data.get('repetitions', protocol.default_repetitions), source, 'repetitions',
                   {'unit': 'trials', 'lo': 1, 'hi': 10000, 'integer': True})
    population = _parse_population(data.get('population'), source)
    controller_data = data.get('controller')
    if isinstance(controller_data, Mapping):
        try:   # a renamed key: read under its new name, with one warning naming the file
            controller_data = renamed(controller_data, f'{source}: controller')
        except ValueError as exc:
            raise SceneError(str(exc)) from None
    controller = _section(ControllerSpec, controller_data, source, 'controller')
    calibration = _section(CalibrationSpec, data.get('calibration'), source, 'calibration')
    if calibration.window_s > min(calibration.dwell_s, calibration.rest_s):
        _fail(source, 'calibration.window_s', 'must not exceed calibration.dwell_s or calibration.rest_s')
    sim_rate = _number(data.get('sim_rate_hz', 60.0), source, 'sim_rate_hz',
                       {'unit': 'Hz', 'lo': 1.0, 'hi': 10000.0})
    if controller.control_rate_hz > sim_rate:
        _fail(source, 'controller.control_rate_hz', f'must not exceed sim_rate_hz ({sim_rate:g} Hz)')
    effects = _parse_effects(data.get('effects'), source)
    _check_traits(population.traits, effects, source)
    return Scene(name, seed, protocol, tuple(conds), reps, population, controller, calibration, sim_rate, effects,
                 source)


def scene_path(name_or_path: str | Path) -> Path:
    """A path as given, or the package's config/scenes/<name>.yaml for a bare name."""
    path = Path(name_or_path).expanduser()
    if path.suffix in ('.yaml', '.yml') or path.exists():
        return path
    return config_path(f'scenes/{name_or_path}.yaml')


def scene_names() -> list[str]:
    """The names of the package's scenes (config/scenes/*.yaml)."""
    return sorted(p.stem for p in config_path('scenes').glob('*.yaml'))


def load_scene(name_or_path: str | Path) -> Scene:
    """Read and validate a scene file (a path, or the name of one of config/scenes/)."""
    path = scene_path(name_or_path)
    if not path.exists() and path.parent == config_path('scenes') and Path(name_or_path).name == str(name_or_path):
        import difflib
        names = scene_names()
        close = difflib.get_close_matches(str(name_or_path), names, n=1)
        raise SceneError(f'no scene named {str(name_or_path)!r}' + (f' (did you mean {close[0]}?)' if close else '')
                         + f'; the package\'s scenes: {", ".join(names)}; or give the path of a .yaml file')
    return scene_from_dict(load_yaml(path, 'scene', SceneError), source=str(path))


__all__ = ['AccuracyProtocol', 'CalibrationSpec', 'ControllerSpec', 'EffectSpec', 'PROTOCOLS', 'PopulationSpec',
           'Scene', 'SceneError', 'SpeedProtocol', 'load_scene', 'scene_from_dict', 'scene_names', 'scene_path']
