"""pressure_controller's control step without ROS: what one step uses (StepInput), what the
step depends on besides its inputs (ControllerSetup), and the step itself (guidance_step, with
the last line of defence safe_command). The live node and the offline replay of a bag both run
this very code; bag/controller_io.py holds how a step is recorded.
"""
from __future__ import annotations

from dataclasses import dataclass, field, make_dataclass
from typing import Any, Callable, Mapping, Optional

import numpy as np

from .calibration import Calibration
from .channels import ChannelMap
from .conditions import condition as condition_of
from .controller_parameters import SETUP
from .feedback import GuidanceController
from .geometry import target_direction
from .power_law import PowerLaw

__all__ = ['RESET_KEEP_STALL', 'RESET_VENT', 'ControllerSetup', 'StepInput', 'apply_reset', 'build_controller',
           'controller_gain', 'guidance_step', 'safe_command', 'why_not_guide']


#: StepInput.reset: a vent since the previous step that forgets a latched stall (a new target,
#: a service call), or one that keeps it (deactivate, activate: an interruption, not a decision).
RESET_VENT, RESET_KEEP_STALL = 1, 2


@dataclass
class StepInput:
    """What one control step used. t: Eq. 5's time (ROS time: a replay's /clock); clock: the
    steady clock the safety bounds run on (the stall watch), None: t."""
    t: float
    origin: np.ndarray | None
    direction: np.ndarray | None
    target: np.ndarray | None
    fresh: bool
    enabled: bool
    has_target: bool
    reset: int          # 0, RESET_VENT or RESET_KEEP_STALL (a bool: RESET_VENT)
    calibrating: bool
    condition: int
    step: int
    command: int
    clock: float | None = None


class _SetupMethods:
    @property
    def layout(self) -> str:
        return condition_of(self.condition).layout or 'suit'

    def values(self) -> dict[str, Any]:
        """The table's setup parameters (core/controller_parameters.py) by name."""
        return {p.name: getattr(self, p.name) for p in SETUP}

    def make_controller(self) -> GuidanceController | None:
        """The node's controller (nodes/pressure_controller.py and the offline replay use this)."""
        cond = condition_of(self.condition)
        if self.calibration is None or not cond.haptic:
            return None
        return build_controller(self.values(), cond.mode, self.calibration)


#: Everything the control step depends on besides its inputs: the table's setup parameters
#: (core/controller_parameters.py, keyword arguments with the table's defaults), the
#: calibration and the channel map (recorded as YAML by bag/controller_io.py).
ControllerSetup = make_dataclass(
    'ControllerSetup',
    [('calibration', Optional[Calibration]), ('channel_map', ChannelMap)]
    + [(p.name, p.type, field(default=None if p.zero_is_none and not p.default else p.default))
       for p in SETUP],
    bases=(_SetupMethods,), kw_only=True)
ControllerSetup.__module__ = __name__


def controller_gain(gain: float, use_wearer_gain: bool, calibration: Calibration | None) -> float:
    """G of Eq. 5: the wearer's own (the calibration's adjustment_gain) when asked and present."""
    if use_wearer_gain and calibration is not None and calibration.adjustment_gain is not None:
        return calibration.adjustment_gain
    return gain


def build_controller(values: Mapping[str, Any], mode: str, calibration: Calibration,
                     law_type: Callable[[PowerLaw], PowerLaw] | None = None) -> GuidanceController:
    """The one builder of the guidance controller, from the table's setup parameters by name
    (`values`: ControllerSetup.values(), or a scene's controller section with the rest), the
    condition's mode and the calibration. law_type: how each fitted law is evaluated (the
    simulator's scalar FastPowerLaw.of); None: the calibration's laws as they are."""
    laws = calibration.laws if law_type is None else [law_type(law) for law in calibration.laws]
    stall = values['stall_timeout_s']
    return GuidanceController(
        laws, p_max=min(values['p_max_kpa'], calibration.p_max),
        gain=controller_gain(values['gain'], values['use_wearer_gain'], calibration),
        mode=mode, rate_deadband_dps=values['rate_deadband_dps'],
        follow_target=values['follow_moving_target'], estimator=values['rate_estimator'],
        rate_filter_tau_s=values['rate_filter_tau_s'], rate_threshold_dps=values['rate_threshold_dps'],
        frame=values['guidance_frame'], rest_gaze=calibration.origin,
        stall_timeout_s=stall if stall else None)


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


def apply_reset(controller: GuidanceController | None, inp: StepInput) -> None:
    """The vent recorded in inp.reset, as the node applied it between steps."""
    if inp.reset and controller is not None:
        controller.vent(forget_stall=inp.reset != RESET_KEEP_STALL)


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
        direction_pressures = controller.update(inp.direction, target_direction(inp.origin, inp.target), inp.t,
                                                inp.clock)
    except ValueError as exc:
        controller.vent(forget_stall=False)
        return zeros, f'invalid input: {exc}', True
    if controller.stalled:
        return zeros, controller.stalled, False
    return setup.channel_map.to_channels(direction_pressures, setup.layout), '', False
