"""pressure_controller's parameters in one table: name, type, unit, default, range, description.

Everything else about a controller parameter comes from here: the node's declarations and
their descriptors (nodes/pressure_controller.py), the fields of the control step's setup
(core/control_step.py ControllerSetup) and of a scene's controller section (sim/scene.py
ControllerSpec), the recorded YAML of a bag (bag/controller_io.py), and docs/interfaces.md's
pressure_controller table (`python -m fabric_guidance.core.controller_parameters --markdown`;
test_controller_parameters compares). Adding a knob is one entry here plus its use.

At run time (`ros2 param set`, a study session's set_parameters) every parameter either takes
effect at once, as its `live` text says, or is read-only (refused by rcl with its reason): none
is accepted and ignored. The node's on-set-parameters callback applies them; docs/interfaces.md
shows each row's `live` text.

Names carry their unit as ROS parameters do (`p_max_kpa`, `rate_threshold_dps`). A name that
was renamed stays readable under its old name (Parameter.old_names) with one warning.
"""
from __future__ import annotations

from dataclasses import dataclass
import math
import sys
from typing import Any, Callable, Mapping
import warnings

from ..interface import markdown_main
from .calibration import MAX_REST_S, REST_TOLERANCE_DEG
from .feedback import (ESTIMATORS, FILTERED, FRAMES, PAPER_GAIN, PAPER_P_MAX, RATE_FILTER_TAU_S,
                       RATE_THRESHOLD_DPS, REST, SIGN, STALL_TIMEOUT_S, TARGET)

#: A parameter recorded before it existed: the value the law then ran with (see legacy).
NOT_RECORDED = object()


@dataclass(frozen=True)
class Parameter:
    """One controller parameter."""
    name: str
    default: Any
    description: str
    unit: str = ''
    low: float | None = None
    high: float | None = None
    #: The core refuses the low end itself (a P_MAX of 0 kPa), though a ROS range is closed.
    low_open: bool = False
    choices: tuple = ()
    read_only: bool = False
    #: What setting it at run time does (the node applies it at once); '' for read-only ones.
    live: str = ''
    #: Part of the control step's setup (ControllerSetup) and of the recorded YAML.
    setup: bool = False
    #: Also a key of a scene's controller section (sim/scene.py).
    scene: bool = False
    #: A recorded YAML without this key ran with this value (a bag older than the parameter).
    legacy: Any = NOT_RECORDED
    #: Setup value of a ROS value: stall_timeout_s 0 (ROS has no null) means never (None).
    zero_is_none: bool = False
    old_names: tuple[str, ...] = ()

    @property
    def type(self) -> type:
        return type(self.default)

    @property
    def docs_default(self) -> str:
        d = self.default
        if isinstance(d, bool):
            return str(d).lower()
        if isinstance(d, float):
            return f'{d:.3g}'
        if isinstance(d, str):
            return d if d else "''"
        return str(d)


_STEP = ('vents; the next step runs Eq. 5 with it (controller_parameters republished); refused during a '
         'calibration')
_NEXT_CAL = 'the next calibration; refused during one'
_LIMIT = ('a safety limit (shortened only; raising it, or stall_timeout_s to 0, is refused; the value is held across '
          'restarts in state_dir): ')

