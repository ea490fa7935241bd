"""A study session as a pure state machine: events in (each with an explicit steady-clock
timestamp in seconds), actions and finished trials out. No threads, no ROS, no clock of its
own: the operator layer calls the event methods as things happen and carries out the actions
(the suit vented, the guidance enabled, a target shown, a prompt for the wearer); a test drives
it with a fake clock.

Every event method returns a Step: the actions to carry out (in order), the trial rows finished
by this event (to be written at once, store.SessionStore.append), the blocks finished, and for
a refused press or command the reason (one line).

Phases: 'idle' (before start), 'rest' (between trials, suit vented), 'target' (a trial runs,
the target is shown), 'front' (speed: the target is back at the front, waiting for the gaze),
'paused', 'stopped', 'done'.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
import math
from typing import Sequence

from .plan import Block, StudyDesign, TrialSpec, target_stream

#: What an Action asks of the operator layer.
ACTION_KINDS = (
    'set_condition',   # condition: switch the graph to it (layout, feedback mode, speech)
    'enable',          # guidance on (after the vent hold): the trial starts
    'vent',            # suit vented, guidance held off until the next 'enable'
    'show_target',     # target (azimuth, elevation) [deg], visible, target_id, dummy_set
    'show_front',      # speed: the target is back at the front (0, 0)
    'hide',            # no target shown
    'prompt',          # text: what the wearer reads on the headset
    'done',            # the display's done event: text 'sequence' or 'block'
)
#: A trial row's status: only 'ok' rows enter the analysis.
STATUSES = ('ok', 'repeated', 'skipped', 'stopped', 'interrupted')


@dataclass(frozen=True)
class Action:
    kind: str                                   # one of ACTION_KINDS
    t: float                                    # event time it was decided at [s, steady clock]
    condition: int | None = None
    target: tuple[float, float] | None = None   # (azimuth, elevation) [deg], positive left / up
    target_id: str | None = None                # 'target', 'front'
    visible: bool | None = None                 # accuracy: False (the unseen target)
    dummy_set: int | None = None                # speed: a new set of dummies per target
    text: str | None = None                     # prompt text; done: 'sequence' or 'block'


@dataclass
class Step:
    """What one event produced."""

    actions: list[Action] = field(default_factory=list)
    rows: list[dict] = field(default_factory=list)          # finished trials (session.ROW_FIELDS)
    blocks: list[Block] = field(default_factory=list)       # finished blocks
    refused: str | None = None                              # a refused press or command, why
    amended: list[tuple[str, int, str]] = field(default_factory=list)  # (block key, repetition, new status)


@dataclass(frozen=True)
class GazeSample:
    t: float                # capture time [s, steady clock]
    yaw_deg: float          # positive left
    pitch_deg: float        # positive up


@dataclass(frozen=True)
class Press:
    stamp: float            # capture time at its source [s, steady clock]
    received: float         # when the session got it [s, steady clock]
    source: str             # 'keyboard', 'ros', 'headset'


class Session:
    """The session over `blocks` (those still to run, in order; store.SessionStore.remaining
    gives them after a restart). `context` holds what every row carries unchanged (gaze source,
    clock state, calibration file and sha256, package version and commit; store.LIVE_CONTEXT)."""

    def __init__(self, design: StudyDesign, blocks: Sequence[Block], context: dict | None = None):
        raise NotImplementedError

    # -- state -----------------------------------------------------------------------------
    @property
    def phase(self) -> str:
        """'idle', 'rest', 'target', 'front', 'paused', 'stopped' or 'done'."""
        raise NotImplementedError

    @property
    def block(self) -> Block | None:
        """The block running (or next), None when done."""
        raise NotImplementedError

    @property
    def trial(self) -> TrialSpec | None:
        raise NotImplementedError

    def status(self, t: float) -> dict:
        """What the operator's terminal shows: participant, condition, trial i of n (1-based),
        time left [s] of a speed trial (or until the accuracy timeout), phase, last result."""
        raise NotImplementedError

    def next_deadline(self) -> float | None:
        """The steady-clock time [s] the next tick must come by (trial end, rest end, a pending
        press's limit); None when nothing is timed."""
        raise NotImplementedError

    # -- events ----------------------------------------------------------------------------
    def start(self, t: float) -> Step:
        """Begin: set the first block's condition, vent, rest, then its first trial."""
        raise NotImplementedError

    def tick(self, t: float) -> Step:
        """Time passed (call by next_deadline()): a speed trial ends at exactly trial start +
        trial_s, an accuracy trial at its timeout, a rest ends and the next trial starts."""
        raise NotImplementedError

    def gaze(self, t: float, yaw_deg: float, pitch_deg: float) -> Step:
        """A gaze sample captured at t [s]: kept in a bounded history (design.gaze_history_s)
        for the error at a press; in 'front' it may let the next target appear. Out-of-order
        samples (t not after the last) are ignored."""
        raise NotImplementedError

    def press(self, stamp: float, received: float, source: str = 'keyboard') -> Step:
        """A confirm press captured at `stamp` at its source, received at `received` [s]. Refused
        (Step.refused) when stale (received - stamp > max_press_age_s), a duplicate (the same
        stamp again, or within debounce_s of the last press), outside a trial, or (speed) with
        an error above acceptance_deg. The error is that of the last gaze sample at or before
        `stamp`; when that sample has not arrived yet the press waits for it (until
        max_press_age_s after the stamp)."""
        raise NotImplementedError

    # -- operator commands -----------------------------------------------------------------
    def pause(self, t: float) -> Step:
        """Vent and hold; a trial running is abandoned (recorded 'repeated') and rerun on resume."""
        raise NotImplementedError

    def resume(self, t: float) -> Step:
        """From 'paused' (or held between blocks): rest, then the next trial."""
        raise NotImplementedError

    def repeat(self, t: float) -> Step:
        """Run the current trial again (abandoned now, recorded 'repeated'), or in the rest after
        a trial, the last finished one (its row amended to 'repeated', Step.amended)."""
        raise NotImplementedError

    def skip(self, t: float) -> Step:
        """Give up the current (or next) trial: recorded 'skipped', the session moves on."""
        raise NotImplementedError

    def stop(self, t: float) -> Step:
        """Vent at once and end the session; the running block is unfinished (redone on resume)."""
        raise NotImplementedError
