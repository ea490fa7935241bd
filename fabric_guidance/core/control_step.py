"""pressure_controller's control step without ROS: what one step uses (StepInput), what the
step depends on besides its inputs (ControllerSetup), and the step itself (guidance_step, with
the last line of defence safe_command). The live node and the offline replay of a bag both run
this very code; bag/controller_io.py holds how a step is recorded.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .calibration import Calibration
from .channels import ChannelMap
from .conditions import condition as condition_of
from .feedback import (FILTERED, RATE_FILTER_TAU_S, RATE_THRESHOLD_DPS, REST, STALL_TIMEOUT_S,
                       GuidanceController)
from .geometry import target_direction

__all__ = ['ControllerSetup', 'StepInput', 'guidance_step', 'safe_command', 'why_not_guide']


@dataclass
class StepInput:
    """What one control step used."""
    t: float
    origin: np.ndarray | None
    direction: np.ndarray | None
    target: np.ndarray | None
    fresh: bool
    enabled: bool
    has_target: bool
    reset: bool
    calibrating: bool
    condition: int
    step: int
    command: int


@dataclass
class ControllerSetup:
    """Everything the control step depends on besides its inputs: the node's parameters, the
    calibration and the channel map (recorded as YAML by bag/controller_io.py)."""
    condition: int
    gain: float
    p_max_kpa: float
    control_rate_hz: float
    gaze_timeout_s: float
    rate_deadband_dps: float
    use_wearer_gain: bool
    follow_moving_target: bool
    calibration: Calibration | None
    channel_map: ChannelMap
    #: Origin of Eq. 5's angles: 'rest' (the calibration's rest gaze) or 'target' (the gaze when
    #: a target begins). A bag recorded before issue 11 has no key: 'target', as it ran then.
    guidance_frame: str = REST
    #: "The error grows": 'filtered' (rate filter + threshold) or 'sign' (the paper's literal
    #: test). A bag recorded before issue 11 has no key: 'sign'.
    rate_estimator: str = FILTERED
    rate_filter_tau_s: float = RATE_FILTER_TAU_S
    rate_threshold_dps: float = RATE_THRESHOLD_DPS
    #: Vent after this long without progress toward the target, s; None: never (a bag
    #: recorded before issue 11).
    stall_timeout_s: float | None = STALL_TIMEOUT_S

    @property
    def layout(self) -> str:
        return condition_of(self.condition).layout or 'suit'

    def make_controller(self) -> GuidanceController | None:
        """The node's controller (nodes/pressure_controller.py uses this very function)."""
        cond = condition_of(self.condition)
        if self.calibration is None or not cond.haptic:
            return None
        gain = self.gain
        if self.use_wearer_gain and self.calibration.adjustment_gain is not None:
            gain = self.calibration.adjustment_gain
        return GuidanceController(self.calibration.laws, p_max=min(self.p_max_kpa, self.calibration.p_max),
                                  gain=gain, mode=cond.mode, rate_deadband=self.rate_deadband_dps,
                                  follow_target=self.follow_moving_target,
                                  estimator=self.rate_estimator,
                                  rate_filter_tau_s=self.rate_filter_tau_s,
                                  rate_threshold=self.rate_threshold_dps,
                                  frame=self.guidance_frame, rest_gaze=self.calibration.origin,
                                  stall_timeout_s=self.stall_timeout_s)


def why_not_guide(setup: ControllerSetup, controller, inp: StepInput) -> str:
    """'' when Eq. 5 runs this step, else why the suit is vented."""
    if not inp.enabled:
        return 'disabled'
    if not condition_of(inp.condition).haptic:
        return 'condition 4 (speech) drives no muscle'
    if controller is None:
        return 'no calibration: call start_calibration or set calibration_file'
    if not inp.has_target:
        return 'no active target'
    if not inp.fresh:
        return f'no valid gaze for {setup.gaze_timeout_s} s'
    return ''


def safe_command(channels: np.ndarray, p_max: float) -> np.ndarray:
    """Last line of defence: nothing above P_MAX and nothing non-finite leaves the node."""
    channels = np.asarray(channels, dtype=float)
    if not np.isfinite(channels).all():
        channels = np.nan_to_num(channels, nan=0.0, posinf=0.0, neginf=0.0)
    return np.clip(channels, 0.0, p_max)


def guidance_step(setup: ControllerSetup, controller: GuidanceController | None,
                  inp: StepInput) -> tuple[np.ndarray, str, bool]:
    """One Eq. 5 control step (not calibration): (channel pressures before the P_MAX clip,
    vent reason or '', whether the input was invalid). `inp.reset` must have been applied
    (controller.vent()) by the caller when the vent happened."""
    zeros = np.zeros(len(setup.channel_map.channels))
    reason = why_not_guide(setup, controller, inp)
    if reason:
        if controller is not None:
            controller.vent(forget_stall=False)   # only a new target or a service forgets a stall
        return zeros, reason, False
    try:
        direction_pressures = controller.update(inp.direction, target_direction(inp.origin, inp.target), inp.t)
    except ValueError as exc:
        controller.vent(forget_stall=False)
        return zeros, f'invalid input: {exc}', True
    if controller.stalled:
        return zeros, controller.stalled, False
    return setup.channel_map.to_channels(direction_pressures, setup.layout), '', False
