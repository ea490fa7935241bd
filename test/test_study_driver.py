"""SessionDriver without a graph: a fake operator records what the driver asks of the graph, in
order, so the order of the trial's preparation against its gate's opening can be checked."""
from collections import deque
import threading
import time

from fabric_guidance.live_study.driver import SessionDriver, target_phases
from fabric_guidance.study.plan import StudyDesign, participant_blocks
from fabric_guidance.study.session import Session


class FakeOperator:
    def __init__(self, log):
        self.log, self.lock, self.gaze, self.gaze_total = log, threading.Lock(), [], 0

    def now_ns(self):
        return time.monotonic_ns()

    def drain_presses(self):
        return []

    controller_started = '1'

    def trial_gate(self, on):
        self.log.append(('gate', on, time.monotonic()))
        return ''

    def arm_dropped(self, started):
        return ''

    def show_target(self, yaw, pitch, wait=True):
        self.log.append(('show', (yaw, pitch), time.monotonic()))

    def to_front(self, wait=True):
        self.log.append(('front', None, time.monotonic()))

    def display(self, line):
        pass


class FakeStore:
    def record(self, step):
        pass


def test_the_next_trial_is_prepared_in_the_rest_before_it_not_at_its_start():
    # Before: before_trial ran inside the trial's enable, after its target was shown, so the
    # simulated wearer started afresh after the trial's clock had started (and its key press
    # model took the new target on the old side's clock).
    design = StudyDesign('speed', conditions=(1, 3), trials=2, trial_s=0.2, rest_s=0.15)
    log = []
    driver = SessionDriver(FakeOperator(log), Session(design, participant_blocks(design, '01', 0)), FakeStore(),
                           set_condition=lambda c: log.append(('condition', c, time.monotonic())),
                           before_trial=lambda c, r: log.append(('prepare', (c, r), time.monotonic())))
    driver.run()
    kinds = [k for k, *_ in log]
    assert kinds.count('prepare') == 4
    for i, (kind, value, t) in enumerate(log):
        if kind == 'show':
            # the trial's preparation came before its target, and at least most of a rest before
            prep = max(j for j in range(i) if log[j][0] == 'prepare')
            assert t - log[prep][2] >= 0.1, log
            assert not any(log[j][0] == 'gate' and log[j][1] for j in range(prep, i)), log
    # each block's trials with its own condition, repetitions in order
    assert [v for k, v, _ in log if k == 'prepare'] == [(c, r) for c in
                                                        [b.condition for b in participant_blocks(design, '01', 0)]
                                                        for r in (0, 1)]


def test_target_phases_pair_each_found_target_with_its_return():
    events = [('target', 0.0, 0.05), ('press', 0.8, 0.87, True), ('front', 0.87, 0.92), ('target', 1.5, 1.55),
              ('press', 1.9, 1.95, False), ('vent', 2.0, 2.01), ('target', 5.0, 5.05), ('press', 5.5, 5.56, True)]
    ph = target_phases(events)
    assert ph['find'] == [0.8, 0.5] and [round(x, 3) for x in ph['press_wait']] == [0.07, 0.06]
    assert [round(x, 3) for x in ph['front_return']] == [0.58]      # not across the trial's end
    assert len(ph['target_call']) == 3 and len(ph['front_call']) == 1


def test_press_latency_is_kept_with_each_press_source():
    from fabric_guidance.study.session import Step
    design = StudyDesign('speed', conditions=(1,), trials=1)
    driver = SessionDriver(FakeOperator([]), Session(design, participant_blocks(design, '01', 0)), FakeStore())
    now = time.monotonic()
    presses = [dict(stamp=now - 0.004, source='keyboard', accepted=True),
               dict(stamp=now - 0.006, source='headset', accepted=False),
               dict(stamp=now - 0.002, source='keyboard', accepted=False)]
    driver.handle(Step(presses=presses))
    t = driver.timing
    assert t.press_sources == ['keyboard', 'headset', 'keyboard'] and len(t.press_latency_s) == 3
    by = t.press_latency_by_source()
    assert sorted(by) == ['headset', 'keyboard'] and len(by['keyboard']) == 2
    assert by['headset'][0] > by['keyboard'][0] > by['keyboard'][1] > 0


class PhaseSession:
    """A session whose phase a test sets; counts how often it is read."""
    def __init__(self):
        self._phase, self.reads = 'rest', 0

    @property
    def phase(self):
        self.reads += 1
        return self._phase


def test_the_timing_runs_keyboard_presses_only_while_a_target_is_shown(monkeypatch):
    from types import SimpleNamespace
    from fabric_guidance.graph.process_graph import wait_until
    from fabric_guidance.live_study import timing
    monkeypatch.setattr(timing, 'KEY_INTERVAL_S', (0.002, 0.005))
    session = PhaseSession()
    pressed = []
    op = SimpleNamespace(press_key=lambda source: pressed.append((source, session._phase)))
    stop = threading.Event()
    sent = timing.press_keys(op, SimpleNamespace(session=session), 5, 0, stop)
    wait_until(lambda: session.reads >= 5, 5.0, what='the key thread reading the phase')
    assert pressed == [] and sent['sent'] == 0          # the rest: no press
    session._phase = 'target'
    sent['thread'].join(5.0)
    assert not sent['thread'].is_alive() and sent['sent'] == 5     # `keys` presses, then it ends
    assert pressed == [('keyboard', 'target')] * 5
    stop.set()


