"""The study session as a state machine on a fake clock: order, timing, acceptance, the error at
the press time, stale and duplicate presses, the operator's commands, and that guidance is off
between trials."""
from __future__ import annotations

import pytest

from fabric_guidance.study.plan import StudyDesign, condition_order, participant_blocks
from fabric_guidance.study.session import ROW_FIELDS, Session, Step
from study_participant import FRAME_S, drive  # noqa: E402 (test/ is on sys.path)


def speed_session(trials=2, trial_s=10.0, **kw):
    d = StudyDesign('speed', seed=3, trials=trials, trial_s=trial_s, rest_s=1.0, **kw)
    return Session(d, participant_blocks(d, 'P1', 2), {'gaze_source': 'test'})


def accuracy_session(trials=2, **kw):
    d = StudyDesign('accuracy', seed=3, trials=trials, rest_s=1.0, timeout_s=5.0, **kw)
    return Session(d, participant_blocks(d, 'P1', 2), {'gaze_source': 'test'})


def into_trial(s: Session, t0=10.0) -> float:
    """Start and tick to the first trial; returns its start time."""
    s.start(t0)
    s.tick(t0 + 1.0)
    assert s.phase == 'target'
    return t0 + 1.0


def test_blocks_in_the_participants_order_and_trials_of_exactly_trial_s():
    s = speed_session()
    steps: list[Step] = []
    rows = drive(s, on_step=steps.append)
    assert s.phase == 'done'
    assert [r['condition'] for r in rows] == [c for c in condition_order(s.design, 2) for _ in range(2)]
    assert [r['repetition'] for r in rows] == [0, 1] * 4
    assert all(set(r) == set(ROW_FIELDS) for r in rows)
    for r in rows:
        assert r['trial_end_s'] - r['trial_start_s'] == pytest.approx(10.0, abs=1e-9)   # on the event clock
        assert r['status'] == 'ok' and r['identified'] >= 5 and r['presented'] in (r['identified'], r['identified'] + 1)
        assert 0.6 <= r['mean_find_s'] <= 0.6 + 0.1 + 2 * FRAME_S
        assert r['press_source'] == 'keyboard' and r['press_age_s'] == pytest.approx(0.006)
        assert r['gaze_source'] == 'test' and r['wearer'] == 'P1' and r['subject'] == 2
    done = [a.text for st in steps for a in st.actions if a.kind == 'done']
    assert done.count('sequence') == 8 and done.count('block') == 4      # per sequence, per block
    assert done.count('session') == 1 and done[-1] == 'session'           # and once when the blocks end
    assert [a.condition for st in steps for a in st.actions if a.kind == 'set_condition'] == \
        list(condition_order(s.design, 2))
    assert [b.key for st in steps for b in st.blocks] == [b.key for b in s.blocks]


def test_guidance_is_off_between_trials():
    """After a trial's end, nothing opens the trial gate until the next trial starts rest_s later."""
    s = speed_session()
    steps = []
    drive(s, on_step=steps.append)
    actions = [a for st in steps for a in st.actions]
    on = False
    last_vent = None
    for a in actions:
        if a.kind == 'vent':
            on, last_vent = False, a.t
        elif a.kind == 'open_gate':
            assert not on
            assert a.t - last_vent >= s.design.rest_s - 1e-9
            on = True
        elif a.kind == 'done' and a.text == 'sequence':
            assert not on, 'the trial ended without a vent before it'


def test_a_speed_trial_ends_at_trial_s_exactly_even_with_a_late_tick():
    s = speed_session(trial_s=40.0)
    t0 = into_trial(s)
    assert s.next_deadline() == t0 + 40.0
    assert not s.tick(t0 + 39.999).rows
    st = s.tick(t0 + 40.5)                       # a late tick: the trial still lasted 40 s
    assert st.rows[0]['trial_end_s'] - st.rows[0]['trial_start_s'] == 40.0
    assert st.rows[0]['identified'] == 0 and st.rows[0]['presented'] == 1
    assert [a.kind for a in st.actions][:3] == ['vent', 'hide', 'done'] and s.phase == 'rest'


