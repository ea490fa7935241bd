"""A study session as a pure state machine: events in (each with an explicit steady-clock
timestamp in seconds), actions and finished trials out. No threads, no ROS, no clock of its
own: the operator layer calls the event methods as things happen and carries out the actions
(the trial gate closed or opened, a target shown, a prompt for the wearer); a test drives it
with a fake clock. The session never arms the controller: pressure flows only while the
operator's arm is on as well (a person's `enable`); when it drops (disarmed) the session holds
until the operator has armed again (arm).

Every event method returns a Step: the actions to carry out (in order), the trial rows finished
by this event (to be written at once, store.SessionStore.append), the blocks finished, and for
a refused press or command the reason (one line).

Phases: 'idle' (before start), 'rest' (between trials, suit vented), 'target' (a trial runs,
the target is shown), 'front' (speed: the target is back at the front, waiting for the gaze),
'paused', 'held' (the operator's arm dropped: waits for the operator), 'stopped', 'done'.
"""
from __future__ import annotations

from collections import deque
import math
from typing import Sequence

from ..core.geometry import wrap_deg
from ..sim.wearer import angle_between_deg
from .plan import Block, StudyDesign, TrialSpec, target_stream
from .steps import ACTION_KINDS, PRESS_KEYS, STATUSES, Action, GazeSample, Press, Step  # noqa: F401 (re-exported)
from .trial_columns import CONTEXT_COLUMNS, RECORD_COLUMNS, SESSION_COLUMNS

#: The columns a session fills (store adds the rest).
ROW_FIELDS = tuple(RECORD_COLUMNS) + tuple(SESSION_COLUMNS) + tuple(CONTEXT_COLUMNS)
#: The most gaze samples kept, whatever their stamps (2 s at 1 kHz).
MAX_GAZE_SAMPLES = 2000
#: A press captured less than this share of a gaze frame after the newest sample is judged at
#: once: a sample captured between the two would have to come sooner than the stream nearly
#: ever does (the frame is the 10th percentile of its last FRAME_SAMPLES intervals: a timer that
#: catches up now and then does not shrink it), so none can still be on its way. Later in the
#: frame the press waits for a sample captured after it.
EARLY_SHARE = 0.75
FRAME_SAMPLES = 32
#: A sample captured up to this after a press's stamp was captured at the press [s]:
#: gaze_bridge maps each datagram's capture time with the clocks read as it handles that
#: datagram, so a press and a sample of one capture time get stamps microseconds apart, either
#: way (a press stamped with its frame's capture time was judged on the frame before). Half a
#: millisecond is half a frame at 1 kHz, a twentieth at 90 Hz.
SAME_CAPTURE_S = 0.0005


