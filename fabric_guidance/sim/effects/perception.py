"""Stages `percept` and `delay`: the wearer's perception of the pressure (weber_perception) and
their reaction time (reaction_delay)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from .base import Effect, RunContext, param


@dataclass
class WeberPerception(Effect):
    """The wearer's percept of each direction's pressure changes only when the pressure has
    changed by more than the Weber fraction of the current percept (perception is relative:
    the paper's Discussion, citing Weber).

    fraction (-, default 0.14): the just-noticeable relative change. Where from: the classic
    textbook table of Weber fractions (Teghtsoonian 1971, as reproduced in Coren, Ward & Enns,
    Sensation and Perception) gives about 0.14 for pressure on the skin; force and pressure
    discrimination studies report 0.07-0.2. A fabric suit pulling the torso was never measured:
    the value is that human-factors figure, not a measurement of this suit.

    From a percept of 0 any non-zero pressure is noticed (the threshold of feeling anything is
    the wearer's own c of their power law).
    """

    name: ClassVar[str] = 'weber_perception'
    stage: ClassVar[str] = 'percept'

    fraction: float = param(0.14, '-', lo=0.0, hi=10.0)

    def start(self, ctx: RunContext) -> None:
        self.out = [0.0, 0.0, 0.0, 0.0]

    def percept(self, p: list) -> list:
        out, w = self.out, self.fraction
        for k in range(4):
            x, q = p[k], out[k]
            if abs(x - q) > w * q:
                out[k] = x
        return out


@dataclass
class ReactionDelay(Effect):
    """The wearer acts on the percept of `delay` ago: each wearer has their own delay, drawn
    once per wearer from N(mean_s, sd_s) (floored at 0) and rounded to whole simulation steps.

    mean_s (s, default 0.25): simple reaction time to a touch stimulus is about 0.15-0.3 s in
    the human-factors literature; choosing a direction from it (choice reaction) takes longer,
    so a scene may well set more. sd_s (s, default 0.05): between-person spread of that order
    (an assumption). The same delay applies to the spoken phrase of condition 4 (after it has
    been heard: see speech_latency).
    """

    name: ClassVar[str] = 'reaction_delay'
    stage: ClassVar[str] = 'delay'
    stochastic: ClassVar[bool] = True

    mean_s: float = param(0.25, 's', lo=0.0)
    sd_s: float = param(0.05, 's', lo=0.0)

    def start(self, ctx: RunContext) -> None:
        draw = float(ctx.wearer_rng(self.name).standard_normal())
        self.delay_s = max(0.0, self.mean_s + self.sd_s * draw)
        self.steps = int(round(self.delay_s / ctx.dt))
        self._buf: list = []
        self._i = 0

    def reset(self, rest) -> None:
        """Fill the history with the percept of rest (what was felt before the run)."""
        self._buf = [rest] * self.steps
        self._i = 0

    def delay(self, percept):
        if not self.steps:
            return percept
        buf, i = self._buf, self._i
        out = buf[i]
        buf[i] = percept
        self._i = i + 1 if i + 1 < self.steps else 0
        return out