def test_presses_from_a_source_not_judged_are_reported_once_per_trial_and_counted_in_its_row():
    from fabric_guidance.live_study.operator import Press
    design = StudyDesign('speed', conditions=(1,), trials=2, trial_s=0.3, rest_s=0.05, press_sources=('keyboard',))

    class Pressing(FakeOperator):
        """Three headset presses in each trial, one per poll."""
        sent: dict = {}

        def drain_presses(self):
            tr = driver.session._trial
            if driver.session.phase != 'target' or self.sent.get(tr['start'], 0) >= 3:
                return []
            self.sent[tr['start']] = self.sent.get(tr['start'], 0) + 1
            now = time.monotonic_ns()
            return [Press('headset', now - 2_000_000, now)]
    lines = []
    op = Pressing([])
    driver = SessionDriver(op, Session(design, participant_blocks(design, '01', 0)), FakeStore(), lines.append,
                           set_condition=lambda c: None)
    rows = driver.run()
    assert [r['ignored_presses'] for r in rows] == [3, 3] and [r['refused_presses'] for r in rows] == [0, 0]
    said = [line for line in lines if 'ignored' in line]
    assert said == ['  ignored 3 press(es) from headset (3): not a press source of this session (keyboard)'] * 2
    assert driver.timing.press_latency_s == []       # none was judged


class History(deque):
    """A gaze history that counts the samples a reader visits (iteration either way, indexing)."""
    visited = 0

    def __iter__(self):
        for s in super().__iter__():
            History.visited += 1
            yield s

    def __reversed__(self):
        for s in super().__reversed__():
            History.visited += 1
            yield s

    def __getitem__(self, i):
        History.visited += 1
        return super().__getitem__(i)


class HistoryOperator(FakeOperator):
    """Operator.gaze as _on_gaze keeps it: appended in order of receipt, counted, trimmed at the left."""
    def __init__(self):
        super().__init__([])
        self.gaze = History()

    def receive(self, stamp_ns, keep=None):
        with self.lock:
            self.gaze.append((stamp_ns, (0.0, 0.0, 1.2), (1.0, 0.0, 0.0)))
            self.gaze_total += 1
            while keep is not None and len(self.gaze) > keep:
                self.gaze.popleft()


class GazeLog:
    def __init__(self):
        self.fed = []

    def gaze(self, t, yaw, pitch):
        from fabric_guidance.study.session import Step
        self.fed.append(t)
        return Step()

    phase = 'rest'
    block = trial = None


def test_feed_gaze_feeds_each_new_sample_once_in_order_without_visiting_the_history():
    # Before: every 2 ms poll went through the whole history (5 s at 90 Hz or more) under the lock.
    op = HistoryOperator()
    driver = SessionDriver(op, GazeLog(), FakeStore())
    driver._offset_s = 0.0
    ms = 1_000_000
    for k in range(20_000):                          # a long history, all of it before the start
        op.receive(k * ms)
    driver._last_gaze_ns, driver._gaze_seen = 20_000 * ms, op.gaze_total     # as run() starts
    History.visited = 0
    driver.feed_gaze()
    assert driver.session.fed == [] and History.visited == 0
    op.receive(20_001 * ms)
    op.receive(20_002 * ms)
    op.receive(20_001 * ms + 500_000)                # captured before the last: left out, as before
    op.receive(20_003 * ms, keep=20_000)             # the history trimmed at the left meanwhile
    driver.feed_gaze()
    assert History.visited == 4                      # the four new samples, nothing older
    driver.feed_gaze()                               # nothing new: nothing fed, nothing visited
    assert History.visited == 4
    assert [round(t, 6) for t in driver.session.fed] == [20.001, 20.002, 20.003]
    for k in range(20_004, 20_010):                  # more than one poll's worth, fed once each
        op.receive(k * ms, keep=100)
    driver.feed_gaze()
    assert [round(t * 1e3) for t in driver.session.fed] == [20_001, 20_002, 20_003, *range(20_004, 20_010)]
    assert History.visited == 4 + 6


class SlowCall:
    """A PendingCall whose answer comes `delay_s` after it was sent, or a refusal."""

    def __init__(self, delay_s, refuse=''):
        self.sent, self.delay_s, self.refuse, self.done_at = time.monotonic(), delay_s, refuse, None

    def done(self):
        from fabric_guidance.live_study.operator import OperatorError
        if time.monotonic() - self.sent < self.delay_s:
            return False
        if self.refuse:
            raise OperatorError(self.refuse)
        self.done_at = self.done_at or time.monotonic()
        return True

    def wait(self):
        while not self.done():
            time.sleep(0.001)


