"""A study folder, a BIDS dataset of behavioural data, written as the session goes so that a
crash keeps every finished trial:

    STUDY_DIR/dataset_description.json        BIDS version, format version, what wrote it
    STUDY_DIR/README.md, .bidsignore          (dataset.py)
    STUDY_DIR/participants.tsv (+ .json)      participant_id, index, registered_utc, a researcher's own
    STUDY_DIR/sub-<id>/ses-<n>/beh/
        sub-<id>_ses-<n>_task-<protocol>_beh.tsv   one row per trial (trial_columns.COLUMNS)
        sub-<id>_ses-<n>_task-<protocol>_beh.json  sidecar: every column with its unit, every
                                                   parameter (the StudyDesign), the blocks done
        sub-<id>_ses-<n>_task-<protocol>_run-<r>_events.tsv (+ .json)  the events of run r (a
                                                   block's attempt, events.py) and its time anchor
        sub-<id>_ses-<n>_task-<protocol>_run-<r>_bag/  run r's bag (reserved here, written by the
                                                   operator layer)

Every file is replaced whole (atomic.py: a temporary file, fsync, rename), the trials file after
every trial, so a SIGKILL or a power loss leaves the file as it was before or after a trial,
never part of one. A block is done when the sidecar lists it; on reopen the rows of a block not
listed (the interrupted one) are kept with status 'interrupted' and the block is run again.

Errors are one line naming the file or field: StudyError (a ValueError) for a folder of another
format version, an unknown participant, parameters that differ from those recorded; DiskFull
(an OSError) when the disk is full (the files stay as they were: nothing recorded is lost).
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
import errno
import io
import json
import math
from pathlib import Path
import time
from typing import Sequence

from ..atomic import write_text
from ..core.safe_input import excerpt
from ..experiments.study_folder import TRIALS_GLOB
from . import dataset
from .events import EVENT_COLUMNS
from .plan import Block, StudyDesign, check_participant
from .trial_columns import COLUMNS, FILE_NAMES

#: 2: the BIDS layout (beh/, _beh.tsv, events, no column named after an entity). A folder of
#: version 1 is refused in one line: finish it with the version that wrote it.
FORMAT_VERSION = 2
FORMAT_KEY = 'FabricGuidanceStudyFormat'
DESCRIPTION = 'dataset_description.json'
PARTICIPANTS = 'participants.tsv'
PARTICIPANT_COLUMNS = {
    'participant_id': ('-', 'sub-<id>: the participant id with the BIDS prefix'),
    'index': ('-', '0-based registration order; seeds the condition order and the targets'),
    'registered_utc': ('-', 'when the participant was registered, ISO 8601 UTC'),
}
MISSING = 'n/a'                  # BIDS's empty cell


class StudyError(ValueError):
    """A study folder or request that cannot be used, in one line."""


class DiskFull(OSError):
    """The disk is full: nothing was written, what was recorded before is intact."""


def _utc() -> str:
    return datetime.now(timezone.utc).isoformat(timespec='milliseconds')


def _write(path: Path, text: str) -> None:
    """One file whole (atomic.write_text); a full disk becomes DiskFull, one line."""
    try:
        write_text(path, text)
    except OSError as exc:
        if exc.errno in (errno.ENOSPC, errno.EDQUOT):
            raise DiskFull(exc.errno, f'disk full: cannot write {path}; what was recorded before is intact '
                                      f'(free space, then go on)') from None
        raise


def _cell(value) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return MISSING
    if isinstance(value, float):
        return repr(value)
    return ' '.join(str(value).split()) or MISSING     # no tab or newline inside a cell


def _tsv(columns: Sequence[str], rows: Sequence[dict]) -> str:
    out = io.StringIO()
    w = csv.writer(out, delimiter='\t', lineterminator='\n', quoting=csv.QUOTE_NONE, escapechar='\\')
    w.writerow(columns)
    for r in rows:
        w.writerow([r.get(c, MISSING) for c in columns])
    return out.getvalue()


def read_tsv(path: Path) -> tuple[list[str], list[dict]]:
    """Header and rows (strings) of a TSV; StudyError naming the file when unreadable."""
    try:
        with path.open(newline='', encoding='utf-8-sig') as f:     # -sig: a spreadsheet's BOM
            lines = list(csv.reader(f, delimiter='\t', quoting=csv.QUOTE_NONE, escapechar='\\'))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise StudyError(f'{path}: cannot read: {getattr(exc, "strerror", None) or exc}') from None
    if not lines:
        raise StudyError(f'{path}: empty, expected a header row')
    header = lines[0]
    bad = [i for i, r in enumerate(lines[1:], start=2) if len(r) != len(header)]
    if bad:
        raise StudyError(f'{path}: line {bad[0]} has a different number of cells than the header')
    return header, [dict(zip(header, r)) for r in lines[1:]]


def _read_json(path: Path) -> dict:
    try:
        data = json.loads(path.read_text(encoding='utf-8'))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise StudyError(f'{path}: cannot read: {getattr(exc, "strerror", None) or excerpt(str(exc))}') from None
    if not isinstance(data, dict):
        raise StudyError(f'{path}: expected a JSON object')
    return data


def _sidecar_columns(columns: dict[str, tuple[str, str]]) -> dict:
    """Each column's description at the sidecar's top level, as BIDS tools read it; Units only
    where there is one."""
    return {name: {'Description': text, **({'Units': unit} if unit != '-' else {})}
            for name, (unit, text) in columns.items()}


def _utc_of(steady_s: float) -> str:
    """The UTC time of an instant on the steady clock (time.monotonic), ISO 8601."""
    return (datetime.now(timezone.utc) - timedelta(seconds=time.monotonic() - steady_s)).isoformat(
        timespec='microseconds')


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
        return (f'block {self.block} was cut off: its {self.trials} finished trial(s) are kept as '
                f"'interrupted' and the block is run again")


def check_version(root: Path) -> dict:
    """The study's description; StudyError when root is not a study folder of this format."""
    path = root / DESCRIPTION
    if not path.is_file():
        raise StudyError(f'{root}: not a study folder (no {DESCRIPTION})')
    data = _read_json(path)
    version = data.get(FORMAT_KEY)
    if version != FORMAT_VERSION:
        raise StudyError(f'{path}: study format version {excerpt(version)}, this fabric_guidance reads version '
                         f'{FORMAT_VERSION}; use the version that wrote it, or a new study folder')
    return data


