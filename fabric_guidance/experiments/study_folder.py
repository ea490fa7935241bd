"""A live study's folder as `analyze` reads it (study/store.py writes it; this layer sits below
study/, so the layout is read here as any BIDS reader reads it, and test_study_store checks that
both agree).

Only trials that ended count: a row is analysed when its status is 'ok' and its block is listed
done in its sidecar (a block cut off by a crash and not yet run again is left out, named in one
line). Every value is checked against its column's range (counts >= 0, identified <= presented,
errors within the field, times within the trial); a bad value, a cut-off or ragged line, is one
line naming the file and the line.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass, field
import json
import math
from pathlib import Path

import pandas as pd

from ..sim.protocols import CONDITION_NAMES

DESCRIPTION = 'dataset_description.json'
FORMAT = ('FabricGuidanceStudyFormat', 2)
#: A session's trials of one task (a BIDS behavioural file), and its sidecar beside it (.json).
TRIALS_GLOB = 'sub-*/ses-*/beh/sub-*_ses-*_task-*_beh.tsv'
MISSING = 'n/a'
#: Whether a larger value of a measure is better (decides each participant's best condition).
HIGHER_IS_BETTER = {
    'identified': True, 'presented': True, 'mean_find_s': False,
    'h_error_deg': False, 'v_error_deg': False, 'tracked_h_error_deg': False, 'tracked_v_error_deg': False,
    'time_s': False,
}
#: The columns a trials file must have for the analysis.
REQUIRED = ('protocol', 'wearer', 'condition', 'repetition', 'status', 'block')
COUNTS = ('identified', 'presented', 'presses', 'refused_presses', 'ignored_presses', 'repetition')
ERRORS = ('h_error_deg', 'v_error_deg', 'tracked_h_error_deg', 'tracked_v_error_deg')
#: Slack on a time compared with its trial's length (the stamps are floats) [s].
TIME_SLACK_S = 1e-6


class StudyFolderError(ValueError):
    """A study folder that cannot be analysed, in one line naming the file (and line)."""


@dataclass
class StudyData:
    """The trials that count, as a DataFrame (subject: the participant id; condition: the names
    experiments.stats uses), their protocol, the conditions of its design, and one line per
    trial or block left out."""

    frame: pd.DataFrame
    protocol: str
    conditions: tuple[str, ...]
    notes: list[str] = field(default_factory=list)
    #: the speed trials' length when every session of the protocol ran one (the plots' labels)
    trial_s: float | None = None


def check_description(root: Path) -> dict:
    path = root / DESCRIPTION
    description = _read_json(path, f'{root}: not a study folder (no {DESCRIPTION}) and not a table')
    key, version = FORMAT
    if description.get(key) != version:
        found = description.get(key)
        raise StudyFolderError(f'{path}: study format version {found!r}, this fabric_guidance reads version {version}')
    return description


def read_lines(path: Path) -> tuple[list[str], list[tuple[int, dict]]]:
    """Header and (line number, row) of a TSV; a line cut off or with another number of cells
    than the header is a StudyFolderError naming the file and the line."""
    try:
        text = path.read_bytes().decode('utf-8')
    except OSError as exc:
        raise StudyFolderError(f'{path}: cannot read: {exc.strerror or exc}') from None
    except UnicodeDecodeError as exc:
        raise StudyFolderError(f'{path}: not UTF-8 text (byte {exc.start})') from None
    if text.startswith('\ufeff'):
        text = text[1:]             # a spreadsheet's byte order mark: not part of the first name
    lines = list(csv.reader(text.splitlines(), delimiter='\t', quoting=csv.QUOTE_NONE, escapechar='\\'))
    if not lines or not lines[0]:
        raise StudyFolderError(f'{path}: empty, expected a header row')
    header = lines[0]
    rows = []
    for number, cells in enumerate(lines[1:], start=2):
        if len(cells) != len(header):
            last = number == len(lines) and not text.endswith('\n')
            raise StudyFolderError(
                f'{path}: line {number} ' + (f'is cut off ({len(cells)} of {len(header)} cells): the file was not '
                                             'written whole' if last and len(cells) < len(header) else
                                             f'has {len(cells)} cells, the header has {len(header)}'))
        rows.append((number, dict(zip(header, cells))))
    return header, rows


def _read_json(path: Path, missing: str = '') -> dict:
    """A JSON object; StudyFolderError naming the file (`missing`: the line when it is absent)."""
    try:
        data = json.loads(path.read_text(encoding='utf-8'))
    except FileNotFoundError:
        raise StudyFolderError(missing or f'{path}: missing: which blocks finished is recorded there') from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise StudyFolderError(f'{path}: cannot read: {getattr(exc, "strerror", None) or exc}') from None
    if not isinstance(data, dict):
        raise StudyFolderError(f'{path}: expected a JSON object')
    return data


def _number(path: Path, line: int, row: dict, column: str) -> float:
    """The cell as a float (NaN for 'n/a' or an absent column); StudyFolderError otherwise."""
    text = row.get(column, MISSING)
    if text == MISSING:
        return math.nan
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise StudyFolderError(f'{path}: line {line}: {column} {text[:40]!r} is not a number')
    return value


def check_row(path: Path, line: int, row: dict, parameters: dict) -> dict[str, float]:
    """The numbers of one trial row, each within its column's range; StudyFolderError naming
    the file, the line and the column otherwise."""
    values = {}

    def bad(column, why):
        return StudyFolderError(f'{path}: line {line}: {column} {row.get(column)!r} {why}')

    for column in COUNTS:
        v = values[column] = _number(path, line, row, column)
        if not math.isnan(v) and (v < 0 or v != int(v)):
            raise bad(column, 'is not a count (a whole number >= 0)')
    if values['identified'] > values['presented']:
        raise bad('identified', f'is more than presented ({row.get("presented")})')
    for column in ERRORS:
        v = values[column] = _number(path, line, row, column)
        if not math.isnan(v) and not 0.0 <= v <= 180.0:
            raise bad(column, 'is not an error within the field (0 to 180 deg)')
    for column, limit in (('target_h_deg', 'horizontal_deg'), ('target_v_deg', 'vertical_deg')):
        v = values[column] = _number(path, line, row, column)
        bound = parameters.get(limit, 180.0)
        if not math.isnan(v) and abs(v) > bound:
            raise bad(column, f'is outside the targets\' field (+-{bound:g} deg)')
    for column, limit in (('mean_find_s', 'trial_s'), ('time_s', 'timeout_s')):
        v = values[column] = _number(path, line, row, column)
        bound = parameters.get(limit, math.inf)
        if not math.isnan(v) and not 0.0 <= v <= bound + TIME_SLACK_S:
            raise bad(column, f'is not within the trial (0 to {bound:g} s)')
    cond = _number(path, line, row, 'condition')
    conditions = parameters.get('conditions') or list(CONDITION_NAMES)
    if math.isnan(cond) or cond not in conditions:
        raise bad('condition', f'is not a condition of the study ({", ".join(map(str, conditions))})')
    values['condition'] = cond
    return values


def read_study(root: Path, protocol: str | None = None) -> StudyData:
    """The trials of `root` that count, of one protocol (default: the only one it holds)."""
    root = Path(root)
    check_description(root)
    files = sorted(root.glob(TRIALS_GLOB))
    if not files:
        raise StudyFolderError(f'{root}: no trials yet (no {TRIALS_GLOB})')
    kept, notes, conditions, seen, lengths = [], [], {}, set(), {}
    for path in files:
        header, rows = read_lines(path)
        absent = [c for c in REQUIRED if c not in header]
        if absent:
            raise StudyFolderError(f'{path}: no column {absent[0]}: not a trials file of this version')
        sidecar = _read_json(path.with_suffix('.json'))
        parameters = sidecar.get('Parameters') if isinstance(sidecar.get('Parameters'), dict) else {}
        task = parameters.get('protocol')
        done = {b.get('block') for b in sidecar.get('BlocksDone', []) if isinstance(b, dict)}
        cut: dict[str, int] = {}
        for line, row in rows:
            seen.add(row['protocol'])
            if row['status'] != 'ok':
                continue
            values = check_row(path, line, row, parameters)
            if row['block'] not in done:
                cut[row['block']] = cut.get(row['block'], 0) + 1
                continue
            kept.append({**row, **values, '_file': path, '_line': line})
        for block, n in cut.items():
            notes.append(f'{path}: block {block} did not finish: its {n} trial(s) are left out until it is run again')
        if task is not None:
            conditions.setdefault(task, set()).update(parameters.get('conditions') or [])
            lengths.setdefault(task, set()).add(parameters.get('trial_s'))
    if not seen:
        raise StudyFolderError(f'{root}: no trials recorded yet (every trials file holds only its header)')
    protocols = sorted({r['protocol'] for r in kept})
    if protocol is None:
        if len(protocols) > 1:
            raise StudyFolderError(f'{root}: holds the tasks {", ".join(protocols)}: choose one with --protocol')
        if not protocols:
            raise StudyFolderError(f'{root}: no finished trials yet (no block has ended)'
                                   + (f'; {notes[0]}' if notes else ''))
        protocol = protocols[0]
    rows = [r for r in kept if r['protocol'] == protocol]
    if not rows:
        raise StudyFolderError(f'{root}: no finished {protocol} trials')
    frame = pd.DataFrame(rows)
    frame['subject'] = frame['wearer']
    frame['condition'] = frame['condition'].astype(int).map(CONDITION_NAMES)
    names = tuple(CONDITION_NAMES[int(c)] for c in sorted(conditions.get(protocol) or CONDITION_NAMES))
    length = lengths.get(protocol, set())
    trial_s = next(iter(length)) if len(length) == 1 and isinstance(next(iter(length)), (int, float)) else None
    return StudyData(frame.reset_index(drop=True), protocol, names, notes, trial_s)


def complete(data: StudyData, measure: str) -> tuple[pd.DataFrame, list[str]]:
    """The trials with a value of `measure`, of the participants with such a trial in every
    condition; a line for each participant left out (and for the trials without a value)."""
    frame = data.frame
    if measure not in frame.columns:
        raise StudyFolderError(f'--measure: {measure} is not a column of the trials')
    values = pd.to_numeric(frame[measure].replace(MISSING, math.nan), errors='coerce')
    notes = []
    bad = frame[values.isna() & frame[measure].ne(MISSING) & frame[measure].notna()]
    if len(bad):
        r = bad.iloc[0]
        raise StudyFolderError(f'{r["_file"]}: line {r["_line"]}: {measure} {r[measure]!r} is not a number')
    empty = int(values.isna().sum())
    if empty:
        notes.append(f'{measure}: {empty} trial(s) without a value (e.g. no target found) are left out')
    frame = frame.assign(**{measure: values})[values.notna()]
    for subject in dict.fromkeys(data.frame['subject']):
        have = set(frame.loc[frame['subject'] == subject, 'condition'])
        missing = [c for c in data.conditions if c not in have]
        if missing:
            notes.append(f'participant {subject} is left out of {measure}: no finished trial in '
                         f'{", ".join(missing)}')
            frame = frame[frame['subject'] != subject]
    return frame.reset_index(drop=True), notes
