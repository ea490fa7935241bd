"""The four guidance conditions of the paper's experiments (its Table I)."""
from __future__ import annotations

from dataclasses import dataclass

from .feedback import ADJUSTED, FIXED


@dataclass(frozen=True)
class Condition:
    number: int
    name: str
    layout: str | None  # channel-map layout the pressures go to; None: no pressure
    mode: str | None    # feedback-law mode; None: no pressure
    speech: bool        # the direction is spoken once per target

    @property
    def haptic(self) -> bool:
        return self.layout is not None


CONDITIONS = {
    1: Condition(1, 'surface haptics, adjusted', 'suit', ADJUSTED, False),
    2: Condition(2, 'surface haptics, fixed', 'suit', FIXED, False),
    3: Condition(3, 'simple (arm) haptics, adjusted', 'arm', ADJUSTED, False),
    4: Condition(4, 'synthesized speech', None, None, True),
}


def condition(number: int) -> Condition:
    try:
        return CONDITIONS[int(number)]
    except (KeyError, ValueError, TypeError):
        raise ValueError(f'condition must be one of {sorted(CONDITIONS)}, got {number!r}') from None
