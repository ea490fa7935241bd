"""The process graph's helpers that keep concurrent graphs apart: the domain ids of pytest-xdist
workers never meet, and a run's processes are found by a variable in their environment (not by
their command line, which other graphs started from the same files share)."""
import os
import socket
import subprocess
import sys

import pytest

from fabric_guidance.graph.process_graph import _above_ephemeral, free_port, fresh_domain_id, processes_with
from rosgraph import wait_until


def ids_of(monkeypatch, worker, workers, n=300):
    monkeypatch.setenv('PYTEST_XDIST_WORKER', f'gw{worker}')
    monkeypatch.setenv('PYTEST_XDIST_WORKER_COUNT', str(workers))
    return {fresh_domain_id() for _ in range(n)}


def test_the_domain_ids_of_xdist_workers_never_meet(monkeypatch):
    for workers in (2, 3):
        drawn = [ids_of(monkeypatch, w, workers) for w in range(workers)]
        for w, ids in enumerate(drawn):
            assert ids <= set(range(1, 101)) and len(ids) == 100 // workers, (workers, w, sorted(ids))
            assert all(i % workers == (w + 1) % workers for i in ids), (workers, w, sorted(ids))
        assert not set.intersection(*drawn)
    # Outside xdist (or with variables it does not set that way) every id 1..100 is drawn.
    monkeypatch.delenv('PYTEST_XDIST_WORKER')
    assert {fresh_domain_id() for _ in range(300)} == set(range(1, 101))
    monkeypatch.setenv('PYTEST_XDIST_WORKER', 'gw7')
    monkeypatch.setenv('PYTEST_XDIST_WORKER_COUNT', '2')
    assert {fresh_domain_id() for _ in range(300)} == set(range(1, 101))


def test_a_simulated_studys_domain_is_a_safe_one_and_never_the_shells(monkeypatch):
    """study --simulated picks its graph's domain as the tests do (1-100: above 101 the DDS ports
    fall in Linux's ephemeral range) and never the domain ROS_DOMAIN_ID names (a running graph's)."""
    from fabric_guidance.live_study.simulated import own_domain_id
    monkeypatch.setenv('PYTEST_XDIST_WORKER', 'gw1')
    monkeypatch.setenv('PYTEST_XDIST_WORKER_COUNT', '2')
    monkeypatch.setenv('ROS_DOMAIN_ID', '42')
    drawn = {own_domain_id() for _ in range(300)}
    assert drawn == set(range(2, 101, 2)) - {42}, sorted(drawn)


def test_processes_with_finds_a_marked_process_and_its_child_until_they_end():
    mark = f'{os.getpid()}-marked'
    # A parent that starts a child (which inherits the environment), both sleeping.
    code = 'import subprocess, sys, time; subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"]); ' \
           'time.sleep(60)'
    proc = subprocess.Popen([sys.executable, '-c', code], env={**os.environ, 'FABRIC_GUIDANCE_TEST_MARK': mark},
                            start_new_session=True)
    try:
        found = wait_until(lambda: len(processes_with('FABRIC_GUIDANCE_TEST_MARK', mark)) == 2 and
                           processes_with('FABRIC_GUIDANCE_TEST_MARK', mark), 20.0, what='both marked processes')
        assert any(line.startswith(f'pid {proc.pid}:') for line in found), found
        assert processes_with('FABRIC_GUIDANCE_TEST_MARK', mark + 'x') == []
    finally:
        os.killpg(proc.pid, 9)
        proc.wait(10)
    wait_until(lambda: processes_with('FABRIC_GUIDANCE_TEST_MARK', mark) == [], 10.0, what='the marked processes gone')


def test_a_graphs_ports_lie_above_the_kernels_ephemeral_range_and_are_free():
    """A port the kernel hands out (a connect, a bind to 0) can never be one a graph chose before
    its node bound it: free_port takes them above the ephemeral range (here 32768-60999)."""
    span = _above_ephemeral()
    if span is None:
        pytest.skip('no ephemeral range to read, or no room above it')
    for kind in (socket.SOCK_STREAM, socket.SOCK_DGRAM):
        ports = [free_port(kind) for _ in range(20)]
        assert all(span[0] <= p <= span[1] for p in ports), (span, sorted(ports))
        assert len(set(ports)) == 20              # never the same port twice before it is bound
        with socket.socket(socket.AF_INET, kind) as s:
            s.bind(('127.0.0.1', ports.pop()))     # still free to bind


def test_each_xdist_worker_takes_ports_of_its_own(monkeypatch):
    """Workers run graphs side by side: worker i of n takes only ports equal to i modulo n, so
    two workers never choose the same port before either binds it."""
    if _above_ephemeral() is None:
        pytest.skip('no ephemeral range to read, or no room above it')
    for worker in range(3):
        monkeypatch.setenv('PYTEST_XDIST_WORKER', f'gw{worker}')
        monkeypatch.setenv('PYTEST_XDIST_WORKER_COUNT', '3')
        assert {free_port() % 3 for _ in range(10)} == {worker}
