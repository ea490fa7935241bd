"""What the command-line tests share (test_cli_interrupt.py, test_dry_run_command.py): a
`fabric-guidance` subcommand in a process of its own, its output gathered line by line, stopped
with the signal a terminal sends."""
from __future__ import annotations

import signal
import subprocess
import sys
import threading

from rosgraph import wait_until

#: Signal -> the command's exit, its graph stopped (each node vents within its bounded teardown).
EXIT_S = 60.0


class Command:
    """`python -m fabric_guidance.commands.cli ARGV...` with `env`, stdout and stderr as one stream.

    `new_session`: the command leads a session of its own, so a test can kill its whole process
    group without touching pytest's."""

    def __init__(self, argv: list[str], env: dict, *, new_session: bool = False):
        # SIGINT at its default, as in a terminal: a child of a shell's background job ignores it.
        self.proc = subprocess.Popen([sys.executable, '-m', 'fabric_guidance.commands.cli', *argv],
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
                                     start_new_session=new_session,
                                     preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(line.rstrip('\n'))

    def text(self) -> str:
        return '\n'.join(self.lines)

    def wait(self, what: str) -> int:
        """Its exit status once it has ended (within EXIT_S) and its last line is read."""
        wait_until(lambda: self.proc.poll() is not None, EXIT_S, what=what)
        self._reader.join(5.0)
        return self.proc.returncode

    def stop(self, sig: int) -> int:
        self.proc.send_signal(sig)
        return self.wait(f'the command to exit after signal {sig}')

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
