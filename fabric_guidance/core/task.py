"""The task protocol's acceptance test: a target counts as found when the gaze stays within
the acceptance angle of it (5 degrees in the paper's speed experiment) for a dwell time."""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from .geometry import unit_vector

#: The paper's acceptance angle, degrees.
PAPER_ACCEPTANCE_DEG = 5.0


def angular_error_deg(gaze: Sequence[float], target: Sequence[float]) -> float:
    """The full angle between two directions, degrees in [0, 180] (atan2 form: exact near 0)."""
    g = unit_vector(gaze, 'gaze direction')
    t = unit_vector(target, 'target direction')
    return math.degrees(math.atan2(float(np.linalg.norm(np.cross(g, t))), float(np.dot(g, t))))


class AcceptanceTracker:
    """Found once the error has stayed <= acceptance_deg for dwell_s seconds (0: at once)."""

    def __init__(self, acceptance_deg: float = PAPER_ACCEPTANCE_DEG, dwell_s: float = 0.0):
        if not (math.isfinite(acceptance_deg) and 0 < acceptance_deg <= 180):
            raise ValueError(f'acceptance_deg must be in (0, 180], got {acceptance_deg}')
        if not (math.isfinite(dwell_s) and dwell_s >= 0):
            raise ValueError(f'dwell_s must be finite and >= 0, got {dwell_s}')
        self.acceptance_deg, self.dwell_s = acceptance_deg, dwell_s
        self._inside_since: float | None = None

    def reset(self) -> None:
        self._inside_since = None

    def update(self, gaze: Sequence[float], target: Sequence[float], t: float) -> bool:
        """True when the target counts as found at time t."""
        if angular_error_deg(gaze, target) > self.acceptance_deg:
            self._inside_since = None
            return False
        if self._inside_since is None or t < self._inside_since:  # a clock jump back restarts the dwell
            self._inside_since = t
        return t - self._inside_since >= self.dwell_s
