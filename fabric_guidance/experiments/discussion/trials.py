"""What seeds a trial of the two Discussion studies (per_wearer_gain.py, moving_targets.py):
the condition they run in and TrialKey, the phase and repetition that key a trial's targets and
effect streams.

Random numbers: a trial is a pure function of (scene, wearer, phase, repetition, and its
settings); arms compared with each other share targets and effect streams (common random
numbers), so they differ only by the controller.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...sim.effects import generator
from ...sim.engine import trial_run
from ...sim.protocols import target_stream
from ...sim.scene import Scene

#: The condition the gain and the moving-target laws are studied in (suit, adjusted).
CONDITION = 1

# Run-key stages of the studies (engine.trial_run uses stage 2, engine.CALIBRATION_RUN stage 1).
_TUNING_STAGE = 11
_MOVING_STAGE = 12


@dataclass(frozen=True)
class TrialKey:
    """phase 'evaluation': the paper-speed protocol's own condition-1 trial of that repetition
    (protocols' target stream, engine.trial_run); 'tuning': a stream of its own and run stage
    11; 'moving': its own stream and stage 12."""

    phase: str
    repetition: int

    def __post_init__(self):
        if self.phase not in ('tuning', 'evaluation', 'moving'):
            raise ValueError(f'unknown phase {self.phase!r}')
        if not (isinstance(self.repetition, (int, np.integer)) and self.repetition >= 0):
            raise ValueError(f'repetition must be a whole number >= 0, got {self.repetition!r}')

    @property
    def run(self) -> tuple[int, ...]:
        if self.phase == 'evaluation':
            return trial_run(CONDITION, self.repetition)
        if self.phase == 'tuning':
            return (_TUNING_STAGE, CONDITION, int(self.repetition))
        return (_MOVING_STAGE, CONDITION, int(self.repetition))

    @property
    def target_stream(self) -> tuple[str, tuple[int, ...]]:
        """(stream name, key) of the targets generator (with the scene seed and the wearer)."""
        if self.phase == 'evaluation':
            return ('targets', (int(self.repetition),))          # protocols.target_stream
        return (f'beyond-{self.phase}-targets', (int(self.repetition),))

    def targets(self, scene: Scene, subject: int) -> np.random.Generator:
        if self.phase == 'evaluation':
            return target_stream(scene, subject, self.repetition)
        name, key = self.target_stream
        return generator(scene.seed, name, subject, key)


def tuning_keys(reps: int) -> list[TrialKey]:
    return [TrialKey('tuning', r) for r in range(reps)]


def evaluation_keys(reps: int) -> list[TrialKey]:
    return [TrialKey('evaluation', r) for r in range(reps)]


__all__ = ['CONDITION', 'TrialKey', 'evaluation_keys', 'tuning_keys']
