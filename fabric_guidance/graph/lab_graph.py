"""What the lab launch (launch/guidance.launch.py, through launch_support.py) and `fabric-guidance
dry-run` (commands/dry_run.py) share, importable without `launch`, which the wheels do not install.
"""
from __future__ import annotations

#: The line mock_plc logs once its listener accepts connections (nodes/mock_plc.py): the lab
#: nodes start after it, so that plc_output's first connection succeeds.
MOCK_PLC_LISTENING = 'mock PLC listening on'

#: The study's tasks: each loads config/params/study-<task>.yaml after the other files.
STUDY_TASKS = ('speed', 'accuracy')

#: Seconds from a lab node's process dying to its restart (the launch argument respawn_delay's default).
RESPAWN_DELAY_S = 2.0


def study_params_file(task: str) -> str:
    """The parameter file of a study task, relative to config/; ValueError for another task."""
    if task not in STUDY_TASKS:
        raise ValueError(f"{task!r} is not one of {', '.join(STUDY_TASKS)}")
    return f'params/study-{task}.yaml'
