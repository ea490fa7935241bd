"""A small, deterministic simulated wearer.

The wearer reads the suit's pressure per direction (left, right, down, up), interprets it
through their own power law (their sensitivity, which the calibration has to discover) as an
angle to turn, and turns torso and gaze toward it as a first-order lag. The turn is relative
to the posture they held when the suit started pulling (the anchor); while they feel nothing
(every pressure below their threshold c) they hold still. Gaze = torso (no separate eye or head movement in this model).

No noise and no delays here: the effects a scene calls for come in their own modules.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..core.feedback import PAPER_P_MAX
from ..core.geometry import DIRECTIONS
from ..core.power_law import PowerLaw


def gaze_from_angles(yaw_deg: float, pitch_deg: float) -> np.ndarray:
    """Unit gaze direction in REP 103 from yaw (positive left) and pitch (positive up)."""
    y, p = math.radians(yaw_deg), math.radians(pitch_deg)
    return np.array([math.cos(p) * math.cos(y), math.cos(p) * math.sin(y), math.sin(p)])


class SimulatedWearer:
    def __init__(self, laws: Sequence[PowerLaw], tau_s: float = 0.4, p_max: float = PAPER_P_MAX,
                 yaw_deg: float = 0.0, pitch_deg: float = 0.0):
        if len(laws) != len(DIRECTIONS):
            raise ValueError(f'need one power law per direction {DIRECTIONS}')
        if not (math.isfinite(tau_s) and tau_s > 0):
            raise ValueError(f'tau_s must be finite and > 0, got {tau_s}')
        self.laws, self.tau_s, self.p_max = list(laws), tau_s, p_max
        self.yaw, self.pitch = yaw_deg, pitch_deg
        self._anchor: tuple[float, float] | None = None

    @property
    def gaze(self) -> np.ndarray:
        return gaze_from_angles(self.yaw, self.pitch)

    def face_front(self) -> None:
        """Be back at the starting posture at once."""
        self.yaw = self.pitch = 0.0
        self._anchor = None

    def return_to_front(self, dt: float) -> np.ndarray:
        """Turn back toward the front on one's own, ignoring the suit, as the paper's wearers
        did between targets; same dynamics as a guided turn."""
        self._anchor = None
        alpha = 1.0 - math.exp(-max(dt, 0.0) / self.tau_s)
        self.yaw -= alpha * self.yaw
        self.pitch -= alpha * self.pitch
        return self.gaze

    def perceived_angles(self, pressures: Sequence[float]) -> np.ndarray:
        """The angle each direction's pressure means to this wearer, degrees."""
        return np.array([law.theta(p, self.p_max) for law, p in zip(self.laws, pressures)])

    def step(self, pressures: Sequence[float], dt: float) -> np.ndarray:
        """Advance dt seconds under direction pressures (kPa); return the new gaze."""
        p = np.nan_to_num(np.asarray(pressures, dtype=float), nan=0.0)
        perceived = self.perceived_angles(p)
        if not np.any(perceived > 0):
            # Nothing felt (every pressure below the wearer's threshold c): hold still, and the
            # next pull counts from here.
            self._anchor = None
            return self.gaze
        if self._anchor is None:
            self._anchor = (self.yaw, self.pitch)
        left, right, down, up = perceived
        goal_yaw = self._anchor[0] + left - right
        goal_pitch = float(np.clip(self._anchor[1] + up - down, -89.0, 89.0))
        alpha = 1.0 - math.exp(-max(dt, 0.0) / self.tau_s)
        self.yaw += alpha * (goal_yaw - self.yaw)
        self.pitch += alpha * (goal_pitch - self.pitch)
        return self.gaze
