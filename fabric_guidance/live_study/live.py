"""The paper's two protocols driven through the graph by an Operator, trial by trial.

speed (Section VI): trial_s per trial (the paper: 40 s). A target appears at the session's
    angle among new dummies (headset_display draws a new set for every activation); a key
    press counts when the gaze at the press's stamp is within acceptance_deg (5 deg) of it;
    the target then returns to the front (no active target: the controller vents), and once the
    gaze has stayed within acceptance_deg of the front for dwell_s the next target appears.
    Recorded: targets identified and presented, mean time to identify.
accuracy (Section V): an unseen target angle; guidance; the key press; the horizontal and
    vertical error of the gaze at the press (timeout_s without a press: timed out, the gaze
    at the deadline).

Between trials the suit is vented (enable false) and no target is active; TrialTiming keeps the
monotonic intervals in which no guidance command may leave (study timing and the graph test).
The target angles come from the caller (the plan's seeded stream).
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math
import time
from typing import Callable, Iterator

import numpy as np

from .operator import Operator, PressError

#: A press stamped more than this before its trial's target appeared, or this far in the future, is refused [s].
STALE_PRESS_S = 1.0


@dataclass
class Phase:
    """A time the suit must be vented: from `start_ns` to `end_ns` (monotonic)."""
    start_ns: int
    end_ns: int = 0


@dataclass
class TrialTiming:
    """What a trial's timing was (monotonic seconds), for the bench."""
    trial_s: float = 0.0
    timer_error_s: float = 0.0          # when the trial ended minus when it should have
    press_latency_s: list[float] = field(default_factory=list)   # stamp of a press -> its error recorded
    vented: list[Phase] = field(default_factory=list)


@dataclass
class SpeedParams:
    trial_s: float = 40.0
    acceptance_deg: float = 5.0
    dwell_s: float = 0.3


@dataclass
class AccuracyParams:
    timeout_s: float = 15.0


def wait_front(op: Operator, acceptance_deg: float, dwell_s: float, deadline: float) -> bool:
    """Until the gaze has stayed within acceptance_deg of the front for dwell_s (by the
    samples' stamps), or the deadline (monotonic): True when it did."""
    inside_since = None
    last = None
    while time.monotonic() < deadline:
        err = op.latest_gaze_error(None)
        if err is not None and err.gaze_stamp_ns != last:
            last = err.gaze_stamp_ns
            if err.error_deg > acceptance_deg:
                inside_since = None
            else:
                inside_since = err.gaze_stamp_ns if inside_since is None else inside_since
                if (err.gaze_stamp_ns - inside_since) * 1e-9 >= dwell_s:
                    return True
        time.sleep(0.005)
    return False


def judge(op: Operator, press, target, appeared_ns: int) -> PressError | None:
    """The gaze error at a press, or None for a press that is not this trial's (stale stamp)."""
    if press.stamp_ns < appeared_ns - STALE_PRESS_S * 1e9 or press.stamp_ns > press.received_ns + STALE_PRESS_S * 1e9:
        return None
    return op.settled_error_at(press.stamp_ns, target)


def speed_trial(op: Operator, targets: Iterator[tuple[float, float]], params: SpeedParams,
                timing: TrialTiming, say: Callable[[str], None] = lambda s: None) -> dict:
    """One speed trial through the graph; the measures as TrialRecord's speed fields plus the
    live ones (presses, presses_refused, press_error_deg)."""
    op.drain_presses()
    op.enable(True)
    if timing.vented:
        timing.vented[-1].end_ns = time.monotonic_ns()
    start = time.monotonic()
    end = start + params.trial_s
    finds, errors, refused, presses = [], [], 0, 0
    target = next(targets)
    op.show_target(*target)
    appeared, appeared_ns = time.monotonic(), op.now_ns()
    presented = 1
    while True:
        press = op.next_press(end - time.monotonic())
        if press is None:
            break
        presses += 1
        err = judge(op, press, target, appeared_ns)
        timing.press_latency_s.append((op.now_ns() - press.stamp_ns) * 1e-9)
        if err is None or err.error_deg > params.acceptance_deg:
            refused += 1
            continue
        finds.append(time.monotonic() - appeared)
        errors.append(err.error_deg)
        op.display('found study')
        op.to_front()
        op.display('prompt Look at the front')
        if not wait_front(op, params.acceptance_deg, params.dwell_s, end):
            break
        op.display('prompt')
        op.drain_presses()          # a press while looking back counts for nothing
        target = next(targets)
        op.show_target(*target)
        appeared, appeared_ns = time.monotonic(), op.now_ns()
        presented += 1
    timing.timer_error_s = time.monotonic() - end
    op.to_front()
    op.enable(False)
    timing.vented.append(_phase_now())
    timing.trial_s = time.monotonic() - start
    return dict(identified=len(finds), presented=presented, mean_find_s=float(np.mean(finds)) if finds else None,
                presses=presses, presses_refused=refused,
                press_error_deg=float(np.mean(errors)) if errors else None)


def accuracy_trial(op: Operator, target: tuple[float, float], params: AccuracyParams,
                   timing: TrialTiming, say: Callable[[str], None] = lambda s: None) -> dict:
    """One accuracy trial through the graph; TrialRecord's accuracy fields plus the live ones."""
    op.drain_presses()
    op.enable(True)
    if timing.vented:
        timing.vented[-1].end_ns = time.monotonic_ns()
    start = time.monotonic()
    op.show_target(*target)
    appeared_ns = op.now_ns()
    deadline = start + params.timeout_s
    err, presses, source = None, 0, ''
    while err is None:
        press = op.next_press(deadline - time.monotonic())
        if press is None:
            break
        presses += 1
        err = judge(op, press, target, appeared_ns)
        timing.press_latency_s.append((op.now_ns() - press.stamp_ns) * 1e-9)
        source = press.source
    timed_out = err is None
    if timed_out:
        err = op.latest_gaze_error(target)
    elapsed = time.monotonic() - start
    op.to_front()
    op.enable(False)
    timing.vented.append(_phase_now())
    timing.trial_s = elapsed
    nan = math.nan
    return dict(target_h_deg=target[0], target_v_deg=target[1],
                h_error_deg=err.h_error_deg if err else nan, v_error_deg=err.v_error_deg if err else nan,
                tracked_h_error_deg=err.h_error_deg if err else nan,
                tracked_v_error_deg=err.v_error_deg if err else nan,
                time_s=elapsed, timed_out=timed_out, presses=presses, press_source=source)


def _phase_now() -> Phase:
    return Phase(time.monotonic_ns())