#: Every pressure_controller parameter, in the node's declaration order.
PARAMETERS: tuple[Parameter, ...] = (
    Parameter('condition', 1, 'guidance condition: 1 surface adjusted, 2 surface fixed, 3 arm adjusted, '
              '4 speech', low=1, high=4, setup=True,
              live='vents; the layout (condition 3: the arm) or speech (4) from the next step; refused during a '
              'calibration'),
    Parameter('gain', PAPER_GAIN, 'adjustment gain G of Eq. 5 (the paper: 0.05)', '-', 0.0, 10.0,
              setup=True, scene=True, live=_STEP),
    Parameter('p_max_kpa', PAPER_P_MAX, 'no command above this leaves the node (the paper: 375 kPa)', 'kPa',
              0.0, 1000.0, low_open=True, setup=True, scene=True,
              live='a safety limit (lowered only): the very next command is clamped to it and the value is held '
              'across restarts (state_dir); raising is refused; lowering ends a running calibration'),
    Parameter('control_rate_hz', 30.0, 'Eq. 5 steps per second without gaze steps; with step_on_gaze the '
              'least: the timer steps whenever no step ran for a period (it vents on a stale gaze)', 'Hz',
              1.0, 1000.0, setup=True, scene=True, live='the timer restarts at the new rate; ' + _STEP),
    Parameter('gaze_timeout_s', 0.3, 'vent when no valid gaze arrived for this long', 's', 0.01, 10.0,
              setup=True, scene=True, live=_LIMIT + _STEP),
    Parameter('rate_deadband_dps', 0.0, 'rate_estimator sign only: de/dt must exceed this to count as '
              'growing (0: the paper)', 'deg/s', 0.0, 1000.0, setup=True, scene=True, live=_STEP),
    Parameter('guidance_frame', REST, "origin of Eq. 5's angles: rest (the calibration's rest gaze) or "
              'target (the gaze when a target begins); docs/guidance.md', choices=FRAMES, setup=True,
              scene=True, legacy=TARGET, live=_STEP),
    Parameter('rate_estimator', FILTERED, '"the error grows": filtered (low-passed de/dt above '
              "rate_threshold_dps) or sign (the paper's literal test)", choices=ESTIMATORS, setup=True,
              scene=True, legacy=SIGN, live=_STEP),
    Parameter('rate_filter_tau_s', RATE_FILTER_TAU_S, 'time constant of the de/dt filter', 's', 0.001, 10.0,
              setup=True, scene=True, legacy=RATE_FILTER_TAU_S, live=_STEP),
    Parameter('rate_threshold_dps', RATE_THRESHOLD_DPS, 'filtered de/dt must exceed this (default: 3 sd '
              'of 1.5 deg tracker noise at 30 Hz)', 'deg/s', 0.001, 1000.0, setup=True, scene=True,
              legacy=RATE_THRESHOLD_DPS, live=_STEP),
    Parameter('stall_timeout_s', STALL_TIMEOUT_S, 'vent when the gaze made no progress toward the target '
              'for this long; 0 = never', 's', 0.0, 3600.0, setup=True, legacy=None, zero_is_none=True,
              live=_LIMIT + _STEP),
    Parameter('calibration_file', '', "the wearer's calibration file (YAML); '' = none: no guidance until "
              'calibrated (a file that does not exist at configure: none, with one line)',
              live='loaded and used from the next step (vents), or refused with the reason; refused during a '
              'calibration'),
    Parameter('calibration_dir', '', "where start_calibration writes <wearer>.yaml; "
              "'' = ~/.fabric_guidance/calibrations", live=_NEXT_CAL),
    Parameter('wearer', 'wearer', "name of the wearer (the calibration file's name; a file name, no path); a "
              'calibration_file of another person is refused (the default `wearer` names nobody: the file\'s '
              'wearer is taken)',
              live='checked as a file name; another wearer vents and drops the calibration in use, loading '
              '<calibration_dir>/<wearer>.yaml if it exists (else no guidance until calibrated); refused '
              'during a calibration'),
    Parameter('calibration_steps', 10, 'pressure steps per direction (Algorithm 1: 10)', '-', 3, 50, live=_NEXT_CAL),
    Parameter('calibration_dwell_s', 3.0, 'time at each pressure step', 's', 0.05, 60.0, live=_NEXT_CAL),
    Parameter('calibration_rest_s', 3.0, 'vented rest before each direction', 's', 0.05, 60.0, live=_NEXT_CAL),
    Parameter('calibration_window_s', 0.5, 'the recorded angle is the median over the last part of a '
              'dwell', 's', 0.01, 60.0, live=_NEXT_CAL),
    Parameter('calibration_min_r2', 0.8, 'refuse a direction whose fit explains less', '-', -1e9, 1.0,
              live=_NEXT_CAL),
    Parameter('calibration_min_span_deg', 5.0, 'refuse a direction whose angles span less', 'deg', 0.0, 180.0,
              live=_NEXT_CAL),
    Parameter('calibration_max_reversal_deg', 2.0, 'refuse a direction whose angle falls more than this '
              'below an earlier one', 'deg', 0.0, 180.0, live=_NEXT_CAL),
    Parameter('calibration_max_rmse_kpa', PAPER_P_MAX / 10.0, 'refuse a direction whose fit RMSE is larger',
              'kPa', 0.0, 1000.0, live=_NEXT_CAL),
    Parameter('calibration_rest_tolerance_deg', REST_TOLERANCE_DEG, "a direction's steps start only when the "
              'gaze at the end of its rest is steady and within this of the first rest gaze; else the rest is '
              'repeated (0 = no check: a rest offset goes into the fit)', 'deg', 0.0, 90.0, live=_NEXT_CAL),
    Parameter('calibration_max_rest_s', MAX_REST_S, "one direction's rests, repeats included, before the "
              'calibration fails for a gaze that did not come back to rest', 's', 0.05, 600.0, live=_NEXT_CAL),
    Parameter('channel_map_file', '', "channel map (YAML); '' = the package's config/hardware/channel_map.yaml "
              '(the channel order is fixed for the process: restart the node to change it)', read_only=True),
    Parameter('speak', True, 'condition 4: also speak the phrase with espeak-ng if installed',
              live='the next phrase'),
    Parameter('use_wearer_gain', False, "beyond the paper: G from the wearer's calibration file "
              '(adjustment_gain) when it has one', setup=True, legacy=False, live=_STEP),
    Parameter('follow_moving_target', False, 'beyond the paper: shift the pressure with f(theta_t) as a '
              '(live) target moves', setup=True, legacy=False, live=_STEP),
    Parameter('start_enabled', True, 'the enable latch when the process starts: true guides once active (the '
              'simulated graph, the demo); false: vented and disabled until the operator calls enable (the lab '
              'launch with respawn: a restarted controller waits for the operator). Only enable and vent move '
              'the latch afterwards; no lifecycle transition or parameter does', read_only=True),
    Parameter('step_on_gaze', True, 'run a control step on every valid gaze sample, so a sample reaches the '
              "suit without waiting for the timer; Eq. 5 adds G once per step (at the HoloLens' 30 Hz the "
              "paper's rate; false: the timer alone)", read_only=True),
    Parameter('target_publisher', 'target_selector', 'the node whose target and active_target the controller takes '
              '(in its namespace); every other publisher is refused (docs/safety.md)', read_only=True),
    Parameter('state_dir', '', "where the limits tightened at run time are held across restarts "
              "(<state_dir>/<namespace>/pressure_controller_limits.yaml, docs/safety.md); '' = "
              '$FABRIC_GUIDANCE_STATE_DIR, else ~/.fabric_guidance/state', read_only=True),
    # Its default is the channel map's channel order, known only at start-up (declare_table's values).
    Parameter('channels', [], 'order of pressure_command (as ros2_controllers '
              'joints)', read_only=True),
)

