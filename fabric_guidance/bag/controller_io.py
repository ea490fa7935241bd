"""pressure_controller's control step as data: the inputs of one step (topic `controller_input`)
and the controller's parameters (latched topic `controller_parameters`, YAML). The step itself
(StepInput, ControllerSetup, guidance_step) is core/control_step.py, shared by the live node
and the offline replay so that both run the very same code.

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
                     its position, enable, vent service): Eq. 5 starts again, a stall is
                     forgotten; 2: vented by deactivate/activate: Eq. 5 starts again, a
                     latched stall and the stall watch are kept
  14     calibrating 1: Algorithm 1 runs; the command is the calibration's, not Eq. 5's
  15     condition   guidance condition 1-4
  16     step        number of this control step since start-up (0-based)
  17     command     index of the pressure_command this step publishes, counting every
                     command the node published (services and shutdown included), 0-based
  18     clock       the node's steady clock at the step [s]: what the stall watch ran on
                     (a bag recorded before it has 18 values: the replay uses t)

The length is INPUT_SIZE; layout.dim is one dimension (size and stride INPUT_SIZE) whose label is
FIELDS joined by commas (the names above, as nodes/array_layout.py labels every array of the
package); data_offset 0. A bag recorded before the label has an empty layout: the data is the same.
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np
import yaml

from ..core import Calibration, ChannelMap
from ..core.control_step import ControllerSetup, StepInput
from ..core.controller_parameters import BY_NAME, NOT_RECORDED, SETUP, check, renamed
from ..core.geometry import DIRECTIONS
from ..core.safe_input import excerpt, parse_yaml
from ..interface import CONTROLLER_INPUT, CONTROLLER_PARAMETERS  # noqa: F401 (re-exported)

PARAMETERS_SCHEMA = 1

T, ORIGIN, DIRECTION, TARGET = 0, slice(1, 4), slice(4, 7), slice(7, 10)
FRESH, ENABLED, HAS_TARGET, RESET, CALIBRATING, CONDITION, STEP, COMMAND = range(10, 18)
CLOCK = 18
INPUT_SIZE = 19
#: Before the steady clock was recorded.
LEGACY_INPUT_SIZE = 18
FIELDS = ('t', 'origin_x', 'origin_y', 'origin_z', 'direction_x', 'direction_y', 'direction_z',
          'target_x', 'target_y', 'target_z', 'fresh', 'enabled', 'has_target', 'reset', 'calibrating',
          'condition', 'step', 'command', 'clock')
assert len(FIELDS) == INPUT_SIZE


def encode_input(inp: StepInput) -> list[float]:
    """A step's inputs as controller_input's data (layout above)."""
    nan3 = [math.nan] * 3

    def vec(v):
        return nan3 if v is None else [float(x) for x in v]
    return ([float(inp.t)] + vec(inp.origin) + vec(inp.direction) + vec(inp.target) +
            [float(inp.fresh), float(inp.enabled), float(inp.has_target), float(inp.reset),
             float(inp.calibrating), float(inp.condition), float(inp.step), float(inp.command),
             float(inp.t if inp.clock is None else inp.clock)])


def decode_input(data: Sequence[float]) -> StepInput:
    """controller_input's data back to the step's inputs; ValueError for a wrong length."""
    d = np.asarray(data, dtype=float)
    if d.shape not in ((INPUT_SIZE,), (LEGACY_INPUT_SIZE,)):
        raise ValueError(f'controller_input must hold {INPUT_SIZE} values, got {d.shape}')

    def vec(s):
        v = d[s]
        return None if np.isnan(v).any() else v.copy()
    return StepInput(float(d[T]), vec(ORIGIN), vec(DIRECTION), vec(TARGET), bool(d[FRESH]),
                     bool(d[ENABLED]), bool(d[HAS_TARGET]), int(d[RESET]), bool(d[CALIBRATING]),
                     int(d[CONDITION]), int(d[STEP]), int(d[COMMAND]),
                     float(d[CLOCK]) if d.size > CLOCK else None)


def channel_map_dict(cmap: ChannelMap) -> dict:
    return {'channels': list(cmap.channels),
            'layouts': {lay: {d: list(cmap.channels_of(lay, d)) for d in DIRECTIONS} for lay in cmap.layouts}}


def setup_to_dict(setup: ControllerSetup) -> dict:
    """controller_parameters' content (schema PARAMETERS_SCHEMA): the table's setup parameters
    (core/controller_parameters.py) in its order, the calibration and the channel map."""
    d: dict[str, Any] = {'schema': PARAMETERS_SCHEMA}
    for name, value in setup.values().items():
        d[name] = value if value is None or isinstance(value, str) else BY_NAME[name].type(value)
    d['calibration'] = setup.calibration.to_dict() if setup.calibration is not None else None
    d['channel_map'] = channel_map_dict(setup.channel_map)
    return d


def setup_to_yaml(setup: ControllerSetup) -> str:
    """controller_parameters' YAML; setup_from_yaml() reads it back with floats exact."""
    return yaml.safe_dump(setup_to_dict(setup), sort_keys=False)


def setup_from_dict(d: Mapping[str, Any], where: str = CONTROLLER_PARAMETERS) -> ControllerSetup:
    """The setup of a recorded controller_parameters mapping. A key the recording lacks (a bag
    older than the parameter) takes the value the law then ran with (the table's legacy); an old
    name is read as its new one with a warning."""
    d = renamed(d, where)
    values = {}
    for p in SETUP:
        if p.name in d:
            values[p.name] = check(p.name, d[p.name], f'{where}: field "{p.name}"')
        elif p.legacy is not NOT_RECORDED:
            values[p.name] = p.legacy
        else:
            raise ValueError(f'{where}: field "{p.name}" is missing')
    cal = d.get('calibration')
    if 'channel_map' not in d:
        raise ValueError(f'{where}: field "channel_map" is missing')
    return ControllerSetup(
        calibration=Calibration.from_dict(cal, f'{where}.calibration') if cal else None,
        channel_map=ChannelMap.from_dict(d['channel_map'], f'{where}.channel_map'), **values)


def setup_from_yaml(text: str) -> ControllerSetup:
    return setup_from_dict(parse_yaml(text, CONTROLLER_PARAMETERS))


def with_overrides(setup: ControllerSetup, overrides: Mapping[str, Any]) -> ControllerSetup:
    """A copy with some parameters changed (`replay --set gain=0.1`)."""
    d = setup_to_dict(setup)
    for key, value in overrides.items():
        if key not in d or key in ('schema', 'calibration', 'channel_map'):
            settable = [k for k in d if k not in ('schema', 'calibration', 'channel_map')]
            raise ValueError(f'unknown controller parameter {excerpt(key)}; settable: {settable}')
        d[key] = _override(key, d[key], value)
    return setup_from_dict(d)


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
