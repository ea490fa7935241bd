"""What a study session's events produce (session.Session): the actions for the operator layer,
the finished trials and resolved presses of one event (a Step), and the samples and presses it
is given. Data only."""
from __future__ import annotations

from dataclasses import dataclass, field

from .plan import Block

#: What an Action asks of the operator layer.
ACTION_KINDS = (
    'set_condition',   # condition: switch the graph to it (layout, feedback mode, speech)
    'open_gate',       # the trial gate opens (after the rest): the trial starts
    'vent',            # the trial gate closes (suit vented) until the next 'open_gate'
    'show_target',     # target (azimuth, elevation) [deg], visible, target_id, dummy_set
    'found',           # speed: the accepted press identified the target (the headset's `found` event)
    'show_front',      # speed: the target is back at the front (0, 0)
    'hide',            # no target shown
    'prompt',          # text: what the wearer reads on the headset
    'done',            # the display's done event: text 'sequence', 'block' or 'session' (the last block)
)
#: What Step.presses tells of each resolved press: its stamp, receipt and source [s, steady
#: clock], the gaze sample's time, the error [deg] (full angle; h/v for accuracy), accepted,
#: and why not.
PRESS_KEYS = ('stamp', 'received', 'resolved', 'source', 'gaze_t', 'error_deg', 'h_error_deg', 'v_error_deg',
              'accepted', 'reason')

#: A trial row's status: only 'ok' rows enter the analysis.
STATUSES = ('ok', 'repeated', 'skipped', 'stopped', 'interrupted', 'vented')


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
    presses: list[dict] = field(default_factory=list)       # presses resolved now (PRESS_KEYS)
    pending: bool = False                                   # a press waits for its gaze sample
    ignored: str | None = None                              # the source of a press not judged (counted)


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
