"""Condition 4's phrase, the acceptance test of the task protocol, the four conditions."""
import math

import pytest

from fabric_guidance.core.conditions import condition
from fabric_guidance.core.speech import phrase
from fabric_guidance.core.task import AcceptanceTracker, angular_error_deg


def test_paper_example_phrase():
    # The paper: target 36 deg right and 12 deg up -> "36 to the right and 12 upward".
    assert phrase(-36.0, 12.0) == '36 to the right and 12 upward'


@pytest.mark.parametrize('h, v, text', [
    (10.4, -0.4, '10 to the left'),
    (0.2, -25.6, '26 downward'),
    (0.4, 0.4, 'straight ahead'),
    (59.5, 30.0, '60 to the left and 30 upward'),
])
def test_phrases(h, v, text):
    assert phrase(h, v) == text


def test_phrase_rejects_non_finite():
    with pytest.raises(ValueError):
        phrase(float('nan'), 0.0)


def test_angular_error():
    assert angular_error_deg([1, 0, 0], [1, 1, 0]) == pytest.approx(45.0)
    assert angular_error_deg([1, 0, 0], [1, 0, 0]) == 0.0
    assert angular_error_deg([1, 0, 0], [-1, 0, 0]) == pytest.approx(180.0)


def test_acceptance_needs_the_dwell():
    tr = AcceptanceTracker(acceptance_deg=5.0, dwell_s=0.3)
    near = [math.cos(math.radians(4)), math.sin(math.radians(4)), 0]
    far = [math.cos(math.radians(6)), math.sin(math.radians(6)), 0]
    target = [1, 0, 0]
    assert not tr.update(near, target, 0.0)
    assert not tr.update(near, target, 0.2)
    assert not tr.update(far, target, 0.25)      # left the cone: the dwell restarts
    assert not tr.update(near, target, 0.3)
    assert not tr.update(near, target, 0.5)
    assert tr.update(near, target, 0.6)


def test_conditions_of_table_1():
    assert (condition(1).layout, condition(1).mode, condition(1).speech) == ('suit', 'adjusted', False)
    assert (condition(2).layout, condition(2).mode) == ('suit', 'fixed')
    assert (condition(3).layout, condition(3).mode) == ('arm', 'adjusted')
    assert condition(4).speech and not condition(4).haptic
    with pytest.raises(ValueError, match='condition must be one of'):
        condition(5)
