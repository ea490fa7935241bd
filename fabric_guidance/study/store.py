"""A study folder, BIDS-like, written as the session goes so that a crash keeps every finished
trial:

    STUDY_DIR/dataset_description.json        name, format version, what wrote it
    STUDY_DIR/participants.tsv (+ .json)      participant_id, index, registered_utc
    STUDY_DIR/sub-<id>/ses-<n>/
        sub-<id>_ses-<n>_task-<protocol>_trials.tsv   one row per trial (trial_columns.COLUMNS)
        sub-<id>_ses-<n>_task-<protocol>_trials.json  sidecar: every parameter (the StudyDesign),
                                                      every column with its unit, the blocks done
        sub-<id>_ses-<n>_task-<protocol>_block-<k>_bag/  one bag per block (reserved here, written
                                                      by the operator layer)

Every file is replaced whole (atomic.py: a temporary file, fsync, rename), the trials file after
every trial, so a SIGKILL or a power loss leaves the file as it was before or after a trial,
never part of one. A block is done when the sidecar lists it; on reopen the rows of a block not
listed (the interrupted one) are kept with status 'interrupted' and the block is run again.

Errors are one line naming the file or field: StudyError (a ValueError) for a folder of another
format version, an unknown participant, parameters that differ from those recorded; DiskFull
(an OSError) when the disk is full (the files stay as they were: nothing recorded is lost).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from .plan import Block, StudyDesign

FORMAT_VERSION = 1
FORMAT_KEY = 'FabricGuidanceStudyFormat'


class StudyError(ValueError):
    """A study folder or request that cannot be used, in one line."""


class DiskFull(OSError):
    """The disk is full: nothing was written, what was recorded before is intact."""


@dataclass(frozen=True)
class Participant:
    participant_id: str          # without the 'sub-' prefix
    index: int                   # 0-based registration order (seeds order and targets)
    registered_utc: str


@dataclass(frozen=True)
class Lost:
    """What a reopen found unfinished: the block cut off and its trials kept as 'interrupted'."""

    block: str                   # Block.key
    trials: int                  # rows of it kept with status 'interrupted'

    def line(self) -> str:
        raise NotImplementedError


class Study:
    """A study folder. Study.open(root) creates it when absent."""

    def __init__(self, root: Path):
        raise NotImplementedError

    @classmethod
    def open(cls, root: str | Path, name: str | None = None) -> 'Study':
        """Open (or create) the study folder `root`; StudyError for another format version or a
        folder that is not a study."""
        raise NotImplementedError

    def participants(self) -> list[Participant]:
        raise NotImplementedError

    def add_participant(self, participant_id: str) -> Participant:
        """Register a new participant (index = the next); the existing one if already there."""
        raise NotImplementedError

    def participant(self, participant_id: str) -> Participant:
        """A registered participant; StudyError naming participants.tsv for an unknown id."""
        raise NotImplementedError

    def session(self, participant_id: str, session: int, design: StudyDesign) -> 'SessionStore':
        """The trials file of one participant, session and task (design.protocol), created or
        reopened; StudyError when `design` differs from the recorded parameters."""
        raise NotImplementedError


class SessionStore:
    """One participant's trials of one task in one session."""

    trials_path: Path
    sidecar_path: Path
    lost: Lost | None            # what the reopen found unfinished (None: nothing)

    def rows(self) -> list[dict]:
        """Every row recorded, in order (values as written: strings; '' for none)."""
        raise NotImplementedError

    def done_blocks(self) -> list[str]:
        """Block keys finished, in order."""
        raise NotImplementedError

    def remaining(self, blocks: Sequence[Block]) -> list[Block]:
        """The blocks of `blocks` not yet done, in order (the session to run after a restart)."""
        raise NotImplementedError

    def bag_path(self, block: Block) -> Path:
        """Where the block's bag goes (a directory that does not exist yet: a redone block gets
        a new name, the interrupted one's bag stays)."""
        raise NotImplementedError

    def append(self, row: dict) -> None:
        """Record one finished trial durably (the whole file replaced atomically, fsynced)."""
        raise NotImplementedError

    def amend(self, block: str, repetition: int, status: str) -> None:
        """Change the status of the last row of (block, repetition), e.g. to 'repeated'."""
        raise NotImplementedError

    def finish_block(self, block: Block) -> None:
        """Mark the block done in the sidecar (durable)."""
        raise NotImplementedError


def study_trials(root: str | Path, protocol: str | None = None) -> list[dict]:
    """Every 'ok' row of every participant's trials files under root (protocol: only that task)."""
    raise NotImplementedError
