"""nodes/log_throttle.py: a line is due once per period for each key, the first at once."""
import time

from fabric_guidance.nodes.log_throttle import LogThrottle


def test_one_line_per_key_per_period():
    throttle = LogThrottle(3600.0)
    assert throttle.due('above p_max')
    assert not any(throttle.due('above p_max') for _ in range(1000))
    assert throttle.due('invalid')                 # another key has its own period
    assert not throttle.due('invalid')


def test_due_again_once_the_period_has_passed():
    throttle = LogThrottle(0.01)
    assert throttle.due('k')
    deadline = time.monotonic() + 5.0
    while not throttle.due('k'):                   # due again after 10 ms; a deadline, not a sleep
        assert time.monotonic() < deadline, 'not due again within 5 s of a 10 ms period'