def test_acceptance_at_the_press_and_the_return_to_the_front():
    s = speed_session()
    t = into_trial(s)
    h, v = s._trial['target']
    s.gaze(t + 0.5, h, v + 6.0)                  # 6 deg off: refused
    st = s.press(t + 0.5, t + 0.505)
    assert st.refused and 'error 6.0 deg > acceptance 5 deg' in st.refused and s.phase == 'target'
    s.gaze(t + 1.0, h, v - 4.0)                  # 4 deg off: accepted
    st = s.press(t + 1.0, t + 1.005)
    assert st.refused is None and st.presses[0]['accepted'] and s.phase == 'front'
    # the headset's found event first, then the target goes back to the front
    assert [a.kind for a in st.actions] == ['found', 'show_front']
    assert st.actions[0].target == (h, v)
    assert s.press(t + 1.5, t + 1.5).refused.endswith('look at the front for the next one')
    s.gaze(t + 1.6, 0.5, 0.5)
    assert s.phase == 'front'
    s.gaze(t + 1.6 + s.design.front_dwell_s - 0.01, 0.5, 0.5)
    assert s.phase == 'front'                    # not yet the dwell
    st = s.gaze(t + 1.6 + s.design.front_dwell_s, 0.2, 0.1)
    assert s.phase == 'target' and st.actions[0].kind == 'show_target' and st.actions[0].target != (h, v)
    assert st.actions[0].dummy_set == 2          # new dummies for the new target
    row = s.tick(t + 10.0).rows[0]
    assert (row['identified'], row['presented'], row['refused_presses']) == (1, 2, 2)
    assert row['mean_find_s'] == pytest.approx(1.0)


def test_the_error_is_taken_at_the_press_time_not_from_a_later_sample():
    s = accuracy_session()
    t = into_trial(s)
    h, v = s._trial['target']
    s.gaze(t + 2.0, h + 1.0, v - 2.0)            # where the wearer was when they pressed
    s.gaze(t + 2.011, h + 10.0, v + 10.0)        # later samples: they moved on
    st = s.press(t + 2.005, t + 2.02)            # arrives after the later sample
    row = st.rows[0]
    assert row['h_error_deg'] == pytest.approx(1.0) and row['v_error_deg'] == pytest.approx(2.0)
    assert row['gaze_at_press_s'] == t + 2.0 and row['time_s'] == pytest.approx(2.005)
    assert row['timed_out'] is False and row['press_age_s'] == pytest.approx(0.015)


def test_a_press_stamped_with_its_frames_capture_time_is_judged_on_that_frame():
    """gaze_bridge maps a press and a gaze sample of one capture time microseconds apart, either
    way: the press is judged on its own frame, not on the one before (12 of 12 presses were)."""
    s = accuracy_session(trials=3)
    t = into_trial(s)
    h, v = s._trial['target']
    s.gaze(t + 2.000, h + 5.0, v)                 # the frame before
    s.gaze(t + 2.011, h + 1.0, v)                 # the press's frame, mapped 3 us after the press
    row = s.press(t + 2.011 - 3e-6, t + 2.02).rows[0]
    assert row['h_error_deg'] == pytest.approx(1.0) and row['gaze_at_press_s'] == t + 2.011
    # a press between two frames is still judged on the frame before it
    t = into_next_trial(s)
    h, v = s._trial['target']
    s.gaze(t + 2.000, h + 5.0, v)
    s.gaze(t + 2.011, h + 1.0, v)
    row = s.press(t + 2.010, t + 2.02).rows[0]
    assert row['h_error_deg'] == pytest.approx(5.0) and row['gaze_at_press_s'] == t + 2.0


def into_next_trial(s: Session) -> float:
    """Tick through the rest to the next trial; returns its start time."""
    t = s.next_deadline()
    s.tick(t)
    assert s.phase == 'target'
    return t


def test_a_press_ahead_of_its_gaze_sample_waits_for_it():
    s = accuracy_session()
    t = into_trial(s)
    h, v = s._trial['target']
    s.gaze(t + 2.0, h + 3.0, v)
    st = s.press(t + 2.008, t + 2.009)           # its sample (at or before 2.008) may still come
    assert st.pending and not st.rows
    st = s.gaze(t + 2.005, h + 1.5, v)           # the sample at the press, arriving late
    assert st.pending is False and not st.rows   # still not known there is none closer
    st = s.gaze(t + 2.016, h + 20.0, v)          # past the stamp: judged on the 2.005 sample
    assert st.rows[0]['h_error_deg'] == pytest.approx(1.5)


