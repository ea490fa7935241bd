"""A gaze sweep whose every sample changes the command to a value that names the sample.

pressure_controller runs condition 2 (Eq. 5 in `fixed` mode: no adjustment from the gaze error)
with follow_moving_target on, and the target stays put while the gaze origin slides sideways.
The command then follows f_left(theta_t) exactly: the first step sets f(theta_t), each later
one shifts it by f(theta_t) - f(theta_t, previous) (the sums telescope). theta_t is the
horizontal angle from the first gaze direction (straight ahead) to the target seen from the
sample's origin, so it is a pure function of the sample. The sweep picks M pressure levels on
whole register counts, apart by `step_kpa`, inverts the calibrated law to the angle and places
the origin there; sample i uses level i mod M. A landed count names the level, and the latest
sample of that level sent before it landed is the sample (M samples take far longer to send
than any latency measured here).
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math

import numpy as np

from ..core import Calibration
from ..core.gaze_wire import encode_datagram
from ..plc import RegisterMap

#: The channel whose register is read: L1, driven by the left twist in the suit layout.
CHANNEL = 'L1'
#: The target: 2 m ahead, at eye height, this far to the left [m] (REP 103).
TARGET_AHEAD_M = 2.0
TARGET_LEFT_M = 0.0
EYE_HEIGHT_M = 1.2


@dataclass
class Sweep:
    calibration: Calibration
    register_map: RegisterMap
    levels: int = 1000
    first_kpa: float = 40.0
    step_kpa: float = 0.3
    counts: np.ndarray = field(init=False)     # register count of each level
    origin_y: np.ndarray = field(init=False)   # gaze origin, REP 103 y [m], of each level

    def __post_init__(self) -> None:
        law = self.calibration.directions['left'].law
        p_max = min(self.calibration.p_max, self.register_map.p_max_kpa)
        per_kpa = self.register_map.counts_per_kpa
        pressures = self.first_kpa + self.step_kpa * np.arange(self.levels)
        if pressures[-1] >= p_max or pressures[0] <= law.c:
            raise ValueError(f'sweep {pressures[0]:g}..{pressures[-1]:g} kPa outside ({law.c:g}, {p_max:g})')
        self.counts = np.rint(pressures * per_kpa).astype(int)
        if np.any(np.abs(self.counts - pressures * per_kpa) > 1e-6) or len(set(self.counts)) != self.levels:
            raise ValueError('sweep levels must sit on distinct whole register counts')
        theta = np.array([law.theta(p, p_max) for p in pressures])
        self.origin_y = TARGET_LEFT_M - TARGET_AHEAD_M * np.tan(np.radians(theta))
        self._level_of = {int(c): j for j, c in enumerate(self.counts)}
        self.register = self.register_map.channels[self.register_map.names.index(CHANNEL)].command_register

    @property
    def target(self) -> tuple[float, float, float]:
        return (TARGET_AHEAD_M, TARGET_LEFT_M, EYE_HEIGHT_M)

    def count(self, i: int) -> int:
        return int(self.counts[i % self.levels])

    def level_of(self, count: int) -> int | None:
        """The level a landed register count names; None for any other value (a vent, 0)."""
        return self._level_of.get(int(count))

    def datagram(self, i: int, rate_hz: float) -> bytes:
        """Sample i as the HoloLens sends it (wire format v1, Unity frame: REP (x, y, z) is
        Unity (-y, z, x)); the gaze looks straight ahead."""
        y = float(self.origin_y[i % self.levels])
        origin = (-y, EYE_HEIGHT_M, 0.0)
        return encode_datagram(i, i / rate_hz, origin, (0.0, 0.0, 1.0), origin, (0.0, 0.0, 0.0, 1.0), True)


def check_sweep(sweep: Sweep) -> float:
    """Largest |f(theta_t) - level| over the levels [kPa] as the controller will compute it
    (through the core's geometry): must stay far below half a register count."""
    from ..core import angles_between, target_direction
    law = sweep.calibration.directions['left'].law
    worst = 0.0
    for j in range(sweep.levels):
        origin = np.array([0.0, sweep.origin_y[j], EYE_HEIGHT_M])
        theta = angles_between([1.0, 0.0, 0.0], target_direction(origin, sweep.target)).horizontal
        worst = max(worst, abs(law.pressure(theta) * sweep.register_map.counts_per_kpa - sweep.counts[j]))
    return worst / sweep.register_map.counts_per_kpa


def level_angle_deg(sweep: Sweep, j: int) -> float:
    return math.degrees(math.atan2(TARGET_LEFT_M - sweep.origin_y[j], TARGET_AHEAD_M))
