"""Ctrl-C or SIGTERM to a command that runs a graph: one line saying what stopped and what is
left, exit 130, no traceback, and nothing of the graph left behind (its nodes, its temporary
logs). The clean-up itself is the commands' `finally` blocks; this is what the person sees."""
from __future__ import annotations

import os
from pathlib import Path
import re
import signal

import pytest

from cli_support import Command
from rosgraph import fresh_domain_id, wait_until

pytestmark = pytest.mark.graph   # the commands start process graphs

#: A cold start of the graph on a loaded 2-core machine, to its first guided target.
STARTED_S = 90.0


def command(*argv: str) -> Command:
    """A `fabric-guidance` command on a fresh ROS domain of its own."""
    return Command(list(argv), dict(os.environ, ROS_DOMAIN_ID=str(fresh_domain_id()), PYTHONUNBUFFERED='1'))


def _node_processes(parent: int) -> list[int]:
    """Processes a graph of `parent` started (nodes/parent.py names the graph's pid in each)."""
    found = []
    for entry in Path('/proc').iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / 'cmdline').read_bytes()
        except OSError:
            continue
        if b'fabric_guidance.nodes.' in cmdline and f'pid={parent}'.encode() in _graph_of(entry):
            found.append(int(entry.name))
    return found


def _graph_of(entry: Path) -> bytes:
    """The FABRIC_GUIDANCE_GRAPH token of a process (the graph's pid leads it), as 'pid=<pid>'."""
    try:
        env = (entry / 'environ').read_bytes().split(b'\0')
    except OSError:
        return b''
    for var in env:
        if var.startswith(b'FABRIC_GUIDANCE_GRAPH='):
            return b'pid=' + var.split(b'=', 1)[1].split(b'-', 1)[0]
    return b''


@pytest.mark.parametrize('sig, named', [(signal.SIGINT, 'Ctrl-C'), (signal.SIGTERM, 'SIGTERM')])
def test_a_stopped_demo_says_so_in_one_line_and_leaves_nothing_running(sig, named):
    cmd = command('demo')
    try:
        wait_until(lambda: re.search(r'target \S+ active', cmd.text()), STARTED_S, what='the demo guiding')
        logs = re.search(r'logs in (\S+) \(removed at the end', cmd.text())
        assert logs, cmd.text()
        code = cmd.stop(sig)
    finally:
        cmd.close()
    out = cmd.text()
    assert 'Traceback' not in out, out
    assert code == 130, out
    assert cmd.lines[-1].startswith(f'fabric-guidance demo: stopped ({named}): the simulated graph is stopped'), out
    assert not Path(logs.group(1)).exists(), f'{logs.group(1)} left behind'
    assert not _node_processes(cmd.proc.pid), 'nodes of the demo still running'


def test_a_demo_whose_nodes_die_says_so_in_lines_without_a_traceback():
    """The nodes (the mock PLC among them) killed under a running demo, as a Ctrl-C that reached
    them and not the demo would (a demo started from a script's background job ignores SIGINT):
    it says which ended and that the PLC could not be read back, and exits 1 (it printed a
    PlcLinkError traceback)."""
    cmd = command('demo')
    try:
        wait_until(lambda: re.search(r'target \S+ active', cmd.text()), STARTED_S, what='the demo guiding')
        for pid in _node_processes(cmd.proc.pid):
            os.kill(pid, signal.SIGKILL)
        code = cmd.wait('the demo to end')
    finally:
        cmd.close()
    out = cmd.text()
    assert 'Traceback' not in out, out
    assert code == 1, out
    assert 'exited early' in out and 'the PLC registers could not be read back after shutdown' in out, out


def test_a_stopped_simulated_study_says_how_to_go_on(tmp_path):
    cmd = command('study', '--simulated', '--participants', '1', '--out', str(tmp_path / 'study'))
    try:
        wait_until(lambda: 'recording block 1' in cmd.text(), STARTED_S, what='the first block under way')
        code = cmd.stop(signal.SIGINT)
    finally:
        cmd.close()
    out = cmd.text()
    assert 'Traceback' not in out, out
    assert code == 130, out
    assert cmd.lines[-1] == ('fabric-guidance study: stopped (Ctrl-C): the session is stopped; the trials that '
                             'ended are in the study folder, and the same command resumes it'), out
    # how long it would have taken, said before the first block began
    said = [i for i, line in enumerate(cmd.lines) if line.startswith('study: at least 17 min: 1 participants')]
    assert said and said[0] < next(i for i, line in enumerate(cmd.lines) if 'recording block 1' in line), out
    assert not _node_processes(cmd.proc.pid), 'nodes of the study still running'
