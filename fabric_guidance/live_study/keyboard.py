"""The operator's terminal as a confirm source and the session's commands: one key, no Enter
(the terminal in cbreak mode while it runs, restored after).

  space or Enter  confirm (published on `confirm`, frame_id 'keyboard', stamped when read)
  p  pause    r  repeat    s  skip    q  stop (vents at once)    c  resume
  e  arm: the operator's enable, then the session goes on (after a vent or a restart held it)

KeyboardSource(press, command, stream) reads `stream` (default stdin) on a thread: press() for a
confirm key, command(name) for the others; any other key is ignored.
"""
from __future__ import annotations

import contextlib
import os
import sys
import threading
from typing import Callable, TextIO

CONFIRM_KEYS = (' ', '\n', '\r')
COMMANDS = {'p': 'pause', 'r': 'repeat', 's': 'skip', 'q': 'stop', 'c': 'resume', 'e': 'arm'}


@contextlib.contextmanager
def cbreak(stream: TextIO):
    """Keys one at a time, without echo, while the block runs (nothing to do off a terminal)."""
    try:
        fd = stream.fileno()
        tty_ok = os.isatty(fd)
    except (AttributeError, OSError, ValueError):
        tty_ok = False
    if not tty_ok:
        yield
        return
    import termios
    import tty
    saved = termios.tcgetattr(fd)
    try:
        tty.setcbreak(fd)
        yield
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)


class KeyboardSource:
    def __init__(self, press: Callable[[], None], command: Callable[[str], None] = lambda name: None,
                 stream: TextIO | None = None):
        self.press, self.command = press, command
        self.stream = stream if stream is not None else sys.stdin
        self.presses = 0
        self._thread = threading.Thread(target=self._run, name='study-keyboard', daemon=True)

    def start(self) -> 'KeyboardSource':
        self._thread.start()
        return self

    def join(self, timeout: float | None = None) -> None:
        self._thread.join(timeout)

    def _run(self) -> None:
        with cbreak(self.stream):
            while True:
                key = self.stream.read(1)
                if not key:            # end of input
                    return
                if key in CONFIRM_KEYS:
                    self.presses += 1
                    self.press()
                elif key.lower() in COMMANDS:
                    self.command(COMMANDS[key.lower()])
                    if key.lower() == 'q':
                        return
