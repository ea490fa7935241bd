"""What a participant does, decided before the session: their condition order, the blocks (one
condition of one participant) and the trials of each block with their targets.

Random numbers are those of the headless experiment (sim/protocols.py) for the same seed and
participant index: the condition order of the 'random' design is sim.protocols.condition_order's
and the targets of repetition r are drawn from the same stream in every condition (common random
numbers), so a live study and `fabric-guidance experiment` on the same seed present the same
targets in the same order.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields, replace
import math
import re
from typing import Iterator, Sequence

import numpy as np

from ..core.conditions import condition as condition_of
from ..core.safe_input import check_wearer, excerpt
from ..sim.effects import generator

PROTOCOLS = ('speed', 'accuracy')
ORDERS = ('random', 'latin')
#: A participant id is a file name (<id>.yaml, its calibration) and a BIDS label (sub-<id>):
#: letters and digits only, since "_" and "-" separate a BIDS file name's entities.
PARTICIPANT_PATTERN = re.compile(r'[A-Za-z0-9]{1,64}')
#: The confirm press's sources, by the frame_id of its `confirm`: the operator's key, the
#: headset's clicker or air tap (gaze_bridge), wearer_sim publishing itself; 'ros' is any other
#: sender on the interface (another tool, a script: whatever frame_id it gives, or none).
PRESS_SOURCES = ('keyboard', 'headset', 'wearer_sim', 'ros')


def press_source_kind(frame_id: str) -> str:
    """The PRESS_SOURCES name of a confirm with this frame_id."""
    return frame_id if frame_id in PRESS_SOURCES else 'ros'


def parse_press_sources(text: str) -> tuple[str, ...]:
    """'all' (or '') -> () (every source); else a comma list of PRESS_SOURCES, sorted, each
    once; ValueError naming an unknown one."""
    names = [n.strip() for n in str(text).split(',') if n.strip()]
    if not names or names == ['all']:
        return ()
    unknown = [n for n in names if n not in PRESS_SOURCES]
    if unknown:
        raise ValueError(f'unknown press source {excerpt(unknown[0])}: one of {", ".join(PRESS_SOURCES)}, '
                         'a comma list of them, or all')
    return tuple(sorted(set(names)))


def check_participant(pid, source: str = 'participant') -> str:
    """The id unchanged when it is a safe file name (core.safe_input.check_wearer) and a BIDS
    label (letters and digits only); ValueError naming `source` otherwise."""
    check_wearer(pid, source)
    if not PARTICIPANT_PATTERN.fullmatch(pid):
        raise ValueError(f'{source} must be 1-64 letters or digits (a BIDS label: no "_", "-" or "."), '
                         f'got {excerpt(pid)}')
    return pid


@dataclass(frozen=True)
class StudyDesign:
    """Every parameter of one task of a study (recorded in the sidecar of its trials file).

    Times are steady-clock seconds, angles degrees."""

    protocol: str                            # 'speed' or 'accuracy'
    seed: int = 0                            # condition order (random) and targets
    conditions: tuple[int, ...] = (1, 2, 3, 4)
    order: str = 'random'                    # 'random' (per participant, from seed) or 'latin'
    trials: int | None = None                # per condition; None: the paper's (speed 6, accuracy 10)
    trial_s: float = 40.0                    # speed: length of a trial [s]
    acceptance_deg: float = 5.0              # speed: a press counts within this error [deg]; also the front's
    front_dwell_s: float = 0.3               # speed: gaze back at the front for this long [s]
    horizontal_deg: float = 60.0             # targets within +-this azimuth [deg]
    vertical_deg: float = 30.0               # targets within +-this elevation [deg]
    timeout_s: float = 15.0                  # accuracy: no press by then ends the trial [s]
    dummies: int = 50                        # speed: distractor objects around each target
    rest_s: float = 3.0                      # between trials, suit vented [s]
    hold_between_blocks: bool = False        # wait for the operator's resume before a new condition
    max_press_age_s: float = 0.5             # a press stamped longer ago than this is stale [s]
    debounce_s: float = 0.15                 # a second press within this of the last is a duplicate [s]
    gaze_gap_s: float = 0.1                  # the gaze sample at a press must be at most this old [s]
    gaze_history_s: float = 2.0              # gaze samples kept (bounded) [s]
    press_sources: tuple[str, ...] = ()      # the confirm sources judged (PRESS_SOURCES); (): all

    def __post_init__(self):
        if self.protocol not in PROTOCOLS:
            raise ValueError(f'protocol must be one of {", ".join(PROTOCOLS)}, got {excerpt(self.protocol)}')
        if self.order not in ORDERS:
            raise ValueError(f'order must be one of {", ".join(ORDERS)}, got {excerpt(self.order)}')
        if not isinstance(self.seed, int) or isinstance(self.seed, bool) or self.seed < 0:
            raise ValueError(f'seed must be a whole number >= 0, got {excerpt(self.seed)}')
        conds = tuple(int(c) for c in self.conditions)
        for c in conds:
            condition_of(c)
        if len(set(conds)) != len(conds) or not conds:
            raise ValueError(f'conditions must be distinct and at least one, got {excerpt(self.conditions)}')
        object.__setattr__(self, 'conditions', conds)
        if isinstance(self.press_sources, str) or not all(isinstance(n, str) for n in self.press_sources):
            raise ValueError(f'press_sources must be a list of {", ".join(PRESS_SOURCES)}, '
                             f'got {excerpt(self.press_sources)}')
        object.__setattr__(self, 'press_sources', parse_press_sources(','.join(self.press_sources)))
        if self.order == 'latin' and len(conds) % 2:
            raise ValueError(f'a balanced Latin square needs an even number of conditions, got {len(conds)}')
        trials = self.trials if self.trials is not None else (6 if self.protocol == 'speed' else 10)
        if not isinstance(trials, int) or isinstance(trials, bool) or trials < 1:
            raise ValueError(f'trials must be a whole number >= 1, got {excerpt(self.trials)}')
        object.__setattr__(self, 'trials', trials)
        if not isinstance(self.dummies, int) or self.dummies < 0:
            raise ValueError(f'dummies must be a whole number >= 0, got {excerpt(self.dummies)}')
        for f in fields(self):
            if f.type == 'float':
                value = getattr(self, f.name)
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                        or value < 0 or (value == 0 and f.name in _POSITIVE):
                    raise ValueError(f'{f.name} must be a {"positive" if f.name in _POSITIVE else "non-negative"} '
                                     f'number, got {excerpt(value)}')
                object.__setattr__(self, f.name, float(value))

    def as_dict(self) -> dict:
        """The task's parameters, without those of the other task (an accuracy sidecar recorded
        the speed task's 50 dummies and 40 s trials)."""
        other = {name for task, names in TASK_ONLY.items() if task != self.protocol for name in names}
        d = {k: v for k, v in asdict(self).items() if k not in other}
        d['conditions'] = list(self.conditions)
        d['press_sources'] = list(self.press_sources)
        return d

    @classmethod
    def from_dict(cls, data: dict, source: str = 'design') -> 'StudyDesign':
        """The design a sidecar recorded; ValueError naming `source` for an unknown or bad field."""
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise ValueError(f'{source}: unknown parameter(s) {", ".join(unknown)}')
        try:
            return cls(**{k: tuple(v) if k in ('conditions', 'press_sources') and isinstance(v, list) else v
                          for k, v in data.items()})
        except (TypeError, ValueError) as exc:
            raise ValueError(f'{source}: {exc}') from None

    def judges(self, source: str) -> bool:
        """Whether a press from this source (a confirm's frame_id) is judged."""
        return not self.press_sources or press_source_kind(source) in self.press_sources

    def with_(self, **changes) -> 'StudyDesign':
        return replace(self, **changes)


