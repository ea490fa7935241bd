"""pressure_controller's control step as data: the inputs of one step (topic `controller_input`),
the controller's parameters (latched topic `controller_parameters`, YAML), and the step itself,
shared by the live node and the offline replay so that both run the very same code.

controller_input is a std_msgs/Float64MultiArray published every control step right before
that step's pressure_command, with this fixed layout (index: meaning):

  0      t           ROS time of the step [s] (sim time under use_sim_time)
  1-3    origin      gaze origin x, y, z [m] (NaN: no gaze yet)
  4-6    direction   gaze direction x, y, z, unit (NaN: no gaze yet)
  7-9    target      active target position x, y, z [m] (NaN: none)
  10     fresh       1: a valid gaze arrived within gaze_timeout_s
  11     enabled     1: guidance enabled (not disabled or vented by service)
  12     has_target  1: an active target name and a position published after it
  13     reset       1: the controller was vented since the previous step (new target,
                     its position, enable false, vent service): Eq. 5 starts again
  14     calibrating 1: Algorithm 1 runs; the command is the calibration's, not Eq. 5's
  15     condition   guidance condition 1-4
  16     step        number of this control step since start-up (0-based)
  17     command     index of the pressure_command this step publishes, counting every
                     command the node published (services and shutdown included), 0-based

layout.dim is empty and data_offset 0; the length is INPUT_SIZE.
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any, Mapping, Sequence

import numpy as np
import yaml

from ..core.safe_input import excerpt, parse_yaml
from ..core import Calibration, ChannelMap, GuidanceController, condition as condition_of, target_direction
from ..core import feedback as law   # law.TARGET, not this module's TARGET (an input slice)
from ..core.feedback import (FILTERED, RATE_FILTER_TAU_S, RATE_THRESHOLD_DPS, REST, SIGN,
                             STALL_TIMEOUT_S)
from ..core.geometry import DIRECTIONS
from ..interface import CONTROLLER_INPUT, CONTROLLER_PARAMETERS  # noqa: F401 (re-exported)

PARAMETERS_SCHEMA = 1

T, ORIGIN, DIRECTION, TARGET = 0, slice(1, 4), slice(4, 7), slice(7, 10)
FRESH, ENABLED, HAS_TARGET, RESET, CALIBRATING, CONDITION, STEP, COMMAND = range(10, 18)
INPUT_SIZE = 18
FIELDS = ('t', 'origin_x', 'origin_y', 'origin_z', 'direction_x', 'direction_y', 'direction_z',
          'target_x', 'target_y', 'target_z', 'fresh', 'enabled', 'has_target', 'reset', 'calibrating',
          'condition', 'step', 'command')
assert len(FIELDS) == INPUT_SIZE


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

    def encode(self) -> list[float]:
        nan3 = [math.nan] * 3

        def vec(v):
            return nan3 if v is None else [float(x) for x in v]
        return ([float(self.t)] + vec(self.origin) + vec(self.direction) + vec(self.target) +
                [float(self.fresh), float(self.enabled), float(self.has_target), float(self.reset),
                 float(self.calibrating), float(self.condition), float(self.step), float(self.command)])

    @classmethod
    def decode(cls, data: Sequence[float]) -> 'StepInput':
        d = np.asarray(data, dtype=float)
        if d.shape != (INPUT_SIZE,):
            raise ValueError(f'controller_input must hold {INPUT_SIZE} values, got {d.shape}')

        def vec(s):
            v = d[s]
            return None if np.isnan(v).any() else v.copy()
        return cls(float(d[T]), vec(ORIGIN), vec(DIRECTION), vec(TARGET), bool(d[FRESH]), bool(d[ENABLED]),
                   bool(d[HAS_TARGET]), bool(d[RESET]), bool(d[CALIBRATING]), int(d[CONDITION]), int(d[STEP]),
                   int(d[COMMAND]))


def channel_map_dict(cmap: ChannelMap) -> dict:
    return {'channels': list(cmap.channels),
            'layouts': {lay: {d: list(cmap.channels_of(lay, d)) for d in DIRECTIONS} for lay in cmap.layouts}}


@dataclass
class ControllerSetup:
    """Everything the control step depends on besides its inputs: the node's parameters, the
    calibration and the channel map. to_yaml()/from_yaml() round-trip floats exactly."""
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

    def to_dict(self) -> dict:
        return {'schema': PARAMETERS_SCHEMA, 'condition': int(self.condition), 'gain': float(self.gain),
                'p_max_kpa': float(self.p_max_kpa), 'control_rate_hz': float(self.control_rate_hz),
                'gaze_timeout_s': float(self.gaze_timeout_s), 'rate_deadband_dps': float(self.rate_deadband_dps),
                'use_wearer_gain': bool(self.use_wearer_gain),
                'follow_moving_target': bool(self.follow_moving_target),
                'guidance_frame': str(self.guidance_frame),
                'rate_estimator': str(self.rate_estimator),
                'rate_filter_tau_s': float(self.rate_filter_tau_s),
                'rate_threshold_dps': float(self.rate_threshold_dps),
                'stall_timeout_s': (None if self.stall_timeout_s is None
                                    else float(self.stall_timeout_s)),
                'calibration': self.calibration.to_dict() if self.calibration is not None else None,
                'channel_map': channel_map_dict(self.channel_map)}

    def to_yaml(self) -> str:
        return yaml.safe_dump(self.to_dict(), sort_keys=False)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> 'ControllerSetup':
        cal = d.get('calibration')
        return cls(int(d['condition']), float(d['gain']), float(d['p_max_kpa']), float(d['control_rate_hz']),
                   float(d['gaze_timeout_s']), float(d['rate_deadband_dps']), bool(d['use_wearer_gain']),
                   bool(d['follow_moving_target']),
                   Calibration.from_dict(cal, 'controller_parameters.calibration') if cal else None,
                   ChannelMap.from_dict(d['channel_map'], 'controller_parameters.channel_map'),
                   # Keys missing: a bag of the law before issue 11, replayed as it ran.
                   str(d.get('guidance_frame', law.TARGET)), str(d.get('rate_estimator', SIGN)),
                   float(d.get('rate_filter_tau_s', RATE_FILTER_TAU_S)),
                   float(d.get('rate_threshold_dps', RATE_THRESHOLD_DPS)),
                   None if d.get('stall_timeout_s') is None else float(d['stall_timeout_s']))

    @classmethod
    def from_yaml(cls, text: str) -> 'ControllerSetup':
        return cls.from_dict(parse_yaml(text, CONTROLLER_PARAMETERS))

    def with_overrides(self, overrides: Mapping[str, Any]) -> 'ControllerSetup':
        """A copy with some parameters changed (`replay --set gain=0.1`)."""
        d = self.to_dict()
        for key, value in overrides.items():
            if key not in d or key in ('schema', 'calibration', 'channel_map'):
                settable = [k for k in d if k not in ('schema', 'calibration', 'channel_map')]
                raise ValueError(f'unknown controller parameter {excerpt(key)}; settable: {settable}')
            d[key] = _override(key, d[key], value)
        return ControllerSetup.from_dict(d)


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


def _override(key: str, current: Any, value: Any) -> Any:
    """An override of the current value's kind (number, whole number, true/false), or ValueError
    naming the parameter."""
    if isinstance(current, bool):
        if not isinstance(value, bool):
            raise ValueError(f'--set {key}: must be true or false, got {excerpt(value)}')
        return value
    ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    try:
        ok = ok and math.isfinite(value)
    except OverflowError:
        ok = False
    if isinstance(current, int) and not (ok and float(value).is_integer()):
        raise ValueError(f'--set {key}: must be a whole number, got {excerpt(value)}')
    if not ok:
        raise ValueError(f'--set {key}: must be a finite number, got {excerpt(value)}')
    return value
