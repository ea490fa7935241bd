"""Simulated wearers of a scene: their own power laws, sampled around the scene's nominal laws,
and each one's calibration by Algorithm 1 in the simulation, as in the paper.

Wearer i's laws depend only on (scene seed, i) and the population section, not on how many
wearers the scene has or which ones run: wearer 3 is the same person in a 5- and a 15-wearer
scene. Per direction k and coefficient x in (a, b, c): x_k = nominal x_k * exp(sigma_x * z),
z ~ N(0, 1) (lognormal, median = nominal). The arm law of condition 3 is the suit law with a
multiplied by exp(arm_spread * z') per direction: the arm's muscles are never calibrated
(the paper uses the suit's f_k in condition 3), so how far their sensation differs is a
property of the wearer that the controller does not know.

Traits (population.traits, sim.scene.TraitSpec): wearer i's value of a trait is u = sd * z,
z ~ N(0, 1) from the trait's own stream (scene seed, 'trait.<name>', i), so adding a trait or
changing one's sd leaves every other draw as it was; it moves each listed effect parameter on
the trait's scale (two traits on one parameter add, in the order listed), and the effects of
all the wearer's runs start with those values.

calibrate_wearer() runs Algorithm 1 with the scene's effects (engine.run_calibration); a wearer
whose calibration fails is not an error: the outcome records the reason and the protocol
excludes the wearer.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields
import math
from typing import Iterable

import numpy as np

from ..core.calibration import Calibration
from ..core.geometry import DIRECTIONS
from ..core.power_law import PowerLaw
from .effects import effect_class, generator
from .engine import run_calibration

#: Angle range over which a fitted law is compared with the true one (the paper's +-60 deg).
COMPARE_DEG = 60.0


@dataclass(frozen=True)
class WearerSpec:
    """One simulated wearer: index in the scene, a name (S01...), their laws per direction
    (left, right, down, up) for the suit and for the arm muscles; `error` when the sampled law
    is not usable (the wearer is then excluded)."""

    index: int
    name: str
    suit_laws: tuple[PowerLaw, ...]
    arm_laws: tuple[PowerLaw, ...]
    error: str | None = None
    #: trait name -> the wearer's u (on the trait's scale; 0 is the population's median)
    traits: dict = field(default_factory=dict)
    #: effect -> {parameter: this wearer's value}, from the traits
    effect_params: dict = field(default_factory=dict)


def wearer_name(index: int) -> str:
    return f'S{index + 1:02d}'


def sample_wearer(scene, index: int) -> WearerSpec:
    """Wearer `index` of the scene's population (deterministic in seed and index)."""
    pop = scene.population
    z = generator(scene.seed, 'population', index).standard_normal((len(DIRECTIONS), 4))
    sa, sb, sc = pop.spread
    suit, arm = [], []
    try:
        for k, nominal in enumerate(pop.laws):
            law = PowerLaw(nominal.a * math.exp(sa * z[k, 0]), nominal.b * math.exp(sb * z[k, 1]),
                           nominal.c * math.exp(sc * z[k, 2]))
            suit.append(law)
            arm.append(PowerLaw(law.a * math.exp(pop.arm_spread * z[k, 3]), law.b, law.c))
    except ValueError as exc:
        nominal_laws = tuple(pop.laws)
        return WearerSpec(index, wearer_name(index), nominal_laws, nominal_laws,
                          f'sampled power law is not usable: {exc}')
    traits, params = wearer_traits(scene, index)
    return WearerSpec(index, wearer_name(index), tuple(suit), tuple(arm), None, traits, params)


def wearer_traits(scene, index: int) -> tuple[dict, dict]:
    """(trait -> u, effect -> {parameter: value}) of wearer `index` (see the module docstring)."""
    traits, params = {}, {}
    for tr in scene.population.traits:
        u = tr.sd * float(generator(scene.seed, f'trait.{tr.name}', index).standard_normal())
        traits[tr.name] = u
        for q in tr.params:
            effect, _, name = q.partition('.')
            spec = scene.effect(effect)
            if spec is None:        # an effect taken out of the scene (a sweep): nothing to vary
                continue
            # Two traits on one parameter add on its scale (each moves the value the other left).
            value = params.get(effect, {}).get(name)
            if value is None:
                value = spec.params_dict.get(name, spec.build().parameters()[name][0])
            params.setdefault(effect, {})[name] = _within_range(effect, name, tr.apply(float(value), u))
    return traits, params