#: The parameters of one task only.
TASK_ONLY = {'speed': ('trial_s', 'acceptance_deg', 'front_dwell_s', 'dummies'), 'accuracy': ('timeout_s',)}
_POSITIVE = {'trial_s', 'acceptance_deg', 'timeout_s', 'max_press_age_s', 'gaze_gap_s', 'gaze_history_s'}


def balanced_latin_square(n: int) -> list[tuple[int, ...]]:
    """Williams' balanced Latin square for an even n: n rows (orders of 0..n-1), each condition
    once in every position and each condition followed by every other exactly once."""
    if n < 2 or n % 2:
        raise ValueError(f'a balanced Latin square needs an even number >= 2 of conditions, got {n}')
    first = [0]
    lo, hi = 1, n - 1
    for k in range(1, n):
        if k % 2:
            first.append(lo)
            lo += 1
        else:
            first.append(hi)
            hi -= 1
    return [tuple((c + r) % n for c in first) for r in range(n)]


def condition_order(design: StudyDesign, index: int) -> tuple[int, ...]:
    """The condition order of the participant with this index (0-based, the order of their
    registration): 'random' as the headless experiment's wearer `index` on the same seed, or
    row index mod n of the balanced Latin square."""
    if not isinstance(index, int) or index < 0:
        raise ValueError(f'participant index must be a whole number >= 0, got {excerpt(index)}')
    conds = design.conditions
    if design.order == 'latin':
        row = balanced_latin_square(len(conds))[index % len(conds)]
    else:
        row = generator(design.seed, 'condition_order', index).permutation(len(conds))
    return tuple(conds[int(i)] for i in row)