class SlowTargetSelector(FakeOperator):
    def __init__(self, log, delay_s, refuse=''):
        super().__init__(log)
        self.delay_s, self.refuse, self.polls = delay_s, refuse, []

    def show_target(self, yaw, pitch, wait=True):
        super().show_target(yaw, pitch)
        assert not wait              # the driver never blocks its loop on the target's call
        return SlowCall(self.delay_s, self.refuse)

    def to_front(self, wait=True):
        super().to_front()
        assert not wait
        return SlowCall(self.delay_s, self.refuse)

    def drain_presses(self):
        self.polls.append(time.monotonic())
        return []

    def set_condition(self, condition):
        pass


def test_the_loop_goes_on_while_target_selector_answers_and_the_phase_ends_at_the_answer():
    # Before, the target's parameter call blocked the loop: no gaze sample and no press was
    # judged until target_selector answered (tens of ms under load).
    design = StudyDesign('speed', conditions=(1,), trials=1, trial_s=0.5, rest_s=0.05)
    op = SlowTargetSelector([], delay_s=0.1)
    driver = SessionDriver(op, Session(design, participant_blocks(design, '01', 0)), FakeStore())
    driver.run()
    shown = next(t for k, _, t in op.log if k == 'show')
    assert sum(1 for t in op.polls if shown < t < shown + 0.09) >= 10     # polled every ~2 ms meanwhile
    target = next(e for e in driver.timing.events if e[0] == 'target')
    assert target[2] - target[1] >= 0.1                                   # carried out at the answer


def test_a_refused_target_call_stops_the_driver_with_the_reason():
    import pytest
    from fabric_guidance.live_study.operator import OperatorError
    design = StudyDesign('speed', conditions=(1,), trials=1, trial_s=0.5, rest_s=0.05)
    op = SlowTargetSelector([], delay_s=0.01, refuse='target_selector refused [active_target]: no such target')
    driver = SessionDriver(op, Session(design, participant_blocks(design, '01', 0)), FakeStore())
    with pytest.raises(OperatorError, match='no such target'):
        driver.run()


def test_the_timer_error_is_kept_when_a_gaze_sample_ends_the_trial():
    # Before, the timer error was read only when the loop's tick ended the trial; a gaze sample
    # captured after the deadline, fed first, ended it without a figure (the bench's quick study
    # then had one timer error for two trials).
    design = StudyDesign('speed', conditions=(1,), trials=2, trial_s=0.3, rest_s=0.05)
    op = FakeOperator([])
    op.set_condition = lambda c: None
    running = threading.Event()
    running.set()

    def stream():
        while running.is_set():
            with op.lock:
                op.gaze.append((time.monotonic_ns(), (0.0, 0.0, 1.2), (1.0, 0.0, 0.0)))
                op.gaze_total += 1
            time.sleep(0.004)
    feeder = threading.Thread(target=stream, daemon=True)
    feeder.start()
    try:
        driver = SessionDriver(op, Session(design, participant_blocks(design, '01', 0)), FakeStore())
        driver.run()
    finally:
        running.clear()
        feeder.join(1.0)
    errors = driver.timing.timer_error_s
    assert len(errors) == 2 and all(0.0 <= e < 0.1 for e in errors), errors


def test_a_slow_block_start_shortens_no_rest_and_comes_after_the_last_rows_on_disk():
    """A block's bag recorder took 1-4 s to start in the rest: the previous trial's row was written
    after it and the next trial started on a queued sample's time, its rest cut short."""
    design = StudyDesign('speed', conditions=(1, 3), trials=1, trial_s=0.2, rest_s=0.15)
    log, said = [], []

    class SlowStore(FakeStore):
        def record(self, step):
            log.append(('record', len(step.rows), time.monotonic()))

    def set_condition(c):           # the condition, then a recorder that takes 0.6 s to start
        log.append(('condition', c, time.monotonic()))
        time.sleep(0.6)
        log.append(('ready', c, time.monotonic()))
    driver = SessionDriver(FakeOperator(log), Session(design, participant_blocks(design, '01', 0)), SlowStore(),
                           say=lambda line: said.append(line) or log.append(('say', line, time.monotonic())),
                           set_condition=set_condition)
    rows = driver.run()
    assert len(rows) == 2
    kinds = [k for k, *_ in log]
    for i, (kind, _c, t_ready) in enumerate(log):
        if kind == 'ready':
            opened = next(t for k, on, t in log[i:] if k == 'gate' and on)
            assert opened >= t_ready + design.rest_s      # the whole rest after the start
    # the first block's row is on disk and said before the second block's condition is set
    second = [i for i, (k, c, _t) in enumerate(log) if k == 'condition'][1]
    assert 'record' in kinds[:second]
    assert any(k == 'say' and 'trial 1: ok' in str(v) for k, v, _t in log[:second])
    # and the rows' trial start is the gate's opening, not a time inside the slow start
    readies = [t for k, _c, t in log if k == 'ready']
    for row, ready in zip(rows, readies):
        assert row['trial_start_s'] >= ready + design.rest_s
