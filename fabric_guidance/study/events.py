"""A block's events, as BIDS events: one row per thing that happened in the run (the block's
attempt), with `onset` in seconds from the run's start and `duration` (0 for an instant).

Every Step of a Session goes through RecordedSession, which gives its actions, its resolved
presses, the presses refused or not judged before any gaze was looked at, and its finished trials
to the store (store.SessionStore.note), which writes them per run beside the trials file.

    trial_type      what happened                       value
    run_start       the run's start (onset 0)           its time in UTC: steady_s and this pair
                                                        the steady clock with wall-clock time
    condition       the block's condition set            the condition (1-4)
    enable / vent   guidance on (a trial starts) / off   -
    target_shown    a target set (speed: visible)        target_h_deg, target_v_deg
    front_shown     speed: the target back at the front  -
    hide            no target                            -
    press           a confirm press, at its capture      accepted, press_source, press_latency_s,
                    stamp                                error_deg; value: why refused
    target_found    speed: an accepted press             duration: since the target appeared
    prompt / done   the wearer's text / done event       the text
    trial           a trial, onset at its start          duration: to its end; value: its status
"""
from __future__ import annotations

import math

#: The events file's columns: (unit, description).
EVENT_COLUMNS: dict[str, tuple[str, str]] = {
    'onset': ('s', "from the run's start (the block's condition set): RunStartSteady_s in the sidecar"),
    'duration': ('s', 'how long it lasted: 0 for an instant'),
    'trial_type': ('-', 'what happened: run_start, condition, enable, vent, target_shown, front_shown, hide, '
                        'press, target_found, prompt, done, trial'),
    'value': ('-', "run_start: its UTC time (ISO 8601); the prompt's text, the condition, a trial's status, "
                   'why a press was refused'),
    'repetition': ('-', '0-based trial within the block, where a trial runs'),
    'target_h_deg': ('deg', 'the target set: azimuth from the front, positive left'),
    'target_v_deg': ('deg', 'the target set: elevation, positive up'),
    'accepted': ('-', 'a press: True when judged and accepted'),
    'press_source': ('-', "a press: its confirm's frame_id ('keyboard', 'headset', ...)"),
    'press_latency_s': ('s', 'a press: received minus captured'),
    'error_deg': ('deg', 'a judged press: the angle between the gaze at the press and the target'),
    'steady_s': ('s', 'the same instant on the steady clock of the trials file'),
}
ACTION_TYPES = {'set_condition': 'condition', 'enable': 'enable', 'vent': 'vent', 'show_target': 'target_shown',
                'show_front': 'front_shown', 'hide': 'hide', 'prompt': 'prompt', 'done': 'done'}
#: The Session's methods whose Steps are noted.
NOTED = ('start', 'tick', 'gaze', 'pause', 'resume', 'repeat', 'skip', 'stop')


def step_events(step, repetition: int | None, shown: dict, press: tuple | None = None) -> list[dict]:
    """The events of one Step, in order (steady-clock `steady_s`); `shown` keeps the last
    target's time between calls (for a find's duration); press: (stamp, received, source) of
    the press that made the step, if one did."""
    # Presses and finished trials first: what ends a block comes before the next block's
    # condition, which starts a new run (store.note).
    out = []
    for p in step.presses:
        e = {'trial_type': 'press', 'steady_s': p['stamp'], 'duration': 0.0, 'repetition': repetition,
             'accepted': bool(p['accepted']), 'press_source': p['source'],
             'press_latency_s': p['received'] - p['stamp'], 'error_deg': p['error_deg'],
             'value': p['reason'] or None}
        out.append(e)
        if p['accepted'] and shown.get('t') is not None and step.actions and \
                any(a.kind == 'show_front' for a in step.actions):
            out.append({'trial_type': 'target_found', 'steady_s': shown['t'], 'repetition': repetition,
                        'duration': p['stamp'] - shown['t']})
            shown['t'] = None
    if press is not None and not step.presses and not step.pending:
        stamp, received, source = press      # refused or not judged before its gaze was looked at
        out.append({'trial_type': 'press', 'steady_s': stamp, 'duration': 0.0, 'repetition': repetition,
                    'accepted': False, 'press_source': source, 'press_latency_s': received - stamp,
                    'value': step.refused or f'not judged: {source} is not a press source of this session'})
    for r in step.rows:
        start, end = r.get('trial_start_s'), r.get('trial_end_s')
        if start is None or not math.isfinite(start):
            continue
        out.append({'trial_type': 'trial', 'steady_s': start, 'repetition': r.get('repetition'),
                    'duration': (end - start) if end is not None else None, 'value': r.get('status')})
    for a in step.actions:
        if a.kind == 'found':     # the headset's flash: the press's target_found above says it
            continue
        kind = ACTION_TYPES.get(a.kind, a.kind)
        e = {'trial_type': kind, 'steady_s': a.t, 'duration': 0.0, 'repetition': repetition}
        if a.kind == 'set_condition':
            e['value'] = a.condition
        elif a.kind in ('prompt', 'done'):
            e['value'] = a.text
        elif a.kind == 'show_target':
            e['target_h_deg'], e['target_v_deg'] = a.target
            shown['t'] = a.t
        out.append(e)
    return out


class RecordedSession:
    """A Session whose every Step is also noted in `store` (store.note(block, events)); the
    rest of the Session (phase, block, design, status ...) as it is."""

    def __init__(self, session, store):
        self._session, self._store = session, store
        self._shown: dict = {}

    def __getattr__(self, name):
        method = getattr(self._session, name)
        if name not in NOTED:
            return method

        def noted(*args, **kwargs):
            return self._note(method(*args, **kwargs))
        return noted

    def press(self, stamp: float, received: float, source: str = 'keyboard'):
        return self._note(self._session.press(stamp, received, source), (stamp, received, source))

    def _note(self, step, press=None):
        if step.actions or step.presses or step.rows or press is not None:
            trial = self._session.trial
            self._store.note(self._session.block, step_events(step, trial.repetition if trial else None,
                                                              self._shown, press))
        return step