def target_stream(design: StudyDesign, index: int, repetition: int) -> Iterator[tuple[float, float]]:
    """The targets (azimuth, elevation) [deg] of repetition r of participant `index`, endless:
    uniform within +-horizontal_deg, +-vertical_deg; the same in every condition and the same as
    sim.protocols.target_stream gives the headless wearer `index` on this seed."""
    rng = generator(design.seed, 'targets', index, (repetition,))
    while True:
        h, v = rng.uniform(-1.0, 1.0, 2)
        yield float(h * design.horizontal_deg), float(v * design.vertical_deg)


@dataclass(frozen=True)
class TrialSpec:
    """One trial of a block. target: the accuracy trial's unseen target (azimuth, elevation)
    [deg]; None for speed (its targets come from target_stream)."""

    repetition: int                          # 0-based within the condition
    target: tuple[float, float] | None = None


@dataclass(frozen=True)
class Block:
    """One condition of one participant: the unit a session resumes at (an interrupted block
    is redone whole)."""

    participant: str
    index: int                               # participant index (seeds their order and targets)
    session: int                             # 1-based session number (BIDS ses-<n>)
    protocol: str
    condition: int
    order: int                               # 1-based position of the condition in their order
    trials: tuple[TrialSpec, ...] = field(default_factory=tuple)

    @property
    def key(self) -> str:
        """What names the block in the files: task, condition and position."""
        return f'{self.protocol}-order{self.order}-cond{self.condition}'


def participant_blocks(design: StudyDesign, participant: str, index: int, session: int = 1) -> tuple[Block, ...]:
    """The participant's blocks in their condition order, each with design.trials trials."""
    check_participant(participant)
    if not isinstance(session, int) or session < 1:
        raise ValueError(f'session must be a whole number >= 1, got {excerpt(session)}')
    accuracy_targets = [next(target_stream(design, index, r)) for r in range(design.trials)] \
        if design.protocol == 'accuracy' else [None] * design.trials
    return tuple(Block(participant, index, session, design.protocol, cond, order,
                       tuple(TrialSpec(r, accuracy_targets[r]) for r in range(design.trials)))
                 for order, cond in enumerate(condition_order(design, index), start=1))


def order_counts(orders: Sequence[Sequence[int]]) -> np.ndarray:
    """How often each condition sits at each position (rows: conditions in sorted order): a
    balance check for a set of participants' orders."""
    conds = sorted({c for o in orders for c in o})
    counts = np.zeros((len(conds), len(conds)), dtype=int)
    for o in orders:
        for pos, c in enumerate(o):
            counts[conds.index(c), pos] += 1
    return counts
