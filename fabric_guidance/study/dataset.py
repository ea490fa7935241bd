"""The files that make a study folder a BIDS dataset (BIDS 1.10, behavioural data): its
description with what wrote it (package version and git commit), a README, and a .bidsignore
for what BIDS has no place for (the bags, the recorder's logs, the scene files).
"""
from __future__ import annotations

from functools import lru_cache
from importlib import metadata
from pathlib import Path
import subprocess

#: The BIDS version the folder follows (the schema of the pinned bids-validator: test_study_bids).
BIDS_VERSION = '1.10.0'
PACKAGE = __package__.split('.')[0]
#: What BIDS tools are to pass over (.bidsignore, gitignore patterns; sourcedata/ they pass over
#: anyway: the simulated graph's logs go there).
IGNORED = ('scene-*.yaml', 'timing-*.json', '**/*_bag/', '**/*_recorder.log')

README = """# {name}

A study of guidance by a pneumatic fabric suit (Yokoe et al., IEEE Trans. Haptics 2025), written
by {package} {version} (git commit {commit}) as it ran: a BIDS dataset of behavioural data.

- `participants.tsv`: one row per participant, in registration order (`index` seeds their
  condition order and targets: it is the package's; add your own columns beside it).
- `sub-<id>/ses-<n>/beh/sub-<id>_ses-<n>_task-<speed|accuracy>_beh.tsv`: one row per trial;
  its `.json` describes every column and holds every parameter of the task.
- `..._run-<r>_events.tsv`: one row per event of a run (a block's attempt), onsets in seconds
  from the run's start; its first row (`run_start`) gives that start on the steady clock and
  in UTC.
- `..._run-<r>_bag/`: the run's rosbag2 bag (not BIDS: listed in `.bidsignore`).
- `sourcedata/logs/`: a simulated study's graph logs and calibrations.

`fabric-guidance analyze <this folder>` runs the paper's statistics on it.
"""


@lru_cache(maxsize=1)
def package_version() -> str:
    try:
        return metadata.version(PACKAGE)
    except metadata.PackageNotFoundError:
        return 'unknown'


@lru_cache(maxsize=1)
def git_commit() -> str:
    """The commit of the running code ('' when not a git checkout)."""
    try:
        return subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], capture_output=True, text=True, timeout=5,
                              cwd=Path(__file__).resolve().parent).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ''


def description(name: str, format_key: str, format_version: int) -> dict:
    """dataset_description.json's content."""
    generated = {'Name': PACKAGE, 'Version': package_version(),
                 'Description': f'git commit {git_commit() or "unknown"}: the study session as it ran'}
    return {'Name': name, 'BIDSVersion': BIDS_VERSION, 'DatasetType': 'raw', format_key: format_version,
            'GeneratedBy': [generated]}


def readme(name: str) -> str:
    return README.format(name=name, package=PACKAGE, version=package_version(), commit=git_commit() or 'unknown')


def bidsignore() -> str:
    return '\n'.join(IGNORED) + '\n'