def _within_range(effect: str, name: str, value: float) -> float:
    """A trait's value clipped to the effect parameter's valid range (direction_p at most 0.5:
    someone who misreads more often than not reads the other way)."""
    meta = next(f.metadata for f in fields(effect_class(effect)) if f.name == name)
    lo, hi = meta.get('lo'), meta.get('hi')
    if hi is not None and value > hi:
        return float(hi)
    if lo is not None and value < lo:
        return float(lo)
    return value


def sample_population(scene, subjects: Iterable[int] | int | None = None) -> list[WearerSpec]:
    """The scene's wearers (all, the first n, or the given indices)."""
    return [sample_wearer(scene, i) for i in subject_indices(scene, subjects)]


def subject_indices(scene, subjects: Iterable[int] | int | None = None) -> list[int]:
    n = scene.population.subjects
    if subjects is None:
        return list(range(n))
    if isinstance(subjects, (int, np.integer)) and not isinstance(subjects, bool):
        if not 1 <= subjects <= n:
            raise ValueError(f'subjects must be within 1..{n} (the scene has {n}), got {subjects}')
        return list(range(int(subjects)))
    out = sorted({int(s) for s in subjects})
    bad = [s for s in out if not 0 <= s < n]
    if bad or not out:
        raise ValueError(f'subject indices must be within 0..{n - 1}, got {sorted(subjects)}')
    return out


def law_error_kpa(true: PowerLaw, fitted: PowerLaw, theta_max: float = COMPARE_DEG) -> float:
    """Largest pressure difference between two laws over 0..theta_max degrees, kPa."""
    th = np.linspace(0.0, theta_max, 121)
    return float(np.max(np.abs(true.pressure(th) - fitted.pressure(th))))


def law_angle_error_deg(true: PowerLaw, fitted: PowerLaw, p_max: float, theta_max: float = COMPARE_DEG) -> float:
    """Largest angle error of the fitted law over 0..theta_max: for each angle, the pressure the
    fit commands for it, and the angle that pressure means to the wearer (true inverse)."""
    th = np.linspace(0.0, theta_max, 121)
    reached = true.theta(np.minimum(fitted.pressure(th), p_max), p_max)
    return float(np.max(np.abs(reached - np.minimum(th, true.theta(p_max, p_max)))))


@dataclass(frozen=True)
class CalibrationOutcome:
    """A wearer's calibration in the simulation: the Calibration, or the reason it failed."""

    subject: int
    wearer: str
    calibration: Calibration | None
    error: str | None = None
    #: direction -> largest |fitted - true| pressure over 0-60 deg, kPa
    law_error_kpa: dict | None = None
    #: direction -> largest angle error the fit causes over 0-60 deg (true wearer), deg
    angle_error_deg: dict | None = None

    @property
    def ok(self) -> bool:
        return self.calibration is not None


def calibrate_wearer(scene, wearer: WearerSpec) -> CalibrationOutcome:
    """Algorithm 1 on the wearer in the simulation, with the scene's effects."""
    if wearer.error:
        return CalibrationOutcome(wearer.index, wearer.name, None, wearer.error)
    try:
        cal = run_calibration(scene, wearer, wearer.name)
    except ValueError as exc:   # CalibrationFitError, or a geometry/procedure error
        return CalibrationOutcome(wearer.index, wearer.name, None, f'calibration failed: {exc}')
    p_max = scene.controller.p_max_kpa
    kpa = {d: law_error_kpa(t, f) for d, t, f in zip(DIRECTIONS, wearer.suit_laws, cal.laws)}
    deg = {d: law_angle_error_deg(t, f, p_max) for d, t, f in zip(DIRECTIONS, wearer.suit_laws, cal.laws)}
    return CalibrationOutcome(wearer.index, wearer.name, cal, None, kpa, deg)


__all__ = ['COMPARE_DEG', 'CalibrationOutcome', 'WearerSpec', 'calibrate_wearer', 'law_angle_error_deg',
           'law_error_kpa', 'sample_population', 'sample_wearer', 'subject_indices', 'wearer_name',
           'wearer_traits']