def test_stale_duplicate_and_out_of_trial_presses_are_refused_with_a_reason():
    s = speed_session(max_press_age_s=0.2, debounce_s=0.15)
    assert 'no trial is running (phase idle)' in s.press(1.0, 1.0).refused
    t = into_trial(s)
    h, v = s._trial['target']
    s.gaze(t + 1.0, h, v)
    assert 'stale: captured 0.300 s before it arrived' in s.press(t + 0.7, t + 1.0).refused
    assert 'in the future' in s.press(t + 2.0, t + 1.0).refused
    assert s.press(t + 1.0, t + 1.01).refused is None                       # found
    s.gaze(t + 1.05, 0, 0)
    assert 'duplicate: the same press again' in s.press(t + 1.0, t + 1.06).refused
    assert 'duplicate: 0.050 s after the last press' in s.press(t + 1.05, t + 1.06).refused
    assert s.tick(t + 10.0).rows[0]['refused_presses'] == 4
    assert 'no trial is running (phase rest)' in s.press(t + 10.2, t + 10.2).refused


def test_no_gaze_at_the_press_refuses_it():
    s = accuracy_session(gaze_gap_s=0.05)
    t = into_trial(s)
    s.gaze(t + 1.0, 0.0, 0.0)
    st = s.press(t + 1.2, t + 1.2)
    assert st.pending
    st = s.tick(t + 1.2 + s.design.max_press_age_s)
    assert 'no gaze sample within 0.05 s before the press' in st.refused and s.phase == 'target'


def test_gaze_history_is_bounded():
    s = accuracy_session(gaze_history_s=0.5)
    into_trial(s)
    for k in range(2000):
        s.gaze(20.0 + k * FRAME_S, 0.0, 0.0)
    assert len(s._history) <= 0.5 / FRAME_S + 2
    assert not s.gaze(20.0, 1.0, 1.0).rows and s._history[-1].t > 20.0      # out of order: ignored


def test_an_accuracy_trial_times_out_with_the_gaze_at_the_timeout():
    s = accuracy_session()
    t = into_trial(s)
    h, v = s._trial['target']
    s.gaze(t + 4.9, h - 7.0, v + 3.0)
    s.gaze(t + 4.95, h - 6.0, v + 3.0)
    row = s.tick(t + 5.2).rows[0]
    assert row['timed_out'] is True and row['time_s'] == 5.0 and row['trial_end_s'] == t + 5.0
    assert row['h_error_deg'] == pytest.approx(6.0) and row['v_error_deg'] == pytest.approx(3.0)
    assert (row['target_h_deg'], row['target_v_deg']) == (h, v)


def test_accuracy_targets_are_unseen_and_from_the_plan():
    s = accuracy_session()
    st = s.start(0.0)
    st = s.tick(1.0)
    shown = [a for a in st.actions if a.kind == 'show_target'][0]
    assert shown.visible is False and shown.target == s.blocks[0].trials[0].target


def test_pause_abandons_the_trial_and_resume_reruns_it():
    s = speed_session()
    t = into_trial(s)
    st = s.pause(t + 3.0)
    assert [a.kind for a in st.actions][:2] == ['vent', 'hide'] and s.phase == 'paused'
    assert st.rows[0]['status'] == 'repeated' and st.rows[0]['repetition'] == 0
    assert not s.tick(t + 100.0).actions and s.phase == 'paused'            # holds
    assert s.resume(t + 100.0).refused is None and s.phase == 'rest'
    s.tick(t + 101.0)
    assert s.phase == 'target' and s.trial.repetition == 0
    assert s.resume(t + 101.0).refused


def test_repeat_now_or_the_last_trial_and_skip():
    s = speed_session(trials=3)
    t = into_trial(s)
    st = s.repeat(t + 2.0)
    assert st.rows[0]['status'] == 'repeated' and s.phase == 'rest' and s.trial.repetition == 0
    s.tick(t + 3.0)
    st = s.tick(t + 13.0)                                                   # repetition 0 done
    assert st.rows[0]['status'] == 'ok' and s.trial.repetition == 1
    st = s.repeat(t + 13.5)                                                 # in the rest: the last one
    assert st.amended == [(s.block.key, 0, 'repeated')] and s.trial.repetition == 0
    assert s.repeat(t + 13.6).refused                                       # not twice
    st = s.skip(t + 13.7)                                                   # skip the next one
    assert st.rows[0]['status'] == 'skipped' and st.rows[0]['repetition'] == 0 and s.trial.repetition == 1
    s.tick(t + 15.0)
    st = s.skip(t + 16.0)                                                   # skip the running one
    assert st.rows[0]['status'] == 'skipped' and st.rows[0]['identified'] is None
    assert st.actions[0].kind == 'vent' and s.trial.repetition == 2


