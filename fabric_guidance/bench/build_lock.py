"""`make -C FOLDER` one at a time per folder, for the bench and the tests: pytest-xdist workers
and a bench run beside them that build the same outputs at once would write them together, and
one of them could run a binary the other is still linking. The lock file sits in the folder's
build output, which git ignores."""
from __future__ import annotations

import fcntl
from pathlib import Path
import subprocess


def locked_run(command: list[str], build_output: Path, timeout: float) -> subprocess.CompletedProcess:
    """Run `command` (a make of the folder whose build output is `build_output`) holding
    build_output/.make.lock; its output captured as text."""
    build_output = Path(build_output)
    build_output.mkdir(parents=True, exist_ok=True)
    with open(build_output / '.make.lock', 'a') as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        return subprocess.run(command, capture_output=True, text=True, timeout=timeout)
