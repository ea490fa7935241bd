"""Stage `body`: the wearer's head and eyes moving toward their goal (body_dynamics)."""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import ClassVar

from .base import Effect, RunContext, param


@dataclass
class BodyDynamics(Effect):
    """The body takes time to move, and the eyes catch a visible target.

    Without this effect the posture jumps to its goal every step. With it the torso follows
    the goal as a first-order lag, and the gaze (head and eyes) rides on the torso; once a
    visible target is inside the central visual field, head and eyes turn to it with a faster
    first-order lag (visual capture: the target is seen).

    torso_tau_s (s, default 0.4): the package's simulated wearer (SimulatedWearer tau_s), an
    assumption of the order of a voluntary trunk rotation of tens of degrees taking about a
    second. head_tau_s (s, default 0.15): head-eye gaze shifts of 20-30 deg take about
    0.1-0.3 s (an order of magnitude from the gaze-shift literature). central_field_deg (deg,
    default 30): the paper's central visual field (30 deg radius, after Sampson and Bhise), in
    which color and shape are identified; 0 disables capture.
    """

    name: ClassVar[str] = 'body_dynamics'
    stage: ClassVar[str] = 'body'

    torso_tau_s: float = param(0.4, 's', lo=0.0, lo_open=True)
    head_tau_s: float = param(0.15, 's', lo=0.0, lo_open=True)
    central_field_deg: float = param(30.0, 'deg', lo=0.0, hi=180.0)

    def start(self, ctx: RunContext) -> None:
        self.torso_alpha = 1.0 - math.exp(-ctx.dt / self.torso_tau_s)
        self.head_alpha = 1.0 - math.exp(-ctx.dt / self.head_tau_s)
        half = math.radians(self.central_field_deg) / 2.0
        self.central_field_hav = math.sin(half) ** 2      # wearer.haversine() at the field's edge
