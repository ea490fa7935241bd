"""The chaos run with the study session (`fabric-guidance chaos --study`): its schedule, its
judge on synthetic register logs (a stop lifted before the operator's key is caught), and a
short seeded run on the simulated study graph held to every invariant, the registers judged
from the mock PLC's own log."""
import json

import pytest

from fabric_guidance.bench import chaos_study
from fabric_guidance.plc.register_log import Entry, gate_breaches, late_vents

ON, OFF = (2450, 2450, 0), (0, 0, 0)


def entries(*pairs):
    return [Entry(t, 'write', c, max(c)) for t, c in pairs]


def test_the_schedule_is_the_seeds_and_each_round_has_every_kind():
    a = chaos_study.schedule(5, 9)
    assert a == chaos_study.schedule(5, 9) and a != chaos_study.schedule(6, 9) and len(a) == 9
    for start in (0, 3, 6):
        assert sorted(p.kind for p in a[start:start + 3]) == sorted(chaos_study.KINDS)
    lo, hi = chaos_study.OPERATOR_S
    assert all(lo <= p.operator_s <= hi and p.operator_s > chaos_study.DEADLINE_S[p.kind] for p in a)


@pytest.mark.parametrize('kind', ['outside_vent', 'controller_kill'])
def test_pressure_before_the_operators_key_breaks_the_stop_and_none_does_not(kind):
    o = chaos_study.StudyOutcome(1, chaos_study.StudyFault(kind, 0.1, 2.0), t=10.0, t_enable=12.0)
    fault = o.fault()
    assert fault.t_end == fault.t_enable == 12.0 and fault.deadline_s == chaos_study.DEADLINE_S[kind]
    held = entries((9.0, ON), (10.3, OFF), (12.5, ON))
    assert late_vents(held, [fault], 13.0) == [] and gate_breaches(held, [fault]) == []
    # The session (or anything but the operator) put pressure back at 11 s, before the key at 12 s:
    # the vent did not hold until the fault's end (the key), so it is no vent (gate_breaches
    # leaves an unvented fault to late_vents: one line, not two).
    lifted = entries((9.0, ON), (10.3, OFF), (11.0, ON), (12.5, ON))
    (line,) = late_vents(lifted, [fault], 13.0)
    assert 'pressure again 1.000 s after it, before the fault ended at 2.000 s' in line
    # A vent later than the deadline.
    late = entries((9.0, ON), (10.0 + fault.deadline_s + 0.2, OFF), (12.5, ON))
    assert late_vents(late, [fault], 13.0)


def test_the_table_names_every_kind_with_its_worst_times():
    outcomes = [chaos_study.StudyOutcome(i, chaos_study.StudyFault(k, 0.0, 2.0), t=float(i), vent_s=v, held_s=h,
                                         recovery_s=r)
                for i, (k, v, h, r) in enumerate([('outside_vent', 0.05, 0.3, 4.0), ('outside_vent', 0.08, 0.2, 5.0),
                                                  ('controller_kill', 0.6, 1.1, 9.0)])]
    rows = chaos_study.table(outcomes)
    assert [r['count'] for r in rows] == [2, 1]
    assert rows[0]['worst_vent_s'] == 0.08 and rows[0]['worst_held_s'] == 0.3 and rows[0]['worst_recovery_s'] == 5.0
    text = chaos_study.markdown(rows, 5, 3, {'phase': 'done', 'planned': 3, 'vented': 2, 'trials_run': 3}, [])
    assert 'every invariant held' in text and '| SIGKILL of pressure_controller mid-trial' in text


@pytest.mark.graph
def test_a_short_seeded_chaos_run_with_the_study_session_holds_every_invariant(tmp_path):
    # Three faults, one of each kind, in a block of a running study session.
    rows, violations = chaos_study.run_study_chaos(3, 3, tmp_path, print)
    summary = json.loads((tmp_path / 'chaos.json').read_text())
    assert violations == [], (violations, summary['session_lines'])
    assert {r['kind'] for r in rows} == set(chaos_study.TITLE.values())
    for r in rows:
        assert r['worst_vent_s'] is not None and r['worst_vent_s'] <= r['deadline_s'], r
    for f in summary['faults_run']:
        if f['kind'] != 'foreign_writer':
            assert f['held_s'] is not None and f['held_s'] <= chaos_study.SESSION_HOLD_S, f
    session = summary['session']
    assert session['phase'] == 'done' and session['trials_run'] == session['planned'] and session['vented'] >= 1
    assert any('STOPPED' in line for line in summary['session_lines'])
