"""The base of every effect: its random streams, its run context, its parameters' checks and
the Effect class (sim/effects/__init__.py has the picture of where each stage acts)."""
from __future__ import annotations

from dataclasses import dataclass, field, fields
import math
from typing import ClassVar
import zlib

import numpy as np

#: Stages of the loop, in the order the engine applies them within a step.
STAGES = ('pressure', 'percept', 'delay', 'body', 'gaze', 'speech', 'cue', 'view')

#: Random numbers drawn per refill of an effect's buffer (drawing one by one is slow).
_BLOCK = 512


class EffectError(ValueError):
    """An effect name or parameter that cannot be used; the message names the field."""


# ---------------------------------------------------------------------------------------------
# Random streams


def logit_shifted(p: float, u: float) -> float:
    """p moved by u on the logit scale; a probability at an end of the scale (0 or 1) stays."""
    if not 0.0 < p < 1.0:
        return p
    return 1.0 / (1.0 + math.exp(-(math.log(p / (1.0 - p)) + u)))


def stream_key(name: str) -> int:
    """A stable 32-bit number for a name (crc32: the same in every process and version)."""
    return zlib.crc32(name.encode('utf-8'))


def seed_sequence(seed: int, name: str, wearer: int, run: tuple[int, ...] = ()) -> np.random.SeedSequence:
    """The seed sequence of stream `name` for one wearer (and one run of that wearer).

    run = () keys what is drawn once per wearer (their reaction time, their laws); a run key
    (stage, condition, repetition) keys what is drawn during one run.
    """
    return np.random.SeedSequence(entropy=int(seed), spawn_key=(stream_key(name), int(wearer)) + tuple(run))


def generator(seed: int, name: str, wearer: int, run: tuple[int, ...] = ()) -> np.random.Generator:
    return np.random.Generator(np.random.PCG64(seed_sequence(seed, name, wearer, run)))


class Draws:
    """Values from one generator, one at a time, drawn in blocks (the values are the same as
    drawing them one by one would give for standard_normal / random)."""

    __slots__ = ('_gen', '_kind', '_buf', '_i')

    def __init__(self, gen: np.random.Generator, kind: str = 'normal'):
        if kind not in ('normal', 'uniform'):
            raise ValueError(f'unknown draw kind {kind!r}')
        self._gen, self._kind, self._buf, self._i = gen, kind, [], 0

    def next(self) -> float:
        i = self._i
        if i == len(self._buf):
            arr = self._gen.standard_normal(_BLOCK) if self._kind == 'normal' else self._gen.random(_BLOCK)
            self._buf, i = arr.tolist(), 0
        self._i = i + 1
        return self._buf[i]


@dataclass(frozen=True)
class RunContext:
    """What an effect needs to start a run: the step and its random streams.

    rng(): the effect's Generator for this run; wearer_rng(): its Generator for this wearer,
    the same in every run (for per-wearer traits such as a reaction time).
    """

    dt: float
    seed: int
    wearer: int
    run: tuple[int, ...]

    def rng(self, name: str) -> np.random.Generator:
        return generator(self.seed, name, self.wearer, self.run)

    def wearer_rng(self, name: str) -> np.random.Generator:
        return generator(self.seed, name, self.wearer)


# ---------------------------------------------------------------------------------------------
# Parameter checks


def param(default, unit: str, lo: float | None = None, hi: float | None = None, lo_open: bool = False,
          optional: bool = False):
    return field(default=default, metadata={'unit': unit, 'lo': lo, 'hi': hi, 'lo_open': lo_open,
                                            'optional': optional})


def _check_fields(effect) -> None:
    for f in fields(effect):
        value = getattr(effect, f.name)
        meta = f.metadata
        where = f'{effect.name}.{f.name}'
        if value is None and meta.get('optional'):
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise EffectError(f'{where} must be a number ({meta.get("unit")}), got {value!r}')
        value = float(value)
        if not math.isfinite(value):
            raise EffectError(f'{where} must be finite, got {value}')
        lo, hi = meta.get('lo'), meta.get('hi')
        if lo is not None and (value <= lo if meta.get('lo_open') else value < lo):
            raise EffectError(f'{where} must be {">" if meta.get("lo_open") else ">="} {lo:g} {meta.get("unit")}, '
                              f'got {value:g}')
        if hi is not None and value > hi:
            raise EffectError(f'{where} must be <= {hi:g} {meta.get("unit")}, got {value:g}')
        object.__setattr__(effect, f.name, value)


class Effect:
    """Base of the effects: a dataclass of parameters; start() makes the per-run state."""

    name: ClassVar[str]
    stage: ClassVar[str]
    #: Order within the stage (physical order: a tracker adds noise before the network loses it).
    order: ClassVar[int] = 0
    stochastic: ClassVar[bool] = False

    def __post_init__(self) -> None:
        _check_fields(self)
        self.validate()

    def validate(self) -> None:
        """Checks across parameters; raise EffectError naming the field."""

    def start(self, ctx: RunContext) -> None:
        """Reset the state for a new run."""

    @classmethod
    def parameters(cls) -> dict[str, tuple[object, str]]:
        """name -> (default, unit)."""
        return {f.name: (f.default, f.metadata.get('unit', '')) for f in fields(cls)}
