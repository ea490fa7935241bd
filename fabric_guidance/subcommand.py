"""One way to build a `fabric-guidance <name>` subcommand and its stand-alone `python -m` entry
from a module's HELP, docstring, configure(parser) and run(args)."""
from __future__ import annotations

import argparse
import signal
import sys
import threading
from typing import Callable, Sequence, TextIO

Configure = Callable[[argparse.ArgumentParser], argparse.ArgumentParser]


def add(subparsers, name: str, help_text: str, doc: str | None, configure: Configure,
        run: Callable[[argparse.Namespace], int]) -> argparse.ArgumentParser:
    """The subcommand `name` on an argparse subparsers object; `args.run(args)` calls run."""
    parser = subparsers.add_parser(name, help=help_text, description=doc,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
    configure(parser).set_defaults(run=run)
    return parser


def stop_on_sigterm() -> None:
    """SIGTERM (a supervisor, `kill`, a CI timeout) ends a command as Ctrl-C does: as a
    KeyboardInterrupt, so its clean-up runs. Without it the runs that start a graph of processes
    (soak, chaos, demo, bench) died at once and left their nodes running."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _interrupt)


def _interrupt(signum, frame):
    raise KeyboardInterrupt(f'signal {signum}')


def interrupted(prog: str, exc: KeyboardInterrupt, after: str = '') -> int:
    """One line for a command that Ctrl-C or SIGTERM stopped, and the shell's 130. By the time
    the exception reaches here it has come through the command's `finally` blocks: its graph is
    stopped (each node vents on its way out) and its temporary folders removed. `after`: what the
    command leaves behind or how to go on."""
    how = 'SIGTERM' if str(exc) == f'signal {int(signal.SIGTERM)}' else 'Ctrl-C'
    print(f'{prog}: stopped ({how})' + (f': {after}' if after else ''), file=sys.stderr, flush=True)
    return 130


def main(prog: str, doc: str | None, configure: Configure,
         run: Callable[[argparse.Namespace], int], argv: Sequence[str] | None = None) -> int:
    """The module run on its own (`python -m ...`): the same options, no subcommand."""
    stop_on_sigterm()
    parser = argparse.ArgumentParser(prog=prog, description=doc,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    return run_until_stopped(prog, run, configure(parser).parse_args(argv))


#: The shell's status of a command that SIGPIPE ended (128 + 13): what `... | head` leaves.
BROKEN_PIPE = 141


def run_until_stopped(prog: str, run: Callable[[argparse.Namespace], int], args: argparse.Namespace) -> int:
    """run(args); Ctrl-C or SIGTERM: one line (with its module's ON_STOP) and 130, no traceback.
    The reader of its output gone (`... | head`): quietly BROKEN_PIPE, as any Unix filter."""
    try:
        return run(args)
    except KeyboardInterrupt as exc:
        return interrupted(prog, exc, getattr(sys.modules.get(run.__module__), 'ON_STOP', ''))
    except BrokenPipeError:
        # The command's finally blocks have run (its graph stopped). Python flushes stdout once
        # more at exit, into the closed pipe: point it at /dev/null so that flush is quiet too.
        import os
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return BROKEN_PIPE


def writable_folder(path) -> str:
    """'' when `path` is a folder this process can write into (made if missing), else why not,
    checked before a command starts anything that would write there at its end."""
    import os
    import tempfile
    from pathlib import Path
    folder = Path(path).expanduser()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        return f'cannot write into {folder}: {exc.strerror or exc}'
    return '' if os.access(folder, os.W_OK) else f'cannot write into {folder}'


def results_folder(out, overwrite: bool) -> str:
    """'' when `out` may take a run's results (missing, empty, or `overwrite`), else why not:
    another run's files would mix with this one's, with nothing to tell them apart."""
    from pathlib import Path
    out = Path(out)
    if out.exists() and not out.is_dir():
        return f'--out {out} is a file, not a folder'
    names = sorted(p.name for p in out.iterdir()) if out.is_dir() else []
    if names and not overwrite:
        shown = ', '.join(names[:3]) + (', ...' if len(names) > 3 else '')
        return (f'--out {out} already holds {len(names)} file(s) ({shown}): another run\'s results would mix '
                'with this one\'s; give a new --out, or --overwrite to write over them')
    return ''


def printer(stream: TextIO) -> Callable[..., None]:
    """say(line=''): print a line to stream and flush it, so progress shows as it happens."""
    def say(line: str = '') -> None:
        print(line, file=stream, flush=True)
    return say


def error(prog: str, message) -> None:
    """`prog: error: message` on stderr, always one line (a message's own line breaks folded)."""
    print(f'{prog}: error: {" ".join(str(message).split())}', file=sys.stderr)