BY_NAME: dict[str, Parameter] = {p.name: p for p in PARAMETERS}
assert all(bool(p.live) != p.read_only for p in PARAMETERS), 'each parameter: live or read-only'
#: Parameters only the next calibration reads (refused while one runs).
CALIBRATION: tuple[Parameter, ...] = tuple(p for p in PARAMETERS if p.live == _NEXT_CAL)
SETUP: tuple[Parameter, ...] = tuple(p for p in PARAMETERS if p.setup)
SCENE: tuple[Parameter, ...] = tuple(p for p in PARAMETERS if p.scene)
_OLD = {old: p.name for p in PARAMETERS for old in p.old_names}

#: The safety limits: a smaller value is tighter (stall_timeout_s 0 means never: the loosest).
#: At run time they only tighten, and a tightening is held across restarts (docs/safety.md).
LIMITS: tuple[str, ...] = ('p_max_kpa', 'gaze_timeout_s', 'stall_timeout_s')
#: rclpy's parameters that must not change at run time (the reason each is refused).
FIXED_AT_RUN_TIME: dict[str, str] = {
    'use_sim_time': "use_sim_time is fixed while the node runs: Eq. 5's time would follow whoever publishes "
                    '/clock; set it at start',
}


def _tightness(name: str, value: float) -> float:
    """value on a scale where smaller is tighter (stall_timeout_s 0, never, is infinite)."""
    if name == 'stall_timeout_s' and not value:
        return math.inf
    return float(value)