class Session:
    """The session over `blocks` (those still to run, in order; store.SessionStore.remaining
    gives them after a restart). `context` holds what every row carries unchanged (gaze source,
    clock state, calibration file and sha256, package version and commit:
    trial_columns.LIVE_CONTEXT; 'scene' names the study)."""

    def __init__(self, design: StudyDesign, blocks: Sequence[Block], context: dict | None = None):
        self.design = design
        self.blocks = tuple(blocks)
        for b in self.blocks:
            if b.protocol != design.protocol:
                raise ValueError(f'block {b.key}: protocol {b.protocol}, the design is {design.protocol}')
        self.context: dict = {}
        self.set_context(**(context or {}))
        self._phase = 'idle' if self.blocks else 'done'
        self._bi = 0                       # block index
        self._ti = 0                       # trial index within the block
        # bounded by time (gaze_history_s) and, whatever the stamps, by count
        self._history: deque[GazeSample] = deque(maxlen=MAX_GAZE_SAMPLES)
        self._rest_end: float | None = None
        self._paused_from: str | None = None
        self._last_stamp: float | None = None
        self._pending: Press | None = None
        self._last_done: tuple[str, int] | None = None   # (block key, repetition) of the last row
        self._last_result = ''
        self._dummy_set = 0
        self._trial: dict | None = None
        self._hold: str | None = None      # why the session holds for the operator's arm

    def set_context(self, **values) -> None:
        """Change what the next rows carry (e.g. the clock state as it changes); ValueError for a
        key that is not a context column."""
        unknown = sorted(set(values) - set(CONTEXT_COLUMNS) - {'scene'})
        if unknown:
            raise ValueError(f'session context: unknown key(s) {", ".join(unknown)}')
        self.context.update(values)

    # -- state -----------------------------------------------------------------------------
    @property
    def phase(self) -> str:
        """'idle', 'rest', 'target', 'front', 'paused', 'held', 'stopped' or 'done'."""
        return self._phase

    @property
    def block(self) -> Block | None:
        """The block running (or next), None when done."""
        return self.blocks[self._bi] if self._bi < len(self.blocks) else None

    @property
    def trial(self) -> TrialSpec | None:
        b = self.block
        return b.trials[self._ti] if b is not None and self._ti < len(b.trials) else None

    def status(self, t: float) -> dict:
        """What the operator's terminal shows: participant, condition, trial i of n (1-based),
        time left [s] of a speed trial (or until the accuracy timeout), phase, last result."""
        b = self.block
        left = max(0.0, self._trial['end'] - t) if self._trial is not None else None
        return {'phase': self._phase, 'participant': b.participant if b else None,
                'condition': b.condition if b else None, 'block': f'{self._bi + 1}/{len(self.blocks)}',
                'trial': f'{min(self._ti + 1, len(b.trials))}/{len(b.trials)}' if b else None,
                'time_left_s': left, 'identified': self._trial['identified'] if self._trial else None,
                'last_result': self._last_result, 'hold': self._hold}

    def next_deadline(self) -> float | None:
        """The steady-clock time [s] the next tick must come by (trial end, rest end, a pending
        press's limit); None when nothing is timed."""
        times = []
        if self._trial is not None:
            times.append(self._trial['end'])
        if self._phase == 'rest' and self._rest_end is not None:
            times.append(self._rest_end)
        if self._pending is not None:
            times.append(self._pending.stamp + self.design.max_press_age_s)
        return min(times) if times else None

    # -- events ----------------------------------------------------------------------------
    def start(self, t: float) -> Step:
        """Begin: set the first block's condition, vent, rest, then its first trial."""
        step = Step()
        if not self.blocks:
            step.refused = 'nothing to run: every block of this session is done'
        elif self._phase != 'idle':
            step.refused = f'the session has already started (phase {self._phase})'
        if step.refused is None:
            self._enter_block(t, step)
        return step

    def tick(self, t: float) -> Step:
        """Time passed (call by next_deadline()): a speed trial ends at exactly trial start +
        trial_s, an accuracy trial at its timeout, a rest ends and the next trial starts."""
        step = Step()
        self._advance(t, step)
        return step

    def gaze(self, t: float, yaw_deg: float, pitch_deg: float) -> Step:
        """A gaze sample captured at t [s]: kept in a bounded history (design.gaze_history_s)
        for the error at a press; in 'front' it may let the next target appear. Out-of-order
        samples (t not after the last) and non-finite ones are ignored."""
        step = Step()
        if not (math.isfinite(t) and math.isfinite(yaw_deg) and math.isfinite(pitch_deg)):
            return step
        if self._history and t <= self._history[-1].t:
            return step
        self._advance(t, step)
        h = self._history
        h.append(GazeSample(t, yaw_deg, pitch_deg))
        while h and t - h[0].t > self.design.gaze_history_s:
            h.popleft()
        if self._pending is not None and self._sample_settled(self._pending.stamp):
            self._resolve(t, step)
        if self._phase == 'front' and self._trial is not None:
            tr = self._trial
            if angle_between_deg(yaw_deg, pitch_deg, 0.0, 0.0) <= self.design.acceptance_deg:
                tr['inside_since'] = t if tr['inside_since'] is None else tr['inside_since']
                if t - tr['inside_since'] >= self.design.front_dwell_s - 1e-9:
                    self._show_next(t, step)
            else:
                tr['inside_since'] = None
        return step

    def press(self, stamp: float, received: float, source: str = 'keyboard') -> Step:
        """A confirm press captured at `stamp` at its source, received at `received` [s]. A press
        from a source the design does not judge (design.press_sources) changes nothing: it is
        counted in the running trial's ignored_presses (Step.ignored names it). Refused
        (Step.refused) when stale (received - stamp > max_press_age_s), a duplicate (the same
        stamp again, or within debounce_s of the last press), outside a trial, or (speed) with
        an error above acceptance_deg. The error is that of the last gaze sample at or before
        `stamp`; when that sample has not arrived yet the press waits for it (until
        max_press_age_s after the stamp; Step.pending)."""
        step = Step()
        if not self.design.judges(source):
            if self._trial is not None:
                self._trial['ignored'] += 1
                step.ignored = source
            return step
        if not (math.isfinite(stamp) and math.isfinite(received)):
            step.refused = f'press from {source}: its time is not a number'
            return step
        self._advance(received, step)
        d = self.design
        age = received - stamp
        reason = None
        if age > d.max_press_age_s:
            reason = f'stale: captured {age:.3f} s before it arrived (limit {d.max_press_age_s:g} s)'
        elif age < -d.max_press_age_s:
            reason = f'stamped {-age:.3f} s in the future: the source clock is not synchronised'
        elif self._last_stamp is not None and stamp <= self._last_stamp:
            reason = 'duplicate: the same press again (not after the last press)'
        elif self._last_stamp is not None and stamp - self._last_stamp < d.debounce_s:
            reason = f'duplicate: {stamp - self._last_stamp:.3f} s after the last press (debounce {d.debounce_s:g} s)'
        elif self._pending is not None:
            reason = 'duplicate: the last press still waits for its gaze sample'
        elif self._phase not in ('target', 'front') or self._trial is None:
            reason = f'no trial is running (phase {self._phase})'
        elif self._phase == 'front':
            reason = 'the target is back at the front: look at the front for the next one'
        elif stamp < self._trial['appeared']:
            reason = 'captured before the target appeared'
        if reason is not None:
            if self._trial is not None:
                self._trial['refused'] += 1
            step.refused = f'press from {source} refused: {reason}'
            return step
        self._last_stamp = stamp
        self._pending = Press(stamp, received, source)
        if self._sample_settled(stamp):
            self._resolve(received, step)
        else:
            step.pending = True
        return step

    def restart_rest(self, t: float) -> None:
        """A rest under way starts again at t: the operator layer's switch to a block's condition
        (and its recorder) took its time, which must shorten no rest."""
        if self._phase == 'rest':
            self._rest_end = t + self.design.rest_s

    # -- operator commands -----------------------------------------------------------------
    def pause(self, t: float) -> Step:
        """Vent and hold; a trial running is abandoned (recorded 'repeated') and rerun on resume."""
        step = Step()
        self._advance(t, step)
        if self._phase not in ('rest', 'target', 'front'):
            step.refused = f'pause: nothing to pause (phase {self._phase})'
            return step
        self._halt(t, 'repeated', step)
        self._phase, self._rest_end = 'paused', None
        return step

    def resume(self, t: float) -> Step:
        """From 'paused' (or held between blocks): rest, then the next trial."""
        step = Step()
        if self._phase == 'held':
            step.refused = f"resume: the operator's arm is off ({self._hold}): the operator arms first (key e)"
            return step
        if self._phase != 'paused':
            step.refused = f'resume: the session is not paused (phase {self._phase})'
            return step
        self._rest(t, step)
        return step

    def repeat(self, t: float) -> Step:
        """Run the current trial again (abandoned now, recorded 'repeated'), or in the rest after
        a trial, the last finished one (its row amended to 'repeated', Step.amended)."""
        step = Step()
        self._advance(t, step)
        if self._trial is not None:
            self._abandon(t, 'repeated', step)
            self._rest(t, step)
            return step
        b = self.block
        if self._phase not in ('rest', 'paused') or b is None:
            step.refused = f'repeat: no trial to repeat (phase {self._phase})'
            return step
        if self._ti == 0 or self._last_done != (b.key, b.trials[self._ti - 1].repetition):
            step.refused = 'repeat: no finished trial in this block to repeat'
            return step
        self._ti -= 1
        step.amended.append((b.key, b.trials[self._ti].repetition, 'repeated'))
        self._last_done = None
        self._last_result = f'trial {self._ti + 1} to be repeated'
        return step

    def skip(self, t: float) -> Step:
        """Give up the current (or next) trial: recorded 'skipped', the session moves on."""
        step = Step()
        self._advance(t, step)
        if self._trial is not None:
            self._abandon(t, 'skipped', step)
        elif self._phase == 'rest' and self.trial is not None:
            step.rows.append(self._row(self.trial, 'skipped', None, t, t, {}))
            self._last_done = None
        else:
            step.refused = f'skip: no trial to skip (phase {self._phase})'
            return step
        self._last_result = f'trial {self._ti + 1} skipped'
        self._next_trial(t, step)
        return step

    def _halt(self, t: float, status: str, step: Step) -> None:
        """Pause or hold: the running trial ends recorded `status` (vented with it), or the suit
        vents; the wearer is asked to wait."""
        if self._trial is not None:
            self._abandon(t, status, step)
        else:
            step.actions.append(Action('vent', t))
        step.actions.append(Action('prompt', t, text='Paused: please wait'))

    def disarmed(self, t: float, why: str) -> Step:
        """The operator's arm dropped (an outside vent, a controller restart, a lost controller):
        the running trial ends now, recorded 'vented', and the session holds until arm()."""
        step = Step()
        if self._phase in ('idle', 'held', 'stopped', 'done'):
            self._hold = why if self._phase == 'held' else self._hold
            return step
        self._halt(t, 'vented', step)
        self._phase, self._rest_end, self._hold = 'held', None, why
        self._last_result = f'held: {why}'
        return step

    def arm(self, t: float) -> Step:
        """The operator has armed the controller again (their key called enable): a held session
        rests, then runs its next trial (a trial cut off is run again)."""
        step = Step()
        if self._phase != 'held':
            step.refused = f'arm: the session is not waiting for the arm (phase {self._phase})'
            return step
        self._hold = None
        self._rest(t, step)
        return step

    def stop(self, t: float) -> Step:
        """Vent at once and end the session; the running block is unfinished (redone on resume)."""
        step = Step()
        if self._phase in ('stopped', 'done'):
            step.refused = f'stop: the session has already ended (phase {self._phase})'
            return step
        step.actions.append(Action('vent', t))      # first: nothing waits before the vent
        if self._trial is not None:
            self._abandon(t, 'stopped', step, vent=False)
        step.actions.append(Action('prompt', t, text='Stopped: thank you'))
        self._phase, self._pending, self._rest_end = 'stopped', None, None
        return step

    # -- inside ----------------------------------------------------------------------------
    def _advance(self, t: float, step: Step) -> None:
        """Whatever is due by t: a pending press past its limit, a trial's end, a rest's end."""
        d = self.design
        if self._pending is not None and t >= self._pending.stamp + d.max_press_age_s:
            self._resolve(t, step)
        tr = self._trial
        if tr is not None and t >= tr['end'] and self._pending is not None and self._pending.stamp <= tr['end']:
            self._resolve(t, step)      # pressed in time: judged on the samples there are
            tr = self._trial
        if tr is not None and t >= tr['end']:
            if d.protocol == 'speed':
                self._finish_speed(t, step)
            else:
                self._finish_accuracy(t, None, step)
        if self._phase == 'rest' and self._rest_end is not None and t >= self._rest_end:
            self._begin_trial(t, step)

    def _enter_block(self, t: float, step: Step) -> None:
        b = self.block
        step.actions.append(Action('vent', t))
        step.actions.append(Action('set_condition', t, condition=b.condition))
        self._ti = 0
        self._last_done = None
        if self.design.hold_between_blocks and (self._phase != 'idle'):
            step.actions.append(Action('prompt', t, text=f'Condition {b.order} of {len(self.blocks)}: please wait'))
            self._phase, self._rest_end = 'paused', None
        else:
            self._rest(t, step)

    def _rest(self, t: float, step: Step) -> None:
        self._phase, self._rest_end = 'rest', t + self.design.rest_s
        b = self.block
        step.actions.append(Action('prompt', t, text=f'Rest: trial {self._ti + 1} of {len(b.trials)} is next'))

    def _begin_trial(self, t: float, step: Step) -> None:
        spec, b = self.trial, self.block
        d = self.design
        self._rest_end = None
        tr = dict(spec=spec, start=t, appeared=t, identified=0, presented=1, finds=[], refused=0, ignored=0,
                  presses=0, last_press=None, inside_since=None,
                  end=t + (d.trial_s if d.protocol == 'speed' else d.timeout_s))
        if d.protocol == 'speed':
            tr['targets'] = target_stream(d, b.index, spec.repetition)
            tr['target'] = next(tr['targets'])
            self._dummy_set += 1
            step.actions.append(Action('show_target', t, target=tr['target'], target_id='target', visible=True,
                                       dummy_set=self._dummy_set))
            text = 'Find the target and press when it is in the centre'
        else:
            tr['target'] = spec.target
            step.actions.append(Action('show_target', t, target=spec.target, target_id='target', visible=False))
            text = 'Follow the suit and press when you think you are there'
        step.actions.append(Action('open_gate', t))
        step.actions.append(Action('prompt', t, text=f'Trial {self._ti + 1} of {len(b.trials)}: {text}'))
        self._trial = tr
        self._phase = 'target'

    def _show_next(self, t: float, step: Step) -> None:
        tr = self._trial
        tr['target'] = next(tr['targets'])
        tr['presented'] += 1
        tr['appeared'], tr['inside_since'] = t, None
        self._dummy_set += 1
        step.actions.append(Action('show_target', t, target=tr['target'], target_id='target', visible=True,
                                   dummy_set=self._dummy_set))
        self._phase = 'target'

    def _frame_s(self) -> float | None:
        """The gaze stream's frame: the 10th percentile of its last FRAME_SAMPLES intervals
        (None: too few samples yet)."""
        h = self._history
        if len(h) <= FRAME_SAMPLES:
            return None
        recent = [h[i].t for i in range(len(h) - FRAME_SAMPLES - 1, len(h))]
        frame = sorted(b - a for a, b in zip(recent, recent[1:]))[FRAME_SAMPLES // 10]
        return frame if frame > 0.0 else None

    def _sample_settled(self, stamp: float) -> bool:
        """Whether the sample at or before `stamp` is known: one captured after it has come, or
        the stamp is early in the newest sample's frame (EARLY_SHARE)."""
        h = self._history
        if not h:
            return False
        if h[-1].t >= stamp:
            return True
        frame = self._frame_s()
        return frame is not None and stamp - h[-1].t < EARLY_SHARE * frame

    def _sample_at(self, stamp: float) -> GazeSample | None:
        """The last gaze sample captured at stamp (up to SAME_CAPTURE_S after it) or before it."""
        for s in reversed(self._history):
            if s.t <= stamp + SAME_CAPTURE_S:
                return s
        return None

    def _resolve(self, t: float, step: Step) -> None:
        """Judge the pending press on the gaze sample at its stamp."""
        p, self._pending = self._pending, None
        tr, d = self._trial, self.design
        out = dict(stamp=p.stamp, received=p.received, resolved=t, source=p.source, gaze_t=None, error_deg=None,
                   h_error_deg=None, v_error_deg=None, accepted=False, reason='')
        step.presses.append(out)
        s = self._sample_at(p.stamp)
        if tr is None or self._phase != 'target':
            out['reason'] = 'the trial ended before its gaze sample came'
        elif s is None or p.stamp - s.t > d.gaze_gap_s:
            out['reason'] = f'no gaze sample within {d.gaze_gap_s:g} s before the press'
        else:
            h, v = tr['target']
            out.update(gaze_t=s.t, error_deg=angle_between_deg(s.yaw_deg, s.pitch_deg, h, v),
                       h_error_deg=abs(wrap_deg(s.yaw_deg - h)), v_error_deg=abs(s.pitch_deg - v))
            if d.protocol == 'speed' and out['error_deg'] > d.acceptance_deg:
                out['reason'] = f'error {out["error_deg"]:.1f} deg > acceptance {d.acceptance_deg:g} deg'
            else:
                out['accepted'] = True
        if not out['accepted']:
            if tr is not None:
                tr['refused'] += 1
            step.refused = f'press from {p.source} refused: {out["reason"]}'
            return
        tr['presses'] += 1
        tr['last_press'] = out
        if d.protocol == 'accuracy':
            self._finish_accuracy(t, out, step)
            return
        tr['identified'] += 1
        tr['finds'].append(p.stamp - tr['appeared'])
        self._last_result = f'target {tr["identified"]} found ({out["error_deg"]:.1f} deg)'
        step.actions.append(Action('found', t, target=tr['target'], target_id='target'))
        step.actions.append(Action('show_front', t, target=(0.0, 0.0), target_id='front', visible=True))
        self._phase, tr['inside_since'] = 'front', None

    def _finish_speed(self, t: float, step: Step) -> None:
        tr = self._trial
        finds = tr['finds']
        measures = dict(identified=tr['identified'], presented=tr['presented'],
                        mean_find_s=sum(finds) / len(finds) if finds else None)
        self._last_result = f'{tr["identified"]} identified of {tr["presented"]}'
        self._end_trial(t, 'ok', tr['end'], measures, step)

    def _finish_accuracy(self, t: float, press: dict | None, step: Step) -> None:
        tr = self._trial
        h, v = tr['target']
        if press is None:           # timed out: the gaze where it was at the timeout
            s = self._sample_at(tr['end'])
            he = abs(wrap_deg(s.yaw_deg - h)) if s else None
            ve = abs(s.pitch_deg - v) if s else None
            end, time_s, timed_out = tr['end'], self.design.timeout_s, True
        else:
            he, ve = press['h_error_deg'], press['v_error_deg']
            end, time_s, timed_out = t, press['stamp'] - tr['start'], False
        measures = dict(target_h_deg=h, target_v_deg=v, h_error_deg=he, v_error_deg=ve, tracked_h_error_deg=he,
                        tracked_v_error_deg=ve, time_s=time_s, timed_out=timed_out)
        self._last_result = ('timed out' if timed_out else
                             f'error h {he:.1f} deg, v {ve:.1f} deg in {time_s:.1f} s')
        self._end_trial(t, 'ok', end, measures, step)

    def _abandon(self, t: float, status: str, step: Step, vent: bool = True) -> None:
        """The running trial ends now without its measures."""
        tr = self._trial
        if vent:
            step.actions.append(Action('vent', t))
        step.actions.append(Action('hide', t))
        step.rows.append(self._row(tr['spec'], status, tr, tr['start'], t, {}))
        self._trial, self._pending = None, None
        self._last_done = None
        self._last_result = f'trial {self._ti + 1} {status}'

    def _end_trial(self, t: float, status: str, end: float, measures: dict, step: Step) -> None:
        tr = self._trial
        step.actions.append(Action('vent', t))
        step.actions.append(Action('hide', t))
        step.actions.append(Action('done', t, text='sequence'))
        step.rows.append(self._row(tr['spec'], status, tr, tr['start'], end, measures))
        self._trial, self._pending = None, None
        self._last_done = (self.block.key, tr['spec'].repetition)
        self._next_trial(t, step)

    def _next_trial(self, t: float, step: Step) -> None:
        b = self.block
        self._ti += 1
        if self._ti < len(b.trials):
            self._rest(t, step)
            return
        step.blocks.append(b)
        step.actions.append(Action('done', t, text='block'))
        self._bi += 1
        if self._bi < len(self.blocks):
            self._enter_block(t, step)
        else:
            step.actions.append(Action('done', t, text='session'))
            step.actions.append(Action('prompt', t, text='Done: thank you'))
            self._phase, self._rest_end = 'done', None

    def _row(self, spec: TrialSpec, status: str, tr: dict | None, start: float, end: float, measures: dict) -> dict:
        b = self.block
        row = dict.fromkeys(ROW_FIELDS)
        row.update(scene=self.context.get('scene', 'study'), protocol=b.protocol, subject=b.index,
                   wearer=b.participant, condition=b.condition, repetition=spec.repetition, order=b.order,
                   session=b.session, status=status, block=b.key, trial_start_s=start, trial_end_s=end)
        if b.protocol == 'accuracy' and spec.target is not None:
            row.update(target_h_deg=spec.target[0], target_v_deg=spec.target[1])
        if tr is not None:
            row.update(presses=tr['presses'], refused_presses=tr['refused'], ignored_presses=tr['ignored'])
            p = tr['last_press']
            if p is not None:
                row.update(press_s=p['stamp'], press_source=p['source'], press_age_s=p['received'] - p['stamp'],
                           gaze_at_press_s=p['gaze_t'])
        row.update(measures)
        row.update({k: v for k, v in self.context.items() if k in CONTEXT_COLUMNS})
        return row