def test_stop_vents_first_and_leaves_the_block_unfinished():
    s = speed_session()
    t = into_trial(s)
    st = s.stop(t + 2.0)
    assert st.actions[0].kind == 'vent' and s.phase == 'stopped'
    assert st.rows[0]['status'] == 'stopped' and not st.blocks
    assert s.stop(t + 3.0).refused and s.press(t + 3.0, t + 3.0).refused
    assert not s.tick(t + 50.0).actions


def test_hold_between_blocks_waits_for_the_operator():
    s = speed_session(trials=1, hold_between_blocks=True)
    t = into_trial(s)
    st = s.tick(t + 10.0)
    assert st.blocks and s.phase == 'paused'
    assert [a.kind for a in st.actions][:4] == ['vent', 'hide', 'done', 'done']
    assert 'set_condition' in [a.kind for a in st.actions]
    assert not s.tick(t + 60.0).actions
    s.resume(t + 60.0)
    s.tick(t + 61.0)
    assert s.phase == 'target' and s.block.order == 2


def test_status_for_the_terminal():
    s = speed_session(trial_s=40.0)
    t = into_trial(s)
    st = s.status(t + 12.5)
    assert st['participant'] == 'P1' and st['trial'] == '1/2' and st['block'] == '1/4'
    assert st['time_left_s'] == pytest.approx(27.5) and st['phase'] == 'target'


def test_a_press_pending_at_the_trial_end_is_judged_not_dropped():
    s = speed_session(trial_s=10.0)
    t = into_trial(s)
    h, v = s._trial['target']
    s.gaze(t + 9.99, h, v)
    assert s.press(t + 9.995, t + 9.999).pending
    st = s.tick(t + 10.0)                        # the trial ends before a later sample came
    assert st.presses and st.presses[0]['accepted'] and st.rows[0]['identified'] == 1
    assert st.rows[0]['trial_end_s'] == t + 10.0


def test_the_gaze_history_has_a_hard_cap():
    s = accuracy_session()
    into_trial(s)
    for k in range(3 * 2000):
        s.gaze(20.0 + k * 1e-6, 0.0, 0.0)        # stamps a microsecond apart: time alone would keep all
    assert len(s._history) == 2000


def test_the_context_goes_into_the_rows_and_can_change():
    s = accuracy_session()
    s.set_context(clock_state='synced', calibration_file='P1.yaml', calibration_sha256='ab' * 32)
    with pytest.raises(ValueError, match='unknown key'):
        s.set_context(colour='red')
    t = into_trial(s)
    first = s.skip(t + 1.0).rows[0]
    s.set_context(clock_state='free')
    s.tick(t + 3.0)
    second = s.skip(t + 4.0).rows[0]
    assert (first['clock_state'], second['clock_state']) == ('synced', 'free')
    assert second['calibration_file'] == 'P1.yaml' and second['gaze_source'] == 'test'
    assert Session(s.design, []).start(0.0).refused == 'nothing to run: every block of this session is done'


def _regular_gaze(s: Session, t0: float, n: int, frame_s: float, yaw: float, pitch: float) -> float:
    for k in range(n):
        s.gaze(t0 + k * frame_s, yaw, pitch)
    return t0 + (n - 1) * frame_s


def _regular_trial():
    """An accuracy trial with 40 gaze samples at 90 Hz 2 deg left of its target."""
    s = accuracy_session()
    t = into_trial(s)
    h, v = s._trial['target']
    frame = 1.0 / 90.0
    return s, h, v, frame, _regular_gaze(s, t + 1.0, 40, frame, h + 2.0, v)


def test_a_press_early_in_a_regular_frame_is_judged_at_once_on_the_sample_before_it():
    s, h, v, frame, last = _regular_trial()
    st = s.press(last + 0.5 * frame, last + 0.5 * frame + 0.001)      # mid-frame: no sample can be between
    assert not st.pending and st.rows and st.rows[0]['h_error_deg'] == pytest.approx(2.0)
    assert st.rows[0]['gaze_at_press_s'] == last