def loosens(name: str, old: Any, new: Any) -> bool:
    """Whether setting safety limit `name` from old to new loosens it."""
    return _tightness(name, new) > _tightness(name, old)


def tightest(name: str, a: Any, b: Any) -> Any:
    """The tighter of two values of safety limit `name`."""
    return a if _tightness(name, a) <= _tightness(name, b) else b


def default(name: str) -> Any:
    return BY_NAME[name].default


def renamed(values: Mapping[str, Any], where: str,
            warn: Callable[[str], None] | None = None) -> dict[str, Any]:
    """values with every old parameter name replaced by its new one; one warning per old name
    (naming `where`, the file or topic it came from). Both names at once: ValueError."""
    out = dict(values)
    for old, new in _OLD.items():
        if old not in out:
            continue
        if new in out:
            raise ValueError(f'{where}: both "{old}" and its new name "{new}" are set; keep "{new}"')
        text = f'{where}: parameter "{old}" is deprecated, read as "{new}"; rename it'
        (warn or (lambda m: warnings.warn(m, FutureWarning, stacklevel=3)))(text)
        out[new] = out.pop(old)
    return out


def check(name: str, value: Any, where: str) -> Any:
    """value as the parameter's type, within its range and choices; ValueError naming `where`."""
    p = BY_NAME[name]
    if value is None and p.zero_is_none:
        return None
    if p.choices:
        if value not in p.choices:
            raise ValueError(f'{where}: must be one of {list(p.choices)}, got {value!r}')
        return value
    if isinstance(p.default, (bool, str, list)):
        if not isinstance(value, p.type):
            raise ValueError(f'{where}: must be of type {p.type.__name__}, got {value!r}')
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f'{where}: must be a number ({p.unit}), got {value!r}')
    if isinstance(p.default, int) and not float(value).is_integer():
        raise ValueError(f'{where}: must be a whole number, got {value!r}')
    if not math.isfinite(value):
        raise ValueError(f'{where}: must be finite, got {value!r}')
    if p.low is not None and (value <= p.low if p.low_open else value < p.low):
        raise ValueError(f'{where}: must be {">" if p.low_open else ">="} {p.low:g} {p.unit}, got {value!r}')
    if p.high is not None and value > p.high:
        raise ValueError(f'{where}: must be <= {p.high:g} {p.unit}, got {value!r}')
    return p.type(value)


def markdown() -> str:
    """pressure_controller's rows of docs/interfaces.md's parameter table."""
    lines = []
    for i, p in enumerate(PARAMETERS):
        node = 'pressure_controller' if i == 0 else ''
        name = f'`{p.name}`' + (' (read-only)' if p.read_only else '')
        what = p.description
        if p.choices:
            what += f' (one of: {", ".join(p.choices)})'
        elif p.low is not None:
            what += f' (range {"(" if p.low_open else "["}{p.low:g}, {p.high:g}])'
        if p.live:
            what += f'. Set at run time: {p.live}'
        default_text = 'from the channel map' if p.name == 'channels' else p.docs_default
        lines.append(f'| {node} | {name} | {default_text} | {p.unit if p.unit != "-" else ""} | {what} |')
    return '\n'.join(lines) + '\n'


def main(argv: list[str] | None = None) -> int:
    return markdown_main('fabric_guidance.core.controller_parameters', markdown, argv)


__all__ = ['BY_NAME', 'CALIBRATION', 'FIXED_AT_RUN_TIME', 'LIMITS', 'PARAMETERS', 'Parameter', 'SCENE', 'SETUP',
           'check', 'default', 'markdown',
           'loosens', 'renamed', 'tightest']

if __name__ == '__main__':
    sys.exit(main())
