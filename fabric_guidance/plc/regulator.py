"""What the PLC does with the registers, simulated in plain Python (no sockets, no pymodbus).

Used by the mock PLC server (modbus.py) and testable on its own with a fake clock:

- :class:`FirstOrderLag`: each regulator's measured pressure follows its command as a
  first-order lag, y' = (u - y) / tau, stepped with the exact discretisation
  y <- u + (y - u) * exp(-dt / tau), so the result does not depend on the scan rate.
- :class:`Watchdog`: the PLC-side heartbeat watchdog. Commands are applied only while the
  heartbeat register keeps changing; after ``timeout_s`` without a change every channel is
  vented.
- :class:`RegulatorSim`: one PLC scan combining the two.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable, Hashable, Sequence


class FirstOrderLag:
    """A vector of independent first-order lags with time constant ``tau_s`` (seconds)."""

    def __init__(self, n: int, tau_s: float):
        if not (math.isfinite(tau_s) and tau_s >= 0):
            raise ValueError(f'tau_s must be a finite number >= 0 (0: no lag), got {tau_s!r}')
        self.tau_s = float(tau_s)
        self._y = [0.0] * n

    @property
    def values(self) -> list[float]:
        """Current outputs (same unit as the targets, here kPa)."""
        return list(self._y)

    def reset(self, value: float = 0.0) -> None:
        self._y = [float(value)] * len(self._y)

    def step(self, targets: Sequence[float], dt_s: float) -> list[float]:
        """Advance by ``dt_s`` seconds towards ``targets``; dt <= 0 (or NaN) leaves the state as is."""
        if len(targets) != len(self._y):
            raise ValueError(f'need {len(self._y)} targets, got {len(targets)}')
        if not dt_s > 0:  # also catches NaN: a clock glitch must not move the pressures
            return self.values
        alpha = 0.0 if self.tau_s == 0 else math.exp(-dt_s / self.tau_s)
        self._y = [u + (y - u) * alpha for u, y in zip(targets, self._y)]
        return self.values


class Watchdog:
    """Heartbeat watchdog: ``update()`` says whether commands may be applied.

    It starts tripped. Why: before any heartbeat has arrived nobody has shown that a live
    controller is behind the command registers (they may hold stale values from an earlier
    session, or a client may have written commands and died), and a PLC that pressurised
    on power-up would inflate the suit with nobody supervising it. Venting until proven
    alive is the fail-safe default; it costs one heartbeat of latency at start-up.

    The first observed heartbeat value is only a baseline; a *change* of it arms the
    watchdog. If the value then stays the same for ``timeout_s`` seconds it trips (``trips``
    counts that) and it re-arms at the next change.
    """

    def __init__(self, timeout_s: float):
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            raise ValueError(f'timeout_s must be a positive finite number, got {timeout_s!r}')
        self.timeout_s = float(timeout_s)
        self.trips = 0
        self.reset()

    def reset(self) -> None:
        """Back to the power-up state (tripped, no baseline); ``trips`` is kept."""
        self.armed = False
        self._last_value: Hashable | None = None
        self._last_change_s = 0.0

    def update(self, heartbeat: Hashable, now_s: float) -> bool:
        """Feed the current heartbeat register value at time ``now_s`` (monotonic seconds).

        Returns True while commands may be applied.
        """
        if self._last_value is None:
            self._last_value, self._last_change_s = heartbeat, now_s
        elif heartbeat != self._last_value:
            self._last_value, self._last_change_s = heartbeat, now_s
            self.armed = True
        elif self.armed and now_s - self._last_change_s >= self.timeout_s:
            self.armed = False
            self.trips += 1
        return self.armed


@dataclass(frozen=True)
class ScanResult:
    applied_kpa: list[float]   #: what the regulators were asked for this scan (0 when vented)
    measured_kpa: list[float]  #: regulator outputs after this scan
    vent: bool                 #: True: the watchdog is tripped, the command registers must be zeroed


class RegulatorSim:
    """One PLC scan: watchdog, then the regulators' first-order lag.

    ``p_max_kpa`` is the regulators' own ceiling: whatever the registers say, the simulated
    regulator never goes above it (a real one is limited by its supply pressure).
    """

    def __init__(self, n_channels: int, p_max_kpa: float, tau_s: float = 0.15, watchdog_s: float = 0.5,
                 clock: Callable[[], float] = time.monotonic):
        self.p_max_kpa = float(p_max_kpa)
        self.lag = FirstOrderLag(n_channels, tau_s)
        self.watchdog = Watchdog(watchdog_s)
        self._clock = clock
        self._last_s: float | None = None

    def reset(self) -> None:
        """PLC power-up: pressures 0, watchdog tripped; the trip count is kept."""
        self.lag.reset()
        self.watchdog.reset()
        self._last_s = None

    def scan(self, commands_kpa: Sequence[float], heartbeat: Hashable, now_s: float | None = None) -> ScanResult:
        now = self._clock() if now_s is None else now_s
        dt = 0.0 if self._last_s is None else now - self._last_s
        # Never let time run backwards for the next scan either.
        self._last_s = now if self._last_s is None else max(now, self._last_s)
        armed = self.watchdog.update(heartbeat, now)
        if armed:
            applied = [min(max(c, 0.0), self.p_max_kpa) if math.isfinite(c) else 0.0 for c in commands_kpa]
        else:
            applied = [0.0] * len(commands_kpa)
        measured = self.lag.step(applied, dt)
        return ScanResult(applied, measured, vent=not armed)