def test_a_press_late_in_a_frame_or_on_an_irregular_stream_waits_for_the_next_sample():
    s, h, v, frame, last = _regular_trial()
    st = s.press(last + 0.9 * frame, last + 0.9 * frame + 0.001)      # the next sample may be on its way
    assert st.pending and not st.rows
    st = s.gaze(last + 0.85 * frame, h + 4.0, v)                      # it was: captured before the press
    assert st.rows and st.rows[0]['h_error_deg'] == pytest.approx(4.0)
    # Too few samples to know the stream's frame: the press waits.
    s2 = accuracy_session()
    t2 = into_trial(s2)
    s2.gaze(t2 + 1.0, 0.0, 0.0)
    assert s2.press(t2 + 1.001, t2 + 1.002).pending


def test_a_sample_arriving_after_an_early_press_settles_it_without_a_later_frame():
    """The press overtook its frame's sample (gaze takes the longer path): the sample's arrival
    settles the press at once, no need to wait for the frame after it."""
    s, h, v, frame, last = _regular_trial()
    st = s.press(last + 1.2 * frame, last + 1.2 * frame + 0.001)
    assert st.pending
    st = s.gaze(last + frame, h + 3.0, v)                           # the press's own frame, arriving late
    assert st.rows and st.rows[0]['h_error_deg'] == pytest.approx(3.0)


def test_a_timer_that_catches_up_now_and_then_does_not_shrink_the_frame():
    """Two samples 1 ms apart among 90 Hz ones (a late timer catching up): the frame stays ~11 ms."""
    s, h, v, frame, last = _regular_trial()
    s.gaze(last + 0.001, h + 2.0, v)
    last += 0.001
    st = s.press(last + 0.5 * frame, last + 0.5 * frame + 0.001)
    assert not st.pending and st.rows[0]['gaze_at_press_s'] == last


class HeadsetPressing(Session):
    """A session that also gets a press from the headset every few gaze samples, on the gaze
    the wearer has then (on target once they look at it: a press that would be accepted), and
    keeps what each of those presses produced."""
    EVERY = 5

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.samples, self.extra = 0, []

    def gaze(self, t, yaw, pitch):
        step = super().gaze(t, yaw, pitch)
        self.samples += 1
        if self.samples % self.EVERY == 0:
            self.extra.append(super().press(t, t + 0.003, 'headset'))
        return step


def test_a_press_from_a_source_not_judged_changes_no_result():
    d = StudyDesign('speed', seed=3, trials=2, trial_s=10.0, rest_s=1.0, press_sources=('keyboard',))
    plain = drive(Session(d, participant_blocks(d, 'P1', 2), {'gaze_source': 'test'}))
    noisy = HeadsetPressing(d, participant_blocks(d, 'P1', 2), {'gaze_source': 'test'})
    rows = drive(noisy)
    counted = [st for st in noisy.extra if st.ignored]
    assert counted and all(st.ignored == 'headset' for st in counted)
    for st in noisy.extra:       # nothing judged, refused or done for any of them
        assert not (st.actions or st.rows or st.presses or st.blocks or st.amended or st.pending)
        assert st.refused is None
    assert [r['ignored_presses'] for r in plain] == [0] * len(plain)
    assert sum(r['ignored_presses'] for r in rows) == len(counted)         # the ones in a trial
    assert all(r['ignored_presses'] > 0 for r in rows)

    def strip(rs):
        return [{k: v for k, v in r.items() if k != 'ignored_presses'} for r in rs]
    assert strip(rows) == strip(plain)
    # The same presses judged (every source) do change the results: the test above can fail.
    judged = drive(HeadsetPressing(d.with_(press_sources=()), participant_blocks(d, 'P1', 2), {'gaze_source': 'test'}))
    assert strip(judged) != strip(plain) and {r['press_source'] for r in judged} == {'headset'}


def test_press_sources_by_the_confirms_frame_id():
    s = speed_session(press_sources=('ros',))
    t = into_trial(s)
    h, v = s._trial['target']
    s.gaze(t + 0.5, h, v)
    assert s.press(t + 0.5, t + 0.505, 'keyboard').ignored == 'keyboard'
    st = s.press(t + 0.5, t + 0.505, 'foot_pedal')          # another sender on the interface: ros
    assert st.ignored is None and st.presses[0]['accepted'] and s.phase == 'front'
    assert speed_session().design.judges('anything') and speed_session().press(1.0, 1.0, 'x').ignored is None
