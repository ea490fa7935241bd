"""Writing a file so that a crash (SIGKILL, power loss) leaves the previous file or the new one,
never part of one: the content goes to a temporary file in the same directory (the rename must
not cross file systems), is flushed and fsynced, then os.replace puts it in place in one step.
Every file the package writes whole (calibrations, reports, tables, plots, profiles, policies,
the mock PLC's records) goes through here. Plain Python: the lowest layer.
"""
from __future__ import annotations

import os
from pathlib import Path
import tempfile
from typing import Callable, IO

# mkstemp creates 0600 files; a new file gets the mode open() would give it (read once, at
# import: setting the umask to read it is not thread safe).
_UMASK = os.umask(0o022)
os.umask(_UMASK)


def _fsync_dir(directory: Path) -> None:
    """Make the rename itself durable; some file systems cannot open a directory (skipped)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def atomic_write(path: str | Path, write: Callable[[IO], object], mode: str = 'wb',
                 check: Callable[[Path], object] | None = None) -> Path:
    """write(file object) into a temporary file beside `path` (opened with `mode`, 'wb' or 'w'),
    fsync it, run check(temporary path) if given (it raises to refuse the file), then rename it
    over `path`. On any error, also KeyboardInterrupt, the old file stays and the temporary one
    is removed. Returns `path`."""
    if mode not in ('wb', 'w'):
        raise ValueError(f'atomic_write: mode must be "wb" or "w", got {mode!r}')
    path = Path(path).expanduser()
    fd, tmp = tempfile.mkstemp(prefix=f'.{path.name}.', suffix='.tmp', dir=path.parent)
    try:
        # newline='': what the caller writes is what lands (csv writers bring their own line ends)
        with os.fdopen(fd, mode, **({} if 'b' in mode else {'encoding': 'utf-8', 'newline': ''})) as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, path.stat().st_mode & 0o7777 if path.exists() else 0o666 & ~_UMASK)
        if check is not None:
            check(Path(tmp))
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)
    return path


def write_text(path: str | Path, text: str, check: Callable[[Path], object] | None = None) -> Path:
    """`text` (UTF-8) to `path` atomically; the replacement for Path.write_text."""
    return atomic_write(path, lambda f: f.write(text), 'w', check)


def write_bytes(path: str | Path, data: bytes) -> Path:
    """`data` to `path` atomically; the replacement for Path.write_bytes."""
    return atomic_write(path, lambda f: f.write(data))


def write_csv(path: str | Path, frame) -> Path:
    """A pandas DataFrame as CSV (no index) to `path` atomically."""
    return atomic_write(path, lambda f: frame.to_csv(f, index=False), 'w')
