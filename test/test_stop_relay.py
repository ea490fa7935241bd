"""plc_output's rules for a stop from any connection (nodes/plc_stop.py), without ROS: when it
is kept out long enough to request the vent, and when a latched PLC may be re-armed."""
import numpy as np

from fabric_guidance.nodes.plc_stop import KEPT_OUT_WATCHDOGS, KeptOut, StopRelay

WATCHDOG_S = 0.5
PRESSURE, ZEROS = np.full(3, 120.0), np.zeros(3)


def test_kept_out_only_by_a_streak_of_busy_refusals_for_two_watchdog_times():
    k = KeptOut()
    k.refused(True, 10.0)
    assert not k.overdue(10.0 + KEPT_OUT_WATCHDOGS * WATCHDOG_S - 0.01, WATCHDOG_S)
    k.refused(True, 10.7)                     # the streak keeps its start
    assert k.overdue(10.0 + KEPT_OUT_WATCHDOGS * WATCHDOG_S, WATCHDOG_S)
    k.refused(False, 11.1)                    # another failure (a timeout, 02) ends the streak
    assert not k.overdue(20.0, WATCHDOG_S)
    k.refused(True, 12.0)
    k.up()                                    # the link up: no streak, no holder
    assert not k.overdue(20.0, WATCHDOG_S) and k.holder == ''


def test_a_latched_plc_is_re_armed_only_for_pressure_sent_after_the_controller_vented():
    wall = [100.0]
    relay = StopRelay(lambda: wall[0])
    assert not relay.may_rearm(PRESSURE, 99.0)          # no stop yet: nothing to re-arm for
    relay.stop('the vent latch of PLC plc is set')
    assert relay.due()
    relay.sending()
    assert not relay.due()                              # one call at a time
    wall[0] = 101.0
    relay.answered(True)
    assert not relay.wanted and relay.told_at == 101.0
    assert not relay.may_rearm(PRESSURE, 100.5)         # sent before the answer: maybe before the vent
    assert not relay.may_rearm(ZEROS, 102.0)            # the vented controller's zeros
    assert not relay.may_rearm(PRESSURE, None)          # no command yet
    assert relay.may_rearm(PRESSURE, 102.0)             # pressure after the operator's enable


def test_a_stop_newer_than_the_call_out_needs_a_call_of_its_own():
    wall = [100.0]
    relay = StopRelay(lambda: wall[0])
    relay.stop('first')
    relay.sending()
    relay.stop('second, while the first call is out')
    wall[0] = 101.0
    relay.answered(True)
    assert relay.wanted and relay.told_at is None and relay.due()
    relay.sending()
    relay.answered(False)                               # refused or failed: asked again
    assert relay.wanted and relay.due() and relay.failures == 1
    assert not relay.may_rearm(PRESSURE, 200.0)
