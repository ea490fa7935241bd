"""The worked example's wearer loop (`fabric-guidance example`): closed-loop runs of the core
with a simple simulated wearer, without ROS: Algorithm 1 on the wearer, then guided turns under
the feedback law. The same core code the nodes call."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..core.calibration import Calibration, CalibrationProcedure, DONE, FAILED
from ..core.channels import ChannelMap
from ..core.feedback import GuidanceController
from ..core.geometry import DIRECTIONS, angles_between
from ..core.task import AcceptanceTracker, angular_error_deg
from .wearer import SimulatedWearer, gaze_from_angles


def calibrate(wearer: SimulatedWearer, name: str, rate_hz: float = 50.0, **procedure_kwargs) -> Calibration:
    """Run Algorithm 1 on the simulated wearer; raise CalibrationFitError if it fails."""
    proc = CalibrationProcedure(name, p_max=wearer.p_max, **procedure_kwargs)
    dt, t = 1.0 / rate_hz, 0.0
    limit = proc.duration_s + 10.0
    direction_pressures = np.zeros(len(DIRECTIONS))
    wearer.face_front()
    while proc.phase not in (DONE, FAILED) and t <= limit:
        cmd = proc.tick(t, wearer.gaze)
        direction_pressures[:] = 0.0
        if cmd.direction is not None:
            direction_pressures[DIRECTIONS.index(cmd.direction)] = cmd.pressure
        wearer.step(direction_pressures, dt)
        t += dt
    return proc.result()


@dataclass(frozen=True)
class TurnResult:
    horizontal_deg: float      # target angle from the starting gaze, positive left
    vertical_deg: float        # positive up
    found: bool
    time_s: float              # time to find (or the timeout)
    final_error_deg: float
    peak_kpa: dict             # direction -> peak commanded pressure


def guide(wearer: SimulatedWearer, controller: GuidanceController, targets: Sequence[tuple[float, float]],
          channel_map: ChannelMap | None = None, layout: str = 'suit', rate_hz: float = 50.0,
          acceptance_deg: float = 5.0, dwell_s: float = 0.3, timeout_s: float = 15.0) -> list[TurnResult]:
    """Guide the wearer to each target, given as (horizontal, vertical) degrees from the
    front. Between targets the suit vents and the wearer faces front again. Channel pressures
    are formed as the PLC would receive them, and the wearer feels the mean pressure of each
    direction's channels."""
    dt = 1.0 / rate_hz
    results = []
    for h, v in targets:
        wearer.face_front()
        target = gaze_from_angles(h, v)
        start = angles_between(wearer.gaze, target)
        controller.begin(wearer.gaze)
        tracker = AcceptanceTracker(acceptance_deg, dwell_s)
        peak = np.zeros(len(DIRECTIONS))
        t, found = 0.0, False
        while t < timeout_s:
            pressures = controller.update(wearer.gaze, target, t)
            if channel_map is not None:
                pressures = channel_map.to_directions(channel_map.to_channels(pressures, layout), layout)
            peak = np.maximum(peak, pressures)
            wearer.step(pressures, dt)
            t += dt
            if tracker.update(wearer.gaze, target, t):
                found = True
                break
        controller.vent()
        wearer.step(np.zeros(len(DIRECTIONS)), dt)
        results.append(TurnResult(start.horizontal, start.vertical, found, t,
                                  angular_error_deg(wearer.gaze, target),
                                  {d: float(p) for d, p in zip(DIRECTIONS, peak)}))
    return results


def within(law_a, law_b, theta_max: float = 60.0) -> float:
    """Largest pressure difference between two power laws over 0..theta_max degrees, kPa."""
    th = np.linspace(0.0, theta_max, 121)
    return float(np.max(np.abs(law_a.pressure(th) - law_b.pressure(th))))


__all__ = ['calibrate', 'guide', 'TurnResult', 'within']
