"""The columns of a study's trials file, each with its unit and meaning (the JSON sidecar
describes them from here). First the columns of the headless experiment's trials
(sim.protocols.TrialRecord: `analyze`, the experiment's plots and compare-paper read human data
unchanged), then what a live trial adds.

A trials file is a BIDS behavioural file: a column may not be named after a BIDS entity (BIDS
tools take `subject` or `session` for the file's own), so the session's `subject` and `session`
are written as `subject_index` and `session_number` (FILE_NAMES); COLUMNS are the file's names.
"""
from __future__ import annotations

from dataclasses import fields

from ..sim.protocols import TrialRecord

#: TrialRecord's columns as a study fills them: (unit, description).
RECORD_COLUMNS: dict[str, tuple[str, str]] = {
    'scene': ('-', "the scene a simulated study ran (its name); a live session: the study folder's name"),
    'protocol': ('-', "the task: 'speed' or 'accuracy'"),
    'subject': ('-', 'participant index, 0-based in registration order (seeds the order and targets)'),
    'wearer': ('-', 'participant id (sub-<id> without the prefix)'),
    'condition': ('-', "the paper's condition, 1-4 (Table I)"),
    'repetition': ('-', '0-based trial number within the condition'),
    'order': ('-', "1-based position of the condition in the participant's order"),
    'target_h_deg': ('deg', 'accuracy: target azimuth from the front, positive left'),
    'target_v_deg': ('deg', 'accuracy: target elevation, positive up'),
    'h_error_deg': ('deg', 'accuracy: |gaze - target| horizontally, from the gaze sample at the press'),
    'v_error_deg': ('deg', 'accuracy: |gaze - target| vertically, from the gaze sample at the press'),
    'tracked_h_error_deg': ('deg', "accuracy: as h_error_deg (live, the tracker's gaze is the gaze)"),
    'tracked_v_error_deg': ('deg', 'accuracy: as v_error_deg'),
    'time_s': ('s', 'accuracy: from the trial start (target set) to the press (or the timeout)'),
    'timed_out': ('-', 'accuracy: True when no press came within timeout_s'),
    'identified': ('-', 'speed: targets identified (accepted presses) within trial_s'),
    'presented': ('-', 'speed: targets that appeared'),
    'mean_find_s': ('s', 'speed: mean time from a target appearing to its accepted press'),
}
assert list(RECORD_COLUMNS) == [f.name for f in fields(TrialRecord)], 'RECORD_COLUMNS out of step with TrialRecord'

#: What a live trial adds, filled by the session.
SESSION_COLUMNS: dict[str, tuple[str, str]] = {
    'session': ('-', 'BIDS session number (ses-<n>)'),
    'status': ('-', "'ok' (analysed), 'repeated' (the operator repeated it), 'skipped', 'stopped' "
                    "(the session was stopped during it), 'interrupted' (its block was cut off by a crash), "
                    "'vented' (the operator's arm dropped during it: an outside vent, a controller restart or a "
                    "lost controller; run again once the operator re-arms)"),
    'block': ('-', 'the block: task, position and condition (one bag per block)'),
    'trial_start_s': ('s', 'steady clock when the trial started (trial gate opened, target set)'),
    'trial_end_s': ('s', 'steady clock when the trial ended (speed: trial_start_s + trial_s exactly)'),
    'press_s': ('s', 'steady clock capture time of the press that ended an accuracy trial, or of the '
                     'last accepted press of a speed trial; empty if none'),
    'press_source': ('-', "where that press came from: its confirm's frame_id ('keyboard', 'headset', "
                          "'wearer_sim'; another tool's own)"),
    'press_age_s': ('s', 'that press: received minus captured (its delivery latency)'),
    'gaze_at_press_s': ('s', 'steady clock capture time of the gaze sample its error was taken from'),
    'presses': ('-', 'presses accepted in the trial'),
    'refused_presses': ('-', 'presses refused in the trial (stale, duplicate, or speed: outside acceptance)'),
    'ignored_presses': ('-', 'presses in the trial from a source the session does not judge (press_sources): '
                             'not judged, each kept in the block\'s bag on confirm'),
}

#: What the operator layer passes once (Session's context), copied into every row.
CONTEXT_COLUMNS: dict[str, tuple[str, str]] = {
    'gaze_source': ('-', "where the gaze came from: 'headset', 'wearer_sim', ..."),
    'clock_state': ('-', "the headset clock's synchronisation state at the trial ('synced', 'free', '-')"),
    'calibration_file': ('-', "the participant's calibration file name"),
    'calibration_sha256': ('-', 'SHA-256 of that file as it was read'),
    'package_version': ('-', 'fabric_guidance version'),
    'git_commit': ('-', 'commit of the running code, empty when not a git checkout'),
}

#: Filled by the store as it writes the row.
STORE_COLUMNS: dict[str, tuple[str, str]] = {
    'recorded_utc': ('-', 'wall-clock time the row was written, ISO 8601 UTC'),
}

COLUMNS: dict[str, tuple[str, str]] = {**RECORD_COLUMNS, **SESSION_COLUMNS, **CONTEXT_COLUMNS, **STORE_COLUMNS}
#: The session's row keys written under another name (a BIDS entity's name is the file's own).
FILE_NAMES = {'subject': 'subject_index', 'session': 'session_number'}
#: The columns as the file has them, in order.
COLUMNS = {FILE_NAMES.get(k, k): v for k, v in COLUMNS.items()}
#: The context keys the operator layer supplies.
LIVE_CONTEXT = tuple(CONTEXT_COLUMNS)
