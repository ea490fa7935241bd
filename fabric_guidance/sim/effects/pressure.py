"""Stage `pressure`: the command to the pressure the suit exerts, per direction (regulator_lag,
suit_hysteresis)."""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import ClassVar

from .base import Effect, RunContext, param


@dataclass
class RegulatorLag(Effect):
    """First-order lag from the commanded pressure to the regulator's output pressure.

    tau_s (s, default 0.15): time constant. Where from: the package's mock PLC regulator
    (config/params/sim.yaml regulator_tau_s = 0.15), itself an order of magnitude for electro-pneumatic
    proportional regulators (datasheets of the CRCB/ITV class give step responses of about
    0.1-0.2 s without load); the suit's muscle volume would slow it further. Not measured on
    the paper's suit: an assumption of the right order.

    Exact discretisation for a command held over the step: p += (cmd - p) * (1 - exp(-dt/tau)).
    """

    name: ClassVar[str] = 'regulator_lag'
    stage: ClassVar[str] = 'pressure'
    order: ClassVar[int] = 0

    tau_s: float = param(0.15, 's', lo=0.0, lo_open=True)

    def start(self, ctx: RunContext) -> None:
        self.alpha = 1.0 - math.exp(-ctx.dt / self.tau_s)
        self.out = [0.0, 0.0, 0.0, 0.0]

    def pressure(self, p: list) -> list:
        out, alpha = self.out, self.alpha
        for k in range(4):
            out[k] += (p[k] - out[k]) * alpha
        return out


@dataclass
class SuitHysteresis(Effect):
    """Backlash (play) between the regulator's pressure and the pressure the suit exerts.

    band_kpa (kPa, default 20): total width of the play. The exerted pressure does not move
    while the input moves within +-band/2 of it; beyond, it follows the input at band/2 behind
    (a rising input leads by band/2, a falling one lags by band/2). It never goes below 0.
    Where from: the paper's Discussion names "the hysteresis of surface haptic sensation" of the
    suit without a figure; McKibben muscles are known for pressure-force hysteresis of a few
    per cent of full scale (braid-bladder friction). 20 kPa is about 5 % of P_MAX = 375 kPa:
    an assumption of that order.
    """

    name: ClassVar[str] = 'suit_hysteresis'
    stage: ClassVar[str] = 'pressure'
    order: ClassVar[int] = 1

    band_kpa: float = param(20.0, 'kPa', lo=0.0)

    def start(self, ctx: RunContext) -> None:
        self.half = 0.5 * self.band_kpa
        self.out = [0.0, 0.0, 0.0, 0.0]

    def pressure(self, p: list) -> list:
        out, h = self.out, self.half
        for k in range(4):
            x, y = p[k], out[k]
            if y < x - h:
                y = x - h
            elif y > x + h:
                y = x + h
            out[k] = y if y > 0.0 else 0.0
        return out
