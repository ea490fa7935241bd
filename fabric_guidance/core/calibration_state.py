"""The live calibration's progress and outcome as fields: the `calibration_state` topic
(std_msgs/String carrying one JSON object, latched; docs/interfaces.md, "Calibration state").

pressure_controller publishes it beside the `calibration_status` sentence (which stays for
people); headset_display builds the wearer's prompt from it (`prompt`), and the study session
reads it. decode() is strict: any text that is not a valid version-1 state raises
CalibrationStateError naming the field, and nothing else.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
import json
import math

from .calibration import APPLY, DONE, FAILED, REST, CalibrationCommand, CalibrationProcedure
from .geometry import DIRECTIONS

VERSION = 1
#: No calibration has run in this node yet.
IDLE = 'idle'
#: A direction's fit was refused (core.calibration.Acceptance); FAILED: stopped by an error (stale
#: gaze, a vent, a file that could not be written). Neither writes a calibration.
REFUSED = 'refused'
PHASES: tuple[str, ...] = (IDLE, REST, APPLY, DONE, FAILED, REFUSED)
#: Phases of a calibration that is running (the suit may pull).
RUNNING = (REST, APPLY)
MAX_TEXT = 4096


class CalibrationStateError(ValueError):
    """A calibration_state message that is not a valid version-1 state (the message names the field)."""


@dataclass(frozen=True)
class CalibrationState:
    """One calibration_state message. Units: kPa, progress 0..1 over the whole procedure.

    phase: idle (none has run), rest (vented, face front before `direction`), apply (`direction`
    pulled at `pressure_kpa`, step `step` of `steps`), done (written to `file`, fit report
    `report`), failed (`error`; nothing written), refused (a direction's fit was refused: `error`
    says why; nothing written). previous_kept: after failed or refused, whether a calibration the
    node had before is still in use.
    """

    wearer: str
    phase: str = IDLE
    direction: str = ''
    step: int = 0
    steps: int = 0
    pressure_kpa: float = 0.0
    progress: float = 0.0
    file: str = ''
    report: str = ''
    error: str = ''
    previous_kept: bool = False
    version: int = VERSION

    def __post_init__(self):
        _check(asdict(self))

    @property
    def running(self) -> bool:
        return self.phase in RUNNING


_TYPES = {'version': int, 'wearer': str, 'phase': str, 'direction': str, 'step': int, 'steps': int,
          'pressure_kpa': float, 'progress': float, 'file': str, 'report': str, 'error': str, 'previous_kept': bool}
FIELDS: tuple[str, ...] = tuple(_TYPES)


def _fail(name: str, why: str):
    raise CalibrationStateError(f'calibration_state field {name!r}: {why}')


def _check(d: dict) -> dict:
    unknown = sorted(set(d) - set(_TYPES))
    if unknown:
        raise CalibrationStateError(f'calibration_state has unknown fields {unknown} '
                                    f'(version {VERSION} has {list(FIELDS)})')
    for name, kind in _TYPES.items():
        if name not in d:
            _fail(name, 'missing')
        value = d[name]
        if kind is float and type(value) is int:
            value = d[name] = float(value)
        if type(value) is not kind:
            _fail(name, f'must be {kind.__name__}, got {type(value).__name__}')
        if kind is str and len(value) > MAX_TEXT:
            _fail(name, f'longer than {MAX_TEXT} characters')
        if kind is float and not math.isfinite(value):
            _fail(name, f'not finite ({value!r})')
    if d['version'] != VERSION:
        _fail('version', f'{d["version"]} is not supported (expected {VERSION})')
    if d['phase'] not in PHASES:
        _fail('phase', f'{d["phase"]!r} is not one of {list(PHASES)}')
    if d['direction'] not in ('',) + tuple(DIRECTIONS):
        _fail('direction', f'{d["direction"]!r} is not one of {list(DIRECTIONS)} or empty')
    if not 0 <= d['step'] <= d['steps']:
        _fail('step', f'{d["step"]} is not within 0..steps ({d["steps"]})')
    if d['pressure_kpa'] < 0.0:
        _fail('pressure_kpa', f'{d["pressure_kpa"]} is negative')
    if not 0.0 <= d['progress'] <= 1.0:
        _fail('progress', f'{d["progress"]} is not within 0..1')
    if d['phase'] in RUNNING and not d['direction']:
        _fail('direction', f'empty while the phase is {d["phase"]}')
    if d['phase'] == APPLY and d['step'] < 1:
        _fail('step', 'must be at least 1 while a step is applied')
    if d['phase'] == DONE and not d['file']:
        _fail('file', 'empty although the phase is done')
    if d['phase'] in (FAILED, REFUSED) and not d['error']:
        _fail('error', f'empty although the phase is {d["phase"]}')
    return d


def encode(state: CalibrationState) -> str:
    """The message text: one compact JSON object."""
    return json.dumps(asdict(state), separators=(',', ':'), allow_nan=False)


def decode(text: str) -> CalibrationState:
    """The state of a message text; CalibrationStateError (naming the field) for anything else."""
    if not isinstance(text, str):
        raise CalibrationStateError(f'calibration_state must be text, got {type(text).__name__}')
    if len(text) > 8 * MAX_TEXT:
        raise CalibrationStateError(f'calibration_state of {len(text)} characters is too long')
    try:
        d = json.loads(text, parse_constant=lambda c: _fail('(json)', f'{c} is not JSON'))
    except RecursionError:
        raise CalibrationStateError('calibration_state is nested too deeply') from None
    except ValueError as exc:
        if isinstance(exc, CalibrationStateError):
            raise
        raise CalibrationStateError(f'calibration_state is not JSON: {exc}') from None
    if type(d) is not dict:
        raise CalibrationStateError(f'calibration_state must be a JSON object, got {type(d).__name__}')
    return CalibrationState(**_check(d))


def of_procedure(wearer: str, proc: CalibrationProcedure, cmd: CalibrationCommand, *, file: str = '',
                 report: str = '', error: str = '', previous_kept: bool = False) -> CalibrationState:
    """The state after a tick of Algorithm 1: running (rest / apply) from the command; at its end
    done (with `file` and `report`) or, with `error` (the procedure's, or why the result could
    not be written), failed, or refused when a direction's fit was refused."""
    steps = len(proc.schedule)
    if cmd.phase in RUNNING:
        return CalibrationState(wearer, cmd.phase, cmd.direction or proc.direction or '', cmd.step, steps,
                                float(cmd.pressure), float(min(max(cmd.progress, 0.0), 1.0)))
    error = error or (proc.error or '' if cmd.phase == FAILED else '')
    if cmd.phase == DONE and not error:
        return CalibrationState(wearer, DONE, '', 0, steps, 0.0, 1.0, file=file, report=report)
    refused = next(iter(proc.refused), '') if proc.refused else ''
    return CalibrationState(wearer, REFUSED if refused else FAILED, refused, 0, steps, 0.0,
                            float(min(max(cmd.progress, 0.0), 1.0)), error=error or 'calibration failed',
                            previous_kept=previous_kept)


def failed(wearer: str, error: str, previous_kept: bool) -> CalibrationState:
    """A calibration ended from outside the procedure (the node vented or shut down)."""
    return CalibrationState(wearer, FAILED, error=error or 'calibration failed', previous_kept=previous_kept)


def prompt(state: CalibrationState) -> tuple[str, int, int]:
    """What the wearer is told (text, step, steps; docs/headset_wire_format.md `prompt`):
    face front and rest, hold still while a direction pulls, nothing otherwise."""
    if state.phase == REST:
        return 'Face front and rest', 0, state.steps
    if state.phase == APPLY:
        return f'Hold still: {state.direction}, step {state.step} of {state.steps}', state.step, state.steps
    return '', 0, 0