class Study:
    """A study folder. Study.open(root) creates it when absent."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self.description = check_version(self.root)

    @classmethod
    def open(cls, root: str | Path, name: str | None = None) -> 'Study':
        """Open (or create) the study folder `root`; StudyError for another format version or a
        folder that is not a study."""
        root = Path(root).expanduser()
        if not (root / DESCRIPTION).exists():
            if root.exists() and (not root.is_dir() or any(root.iterdir())):
                raise StudyError(f'{root}: not a study folder (no {DESCRIPTION}) and not empty')
            root.mkdir(parents=True, exist_ok=True)
            _write(root / 'README.md', dataset.readme(name or root.name))
            _write(root / '.bidsignore', dataset.bidsignore())
            _write(root / DESCRIPTION, json.dumps(dataset.description(name or root.name, FORMAT_KEY, FORMAT_VERSION),
                                                  indent=2) + '\n')
            _write(root / 'participants.json', json.dumps(_sidecar_columns(PARTICIPANT_COLUMNS), indent=2) + '\n')
            _write(root / PARTICIPANTS, _tsv(list(PARTICIPANT_COLUMNS), []))
        return cls(root)

    def _participant_rows(self) -> tuple[list[str], list[dict], list[Participant]]:
        """participants.tsv's header and rows as written (a researcher's columns included) and
        the participants; StudyError naming the file and line for a row the package cannot use."""
        path = self.root / PARTICIPANTS
        if not path.exists():
            return list(PARTICIPANT_COLUMNS), [], []
        header, rows = read_tsv(path)
        absent = [c for c in PARTICIPANT_COLUMNS if c not in header]
        if absent:
            raise StudyError(f'{path}: line 1: no column {absent[0]} (the columns {", ".join(PARTICIPANT_COLUMNS)} '
                             'are fabric_guidance\'s; add your own beside them)')
        out, seen = [], {}
        for i, r in enumerate(rows, start=2):
            pid = r['participant_id']
            try:
                if not pid.startswith('sub-'):
                    raise ValueError
                check_participant(pid[4:])
            except ValueError:
                raise StudyError(f'{path}: line {i}: participant_id {excerpt(pid)} is not sub-<letters or digits>') \
                    from None
            if pid in seen:
                raise StudyError(f'{path}: line {i}: {pid} is registered twice (also line {seen[pid]})')
            seen[pid] = i
            # The index is the registration order, which seeds the condition order and the
            # targets: one edited by hand would give a participant another's, so it is refused.
            if r['index'] != str(i - 2):
                raise StudyError(f'{path}: line {i}: index {excerpt(r["index"])} of {pid} is not its registration '
                                 f'order ({i - 2}); the index is fabric_guidance\'s (it seeds the condition order '
                                 'and the targets): put the rows and the index back as they were written')
            out.append(Participant(pid[4:], i - 2, r['registered_utc']))
        return header, rows, out

    def participants(self) -> list[Participant]:
        """The registered participants in registration order."""
        return self._participant_rows()[2]

    def add_participant(self, participant_id: str) -> Participant:
        """Register a new participant (index = the next); the existing one if already there.
        Columns a researcher added to participants.tsv are kept, in their order (the new row
        has n/a there)."""
        try:
            check_participant(participant_id)
        except ValueError as exc:
            raise StudyError(str(exc)) from None
        header, rows, known = self._participant_rows()
        for p in known:
            if p.participant_id == participant_id:
                return p
        p = Participant(participant_id, len(known), _utc())
        rows.append({'participant_id': f'sub-{p.participant_id}', 'index': str(p.index),
                     'registered_utc': p.registered_utc})
        _write(self.root / PARTICIPANTS, _tsv(header, rows))
        return p

    def participant(self, participant_id: str) -> Participant:
        """A registered participant; StudyError naming participants.tsv for an unknown id."""
        known = self.participants()
        for p in known:
            if p.participant_id == participant_id:
                return p
        names = ', '.join(p.participant_id for p in known[:10]) or 'none'
        raise StudyError(f'{self.root / PARTICIPANTS}: unknown participant {excerpt(participant_id)} '
                         f'(registered: {names}); register them first')

    def session(self, participant_id: str, session: int, design: StudyDesign) -> 'SessionStore':
        """The trials file of one participant, session and task (design.protocol), created or
        reopened; StudyError when `design` differs from the recorded parameters."""
        p = self.participant(participant_id)
        if not isinstance(session, int) or session < 1:
            raise StudyError(f'session must be a whole number >= 1, got {excerpt(session)}')
        return SessionStore(self, p, session, design)


class SessionStore:
    """One participant's trials of one task in one session."""

    def __init__(self, study: Study, participant: Participant, session: int, design: StudyDesign):
        self.study, self.participant, self.session, self.design = study, participant, session, design
        folder = study.root / f'sub-{participant.participant_id}' / f'ses-{session}' / 'beh'
        self.folder = folder
        self.prefix = f'sub-{participant.participant_id}_ses-{session}_task-{design.protocol}'
        self.trials_path = folder / f'{self.prefix}_beh.tsv'
        self.sidecar_path = folder / f'{self.prefix}_beh.json'
        self.lost: Lost | None = None
        self._rows: list[dict] = []
        self._unwritten = False
        self._run: dict | None = None        # the run events go to: its number, block, start, events
        self._early: list[dict] = []         # events before the first run (its start's vent)
        self._closed: list[dict] = []        # runs ended since the last flush_events()
        if self.sidecar_path.exists():
            self._reopen()
        else:
            folder.mkdir(parents=True, exist_ok=True)
            self._sidecar = {
                **_sidecar_columns(COLUMNS),
                'TaskName': design.protocol, FORMAT_KEY: FORMAT_VERSION, 'Participant': participant.participant_id,
                'ParticipantIndex': participant.index, 'Session': session, 'Parameters': design.as_dict(),
                'Clock': 'times in s on the steady clock (monotonic) of the machine that ran the session; '
                         'each run\'s events sidecar pairs its start with UTC',
                'RunsStarted': 0, 'BlocksStarted': [], 'BlocksDone': []}
            self._write_rows()
            self._write_sidecar()

    def _reopen(self) -> None:
        side = _read_json(self.sidecar_path)
        if side.get(FORMAT_KEY) != FORMAT_VERSION:
            raise StudyError(f'{self.sidecar_path}: study format version {excerpt(side.get(FORMAT_KEY))}, '
                             f'this fabric_guidance reads version {FORMAT_VERSION}')
        if side.get('ParticipantIndex') != self.participant.index:
            raise StudyError(f'{self.sidecar_path}: participant index {excerpt(side.get("ParticipantIndex"))} '
                             f'recorded, participants.tsv gives {self.participant.index}: the index seeds the '
                             'condition order and the targets; put participants.tsv back as it was written')
        recorded = StudyDesign.from_dict(side.get('Parameters') or {}, str(self.sidecar_path))
        mine, theirs = self.design.as_dict(), recorded.as_dict()   # the task's own parameters
        if mine != theirs:
            diff = [f'{k} {theirs[k]!r} recorded, {mine[k]!r} given' for k in mine if mine[k] != theirs[k]]
            raise StudyError(f'{self.sidecar_path}: parameters differ from those recorded: {"; ".join(diff)}')
        # Every parameter listed, those added since it was written too (their defaults: equal).
        side['Parameters'] = self.design.as_dict()
        side.update(_sidecar_columns(COLUMNS))
        self._sidecar = side
        if self.trials_path.exists():
            header, rows = read_tsv(self.trials_path)
            if header != list(COLUMNS):
                raise StudyError(f'{self.trials_path}: columns differ from this version\'s '
                                 f'(first difference: {next((a for a, b in zip(header, COLUMNS) if a != b), "count")})')
            self._rows = rows
        done = set(self.done_blocks())
        cut = [r for r in self._rows if r['block'] not in done and r['status'] != 'interrupted']
        started = [b['block'] for b in side.get('BlocksStarted', []) if b['block'] not in done]
        if cut or started:
            block = cut[0]['block'] if cut else started[-1]
            for r in cut:
                r['status'] = 'interrupted'
            self.lost = Lost(block, len(cut))
            # The cut block's bags stay named (its first run's bag holds what happened up to the cut).
            runs = [b for b in side['BlocksStarted'] if b['block'] == block]
            side['BlocksStarted'] = [b for b in side['BlocksStarted'] if b['block'] in done or b.get('interrupted')]
            side.setdefault('BlocksInterrupted', []).append({
                'block': block, 'trials': len(cut), 'runs': [b['run'] for b in runs if 'run' in b],
                'bags': [b['bag'] for b in runs if b.get('bag')], 'found_utc': _utc()})
            self._write_rows()
            self._write_sidecar()

    def _write_rows(self) -> None:
        _write(self.trials_path, _tsv(list(COLUMNS), self._rows))
        self._unwritten = False

    def _write_sidecar(self) -> None:
        _write(self.sidecar_path, json.dumps(self._sidecar, indent=2) + '\n')

    def rows(self) -> list[dict]:
        """Every row recorded, in order (values as written: strings; 'n/a' for none)."""
        return [dict(r) for r in self._rows]

    def done_blocks(self) -> list[str]:
        """Block keys finished, in order."""
        return [b['block'] for b in self._sidecar.get('BlocksDone', [])]

    def remaining(self, blocks: Sequence[Block]) -> list[Block]:
        """The blocks of `blocks` not yet done, in order (the session to run after a restart)."""
        done = set(self.done_blocks())
        return [b for b in blocks if b.key not in done]

    def run_path(self, run: int, suffix: str) -> Path:
        """A file of run `run` (suffix: 'events.tsv', 'events.json', 'bag')."""
        return self.folder / f'{self.prefix}_run-{run}_{suffix}'

    def start_run(self, block: Block, steady_s: float, write: bool = True) -> dict:
        """A new run of `block` (its attempt), starting at steady_s [s, steady clock]: recorded
        as started in the sidecar, its first event the start on the steady clock and in UTC; its
        events and bag get the run's number (never one used before). write=False: the files are
        written with the next flush_events() (note() runs before the step's vent is carried out)."""
        if self._run is not None:
            self._closed.append(self._run)
        run = int(self._sidecar.get('RunsStarted', 0)) + 1
        while any(self.run_path(run, x).exists() for x in ('events.tsv', 'events.json', 'bag')):
            run += 1
        self._sidecar['RunsStarted'] = run
        utc = _utc_of(steady_s)
        self._sidecar['BlocksStarted'].append({'block': block.key, 'condition': block.condition, 'run': run,
                                               'bag': self.run_path(run, 'bag').name,
                                               'events': self.run_path(run, 'events.tsv').name,
                                               'started_utc': utc, 'started_steady_s': steady_s})
        self._run = {'run': run, 'block': block.key, 'start': steady_s, 'events': [], 'bag': False, 'dirty': True,
                     'new': True}
        self._event({'trial_type': 'run_start', 'steady_s': steady_s, 'duration': 0.0, 'value': utc})
        for e in self._early:
            self._event(e)
        self._early = []
        if write:
            self.flush_events()
        return self._run

    def bag_path(self, block: Block) -> Path:
        """Where the block's bag goes (a directory that does not exist yet: a redone block's run
        gets a new number, the interrupted one's bag stays): the bag of the block's run noted
        already (note()), else of a run started now. The run's files are written here."""
        run = self._run
        if run is None or run['block'] != block.key or run['bag']:
            run = self.start_run(block, time.monotonic(), write=False)
        run['bag'] = True
        self.flush_events()
        return self.run_path(run['run'], 'bag')

    def note(self, block: Block | None, events: Sequence[dict]) -> None:
        """Events of the session (events.step_events), kept in memory: a 'condition' event starts
        a new run of `block`; written with the next bag_path(), trial (record) or flush_events()
        (never before the step's actions are carried out: a vent waits on no disk)."""
        for e in events:
            if e['trial_type'] == 'condition' and block is not None:
                self.start_run(block, e['steady_s'], write=False)
            if self._run is None:
                self._early.append(e)
            else:
                self._event(e)

    def _event(self, e: dict) -> None:
        run = self._run
        row = {c: _cell(e.get(c)) for c in EVENT_COLUMNS if c not in ('onset',)}
        row['onset'] = _cell(e['steady_s'] - run['start'])
        run['events'].append(row)
        run['dirty'] = True

    def flush_events(self) -> None:
        """Write what the runs noted since the last flush: a new run's entry in the sidecar and
        its events sidecar (column descriptions only, as BIDS has it), and each run's events file
        (sorted by onset)."""
        runs = self._closed + ([self._run] if self._run is not None else [])
        self._closed = []
        if any(r['new'] for r in runs):
            self._write_sidecar()
        for run in runs:
            if run['new']:
                _write(self.run_path(run['run'], 'events.json'),
                       json.dumps(_sidecar_columns(EVENT_COLUMNS), indent=2) + '\n')
                run['new'] = False
            if run['dirty']:
                rows = sorted(run['events'], key=lambda r: float(r['onset']))
                _write(self.run_path(run['run'], 'events.tsv'), _tsv(list(EVENT_COLUMNS), rows))
                run['dirty'] = False

    def append(self, row: dict) -> None:
        """Record one finished trial durably (the whole file replaced atomically, fsynced).
        DiskFull: the row is kept here and written with the next append (or flush())."""
        full = {FILE_NAMES.get(k, k): v for k, v in row.items()}
        unknown = sorted(set(full) - set(COLUMNS))
        if unknown:
            raise ValueError(f'trial row: unknown column(s) {", ".join(unknown)}')
        if full.get('scene') in (None, 'study'):
            full['scene'] = self.study.root.name
        if full.get('package_version') is None:
            full['package_version'] = dataset.package_version()
        if full.get('git_commit') is None:
            full['git_commit'] = dataset.git_commit()
        full['recorded_utc'] = _utc()
        self._rows.append({c: _cell(full.get(c)) for c in COLUMNS})
        self._unwritten = True
        self._write_rows()

    def flush(self) -> None:
        """Write rows a full disk held back."""
        if self._unwritten:
            self._write_rows()

    def amend(self, block: str, repetition: int, status: str) -> None:
        """Change the status of the last row of (block, repetition), e.g. to 'repeated'."""
        for r in reversed(self._rows):
            if r['block'] == block and r['repetition'] == str(repetition):
                r['status'] = status
                self._write_rows()
                return
        raise ValueError(f'amend: no row of block {block}, repetition {repetition}')

    def record(self, step) -> None:
        """Write what a session.Step produced: its rows, its amended statuses, its finished blocks
        (and the run's events so far)."""
        self.flush_events()
        for row in step.rows:
            self.append(row)
        for block, repetition, status in step.amended:
            self.amend(block, repetition, status)
        for block in step.blocks:
            self.finish_block(block)

    def finish_block(self, block: Block) -> None:
        """Mark the block done in the sidecar (durable), its run's events written."""
        self.flush_events()
        self._sidecar['BlocksDone'].append({'block': block.key, 'condition': block.condition, 'order': block.order,
                                            'finished_utc': _utc()})
        self._write_sidecar()


def trials_files(root: str | Path) -> list[Path]:
    """Every trials file of the study, sorted."""
    return sorted(Path(root).glob(TRIALS_GLOB))


def study_trials(root: str | Path, protocol: str | None = None) -> list[dict]:
    """Every trial that ended in every participant's trials files under root (protocol: only
    that task): 'ok' rows of the blocks their sidecar lists done (a block cut off and not yet
    run again does not count)."""
    root = Path(root)
    check_version(root)
    out = []
    for path in trials_files(root):
        _, rows = read_tsv(path)
        done = {b.get('block') for b in _read_json(path.with_suffix('.json')).get('BlocksDone', [])}
        out.extend(r for r in rows if r.get('status') == 'ok' and r.get('block') in done
                   and (protocol is None or r.get('protocol') == protocol))
    return out
