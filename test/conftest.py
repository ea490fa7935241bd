"""Hypothesis profiles: what randomness the property tests may use.

- "ci": derandomize=True (examples derived from each test's source, the same on every run
  and every clone), no example database (nothing carried between runs), print_blob=True (a
  failure prints the exact reproduction blob). Loaded whenever the CI environment variable
  is set, so a submission is never rejected by chance.
- "dev": hypothesis's defaults (random, with the local example database); the default
  elsewhere.
- "deep": many more random examples, for people to run (`make test-deep`) to search for
  defects that the fixed CI examples do not reach.
HYPOTHESIS_PROFILE selects one explicitly when CI is not set.

Every test holds its safety limits (pressure_controller's held limits, nodes/held_limits.py) in
a folder of its own (`held_limits_apart` below): a limit one test tightens is never in force in
another's controller. A process graph keeps its own folder too (process_graph.Graph).

`make test` runs pytest on three pytest-xdist workers (whole files to a worker). A test marked
`serial` claims something of a quiet machine (a soak run that loses nothing): while it runs, the
other workers run no test (the `serial_lock` fixture below).
"""
import fcntl
import os

from hypothesis import HealthCheck, settings
import pytest

# No deadline and no too-slow health check in any profile: an example's time on two loaded cores
# is the machine's, and a property test that fails on it fails by chance (timing belongs to the
# benchmarks). A test that sets its own deadline keeps it.
UNTIMED = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.register_profile('ci', derandomize=True, database=None, print_blob=True, **UNTIMED)
settings.register_profile('dev', **UNTIMED)
settings.register_profile('deep', max_examples=2000, derandomize=False, **UNTIMED)

if os.environ.get('CI'):
    settings.load_profile('ci')
else:
    settings.load_profile(os.environ.get('HYPOTHESIS_PROFILE', 'dev'))


def pytest_collection_modifyitems(config, items):
    # `make test-deep` selects the property tests with -m property; hypothesis marks them.
    for item in items:
        if getattr(getattr(item, 'obj', None), 'is_hypothesis_test', False):
            item.add_marker('property')


@pytest.fixture(autouse=True)
def serial_lock(request, tmp_path_factory):
    """Under pytest-xdist: every test holds a shared lock on a file of this run's workers, a
    `serial` test an exclusive one, so a serial test runs alone. Both are taken through a
    turnstile held while waiting, so a waiting serial test is not starved by the other worker's
    tests taking turns on the shared lock. Outside xdist there is nothing to wait for."""
    if not os.environ.get('PYTEST_XDIST_WORKER'):
        yield
        return
    folder = tmp_path_factory.getbasetemp().parent      # one per run, shared by its workers
    exclusive = request.node.get_closest_marker('serial') is not None
    with open(folder / 'serial.turnstile', 'a') as turnstile, open(folder / 'serial.lock', 'a') as lock:
        fcntl.flock(turnstile, fcntl.LOCK_EX)
        try:
            fcntl.flock(lock, fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)
        finally:
            fcntl.flock(turnstile, fcntl.LOCK_UN)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


@pytest.fixture(autouse=True)
def held_limits_apart(tmp_path, monkeypatch):
    """This test's own state folder for the limits its controllers hold across restarts."""
    monkeypatch.setenv('FABRIC_GUIDANCE_STATE_DIR', str(tmp_path / 'held_limits'))
