"""calibration_state (core/calibration_state.py): the live calibration as fields, strictly
decoded; the states Algorithm 1 goes through; the wearer's prompt built from them."""
import json

import numpy as np
import pytest

from fabric_guidance.core import calibration_state as cs
from fabric_guidance.core.calibration import CalibrationProcedure, pressure_schedule

GOOD = cs.CalibrationState('alice', 'apply', 'left', 2, 10, 25.0, 0.3)


def test_a_state_round_trips_and_has_every_field():
    text = cs.encode(GOOD)
    assert set(json.loads(text)) == set(cs.FIELDS)
    assert cs.decode(text) == GOOD


def fields(**changes):
    d = json.loads(cs.encode(GOOD))
    d.update(changes)
    return json.dumps(d)


@pytest.mark.parametrize('text, field', [
    (fields(version=2), 'version'),
    (fields(phase='pressurize'), 'phase'),
    (fields(direction='back'), 'direction'),
    (fields(step=11), 'step'),
    (fields(step=0), 'step'),              # apply is a step >= 1
    (fields(step=1.0), 'step'),
    (fields(progress=1.5), 'progress'),
    (fields(pressure_kpa=-1), 'pressure_kpa'),
    (fields(pressure_kpa='25'), 'pressure_kpa'),
    (fields(previous_kept=1), 'previous_kept'),
    (fields(wearer=None), 'wearer'),
    (fields(phase='done'), 'file'),
    (fields(phase='failed'), 'error'),
    (fields(phase='rest', direction=''), 'direction'),
    (fields(extra=1), 'unknown fields'),
    (json.dumps({k: v for k, v in json.loads(cs.encode(GOOD)).items() if k != 'steps'}), 'steps'),
    (cs.encode(GOOD).replace('0.3', 'NaN'), 'NaN'),
    (cs.encode(GOOD).replace('0.3', '1e400'), 'progress'),
    ('[1]', 'object'),
    ('{', 'not JSON'),
])
def test_a_bad_state_is_refused_naming_its_field(text, field):
    with pytest.raises(cs.CalibrationStateError, match=field):
        cs.decode(text)


def test_the_states_of_a_calibration_and_the_prompts_they_give():
    proc = CalibrationProcedure('bob', steps=3, dwell_s=1.0, rest_s=1.0, record_window_s=0.5,
                                directions=['left'])
    states = []
    t = 0.0
    schedule = pressure_schedule(steps=3)
    angles = iter([0.0, 10.0, 20.0, 30.0])
    gaze = np.array([1.0, 0.0, 0.0])
    while proc.phase not in ('done', 'failed'):
        cmd = proc.tick(t, gaze)
        states.append(cs.of_procedure('bob', proc, cmd, file='/c/bob.yaml', report='/c/bob.txt'))
        t += 0.25
        if cmd.phase == 'apply' and t % 1.0 == 0.0:
            a = np.radians(next(angles, 30.0))
            gaze = np.array([np.cos(a), np.sin(a), 0.0])
    phases = [s.phase for s in states]
    assert phases[0] == 'rest' and 'apply' in phases and phases[-1] in ('done', 'failed', 'refused')
    rest = states[0]
    assert (rest.direction, rest.step, rest.steps) == ('left', 0, 3)
    assert cs.prompt(rest) == ('Face front and rest', 0, 3)
    applied = [s for s in states if s.phase == 'apply']
    assert {s.step for s in applied} == {1, 2, 3}
    assert {s.pressure_kpa for s in applied} == set(map(float, schedule))
    assert cs.prompt(applied[0]) == ('Hold still: left, step 1 of 3', 1, 3)
    assert cs.prompt(states[-1]) == ('', 0, 0)
    for s in states:
        assert cs.decode(cs.encode(s)) == s


def test_a_refused_fit_a_failure_and_an_unsaved_result_say_so():
    proc = CalibrationProcedure('bob', steps=3, directions=['left'])
    cmd = proc.fail('the gaze stream stopped for more than 0.5 s')
    s = cs.of_procedure('bob', proc, cmd, previous_kept=True)
    assert (s.phase, s.error, s.previous_kept) == ('failed', 'the gaze stream stopped for more than 0.5 s', True)
    proc.refused['left'] = 'R^2 0.2 below 0.8'
    s = cs.of_procedure('bob', proc, proc.fail('left: fit refused: R^2 0.2 below 0.8'), previous_kept=False)
    assert (s.phase, s.direction, s.previous_kept) == ('refused', 'left', False) and 'refused' in s.error
    vented = cs.failed('bob', 'vented by request', previous_kept=False)
    assert cs.decode(cs.encode(vented)).phase == 'failed'
    assert cs.prompt(vented) == ('', 0, 0)
    from fabric_guidance.core.calibration import CalibrationCommand
    unsaved = cs.of_procedure('bob', CalibrationProcedure('bob', steps=3),
                              CalibrationCommand('done', None, 0.0, 0, 1.0),
                              error='not saved: [Errno 28] No space left on device', previous_kept=True)
    assert (unsaved.phase, unsaved.file, unsaved.previous_kept) == ('failed', '', True)
