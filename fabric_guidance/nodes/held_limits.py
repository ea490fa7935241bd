"""The safety limits a person tightened at run time, held across restarts of pressure_controller.

A lowered p_max_kpa (or a shortened gaze_timeout_s, stall_timeout_s) must survive the death of
the PC process that took it: a respawned controller comes up with the tightest limit in force.
The node writes the limits in force to one small YAML file per namespace, atomically (atomic.py),
every time one is tightened, and reads it at every start:

    <state_dir>/<namespace or _root>/pressure_controller_limits.yaml

    held:                      # name: value, only the limits tightened at run time
      p_max_kpa: 100.0
    set_at: '2026-11-28T18:03:12Z'

At start the value in force is the tighter of the parameter (params file, launch) and the held
one. Only a person loosens a held limit: stop the controller, remove (or edit) the file, start
it again (docs/safety.md). A file that cannot be read stops the start-up with one line naming it:
a limit that cannot be known is not guessed.
"""
from __future__ import annotations

import os
from pathlib import Path
import time
from typing import Any

import yaml

from ..atomic import write_text
from ..core.controller_parameters import LIMITS, check

#: The environment variable that moves the default folder (the tests' and a lab's own place).
STATE_DIR_ENV = 'FABRIC_GUIDANCE_STATE_DIR'
FILE_NAME = 'pressure_controller_limits.yaml'


def state_folder(value: str) -> Path:
    """The state_dir parameter's folder ('' : $FABRIC_GUIDANCE_STATE_DIR, else ~/.fabric_guidance/state)."""
    if value:
        return Path(value).expanduser()
    env = os.environ.get(STATE_DIR_ENV, '')
    return Path(env).expanduser() if env else Path.home() / '.fabric_guidance' / 'state'


def limits_file(state_dir: str, namespace: str) -> Path:
    """The file of the controller in `namespace` ('/' or '' : the root)."""
    ns = '_'.join(part for part in namespace.split('/') if part) or '_root'
    return state_folder(state_dir) / ns / FILE_NAME


def read_held(path: Path) -> dict[str, Any]:
    """The held limits of `path` ({} when there is no file); ValueError naming the file and field."""
    if not path.is_file():
        return {}
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f'held limits {path}: cannot be read ({" ".join(str(exc).split())[:120]}); '
                         'a person checks it or removes it (docs/safety.md)') from None
    held = data.get('held') if isinstance(data, dict) else None
    if not isinstance(held, dict):
        raise ValueError(f'held limits {path}: field "held" must map limit names to values; '
                         'a person checks it or removes it (docs/safety.md)')
    out = {}
    for name, value in held.items():
        if name not in LIMITS:
            raise ValueError(f'held limits {path}: field "held.{name}" is no safety limit (one of {list(LIMITS)})')
        out[name] = check(name, value, f'held limits {path}: field "held.{name}"')
    return out


def write_held(path: Path, held: dict[str, Any]) -> None:
    """Hold `held` in `path` (atomically: a crash leaves the old file or the new one)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    text = yaml.safe_dump({'held': {k: held[k] for k in LIMITS if k in held},
                           'set_at': time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())}, sort_keys=False)
    write_text(path, text)


__all__ = ['STATE_DIR_ENV', 'limits_file', 'read_held', 'state_folder', 'write_held']
