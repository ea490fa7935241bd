"""study.session.Session on the graph: the graph's events into the state machine, its actions
onto the graph through an Operator, its rows into the study folder (study.store) as they come.

The Session runs on the steady clock; the graph stamps gaze and presses on the PC clock (ROS
time). Stamps are mapped with the offset between the two clocks read at start (both are read
on this machine; the headset's clock was mapped to the PC clock by gaze_bridge already).

Gaze is fed as it arrives (each sample once, in capture order), presses as they arrive, and
tick() whenever the Session's next deadline has come; the loop sleeps at most 2 ms in between.

The session's vents and trials go through the controller's trial gate; it never arms the
controller. The loop watches the operator's arm (Operator.arm_dropped: an outside vent, a
restart, a lost controller; an opening of the gate refused for it too): the running trial ends,
recorded 'vented', one line tells the operator, and the session holds until the operator's key
`e` has armed the controller (live_session.operator_keys) and the `arm` command reaches it.
"""
from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass, field
from itertools import islice
import queue
import time
from typing import Callable

from ..core.geometry import azimuth_deg, elevation_deg
from .operator import STUDY_TARGET, Operator, OperatorError

#: The loop's sleep between polls [s].
POLL_S = 0.002
#: The session's commands an operator may give while it runs (Session's methods of these names).
OPERATOR_COMMANDS = ('pause', 'resume', 'repeat', 'skip', 'stop', 'arm')
#: How often on_status gets the session's status [s].
STATUS_S = 0.25


@dataclass
class DriverTiming:
    press_latency_s: list[float] = field(default_factory=list)   # press stamp -> its row's error resolved
    press_sources: list[str] = field(default_factory=list)       # each of those presses' source, in step
    timer_error_s: list[float] = field(default_factory=list)     # speed trial end: acted on - deadline
    vented_from_ns: int | None = None                             # monotonic ns of the last vent
    vented: list[tuple[int, int]] = field(default_factory=list)   # (vent, next gate opening) monotonic ns
    # The phases of a speed target on the graph [s, steady clock], one tuple per event:
    # ('target' | 'front' | 'vent', decided, carried out) and ('press', stamp, resolved, accepted).
    events: list[tuple] = field(default_factory=list)
    # Each gaze sample's age when the session got it (receipt - capture stamp) [s], the last ones.
    gaze_age_s: deque = field(default_factory=lambda: deque(maxlen=100_000))

    def press_latency_by_source(self) -> dict[str, list[float]]:
        """press_latency_s split by the presses' sources ('keyboard', 'headset', ...) [s]."""
        out: dict[str, list[float]] = {}
        for source, latency in zip(self.press_sources, self.press_latency_s):
            out.setdefault(source, []).append(latency)
        return out


def target_phases(events) -> dict[str, list[float]]:
    """The phases of each found speed target from DriverTiming.events [s]: target_call (the
    target's parameter call), find (target decided to the accepted press's stamp), press_wait
    (the stamp to its judgement: the gaze sample after the press on its way), front_call (the
    front's parameter call), front_return (the front shown to the next target decided: the
    wearer's way back and the front dwell)."""
    out: dict[str, list[float]] = {k: [] for k in ('target_call', 'find', 'press_wait', 'front_call', 'front_return')}
    shown = front_done = None
    for e in events:
        if e[0] == 'target':
            out['target_call'].append(e[2] - e[1])
            if front_done is not None:
                out['front_return'].append(e[1] - front_done)
            shown, front_done = e[1], None
        elif e[0] == 'press' and e[3] and shown is not None:
            out['find'].append(e[1] - shown)
            out['press_wait'].append(e[2] - e[1])
            shown = None
        elif e[0] == 'front':
            out['front_call'].append(e[2] - e[1])
            front_done = e[2]
        elif e[0] == 'vent':        # a trial's end: its last target is not a phase of the next
            shown = front_done = None
    return out


class SessionDriver:
    """Run `session` on the graph through `op`, recording into `store`.

    hooks: before_trial(condition, repetition) for the next trial (the simulated graph sets
    wearer_sim's streams there), called as the rest before it begins, so that the wearer side
    starts afresh facing front while vented (the headless trial's warm-up) and the trial's start
    does not wait for it (at the latest before the trial's gate opens); set_condition(condition) for
    a switch (default: the Operator's set_condition)."""

    def __init__(self, op: Operator, session, store, say: Callable[[str], None] = lambda s: None,
                 set_condition: Callable[[int], None] | None = None,
                 before_trial: Callable[[int, int], None] | None = None):
        self.op, self.session, self.store, self.say = op, session, store, say
        self.set_condition = set_condition or (lambda c: op.set_condition(c))
        self.before_trial = before_trial
        self.timing = DriverTiming()
        self._offset_s = 0.0
        self._last_gaze_ns = 0
        self._gaze_seen = 0                 # op.gaze_total already fed (or passed over)
        self._prepared: tuple[str, int] | None = None    # (block key, repetition) before_trial was called for
        self.rows: list[dict] = []
        # The operator's commands (pause, resume, repeat, skip, stop) from any thread; the loop
        # applies them, so the Session is only ever touched by the loop.
        self._commands: queue.SimpleQueue[str] = queue.SimpleQueue()
        self.on_status: Callable[[dict], None] | None = None      # called about every STATUS_S
        self._status_due = 0.0
        self._drawn = True                  # headset_display's draw_targets
        self._ignored: Counter[str] = Counter()    # sources of the running trial's ignored presses
        # target_selector's calls sent without waiting: (index of their event, PendingCall), in order
        self._calls: deque = deque()
        self._started: str | None = None    # the controller process the operator armed (its `started`)
        self._disarmed: str | None = None   # an opening of the trial gate refused: why

    def command(self, name: str) -> None:
        """An operator's command for the session: 'pause', 'resume', 'repeat', 'skip', 'stop' or
        'arm' (sent once the operator's key has armed the controller)."""
        if name not in OPERATOR_COMMANDS:
            raise ValueError(f'unknown session command {name!r}; one of {", ".join(OPERATOR_COMMANDS)}')
        self._commands.put(name)

    def _apply_commands(self, now: float) -> None:
        while True:
            try:
                name = self._commands.get_nowait()
            except queue.Empty:
                return
            if name == 'arm':
                why = self.op.arm_dropped(None)
                if why:
                    self.say(f'  operator: arm refused: {why}')
                    continue
                self._started = self.op.controller_started
            step = getattr(self.session, name)(now)
            self.say(f'  operator: {name}' + (f' refused: {step.refused}' if step.refused else ''))
            self.handle(step)

    def steady(self, stamp_ns: int) -> float:
        return stamp_ns * 1e-9 - self._offset_s

    def run(self) -> list[dict]:
        op = self.op
        self._offset_s = op.now_ns() * 1e-9 - time.monotonic()
        self._last_gaze_ns = op.now_ns()      # gaze before the start is not the session's
        with op.lock:
            self._gaze_seen = op.gaze_total
        op.drain_presses()
        self._started = op.controller_started
        self.handle(self.session.start(time.monotonic()))
        while self.session.phase not in ('done', 'stopped'):
            self._check_calls()
            self._apply_commands(time.monotonic())
            self.watch_arm()
            if self.on_status is not None and time.monotonic() >= self._status_due:
                self._status_due = time.monotonic() + STATUS_S
                self.on_status(self.session.status(time.monotonic()))
            self.feed_gaze()
            for press in op.drain_presses():
                self.handle(self.session.press(self.steady(press.stamp_ns), self.steady(press.received_ns),
                                               press.source))
            deadline = self.session.next_deadline()
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                self.handle(self.session.tick(now))
            else:
                time.sleep(POLL_S)
        self._check_calls(wait=True)
        return self.rows

    def watch_arm(self) -> None:
        """The operator's arm dropped (or a gate opening was refused for it): the session holds."""
        why, self._disarmed = self._disarmed or self.op.arm_dropped(self._started), None
        if not why or self.session.phase in ('held', 'idle', 'stopped', 'done'):
            return
        self.say(f'  STOPPED: {why}; the suit is vented and the trial will be run again. Check the suit, then '
                 'press e to arm (enable) and resume, or q to stop')
        self.handle(self.session.disarmed(time.monotonic(), why))

    def gate(self, on: bool) -> None:
        """The controller's trial gate. Refused (the operator's arm is off), or not answered (the
        controller lost: a restart's first seconds, a dead process): the session holds, once this
        step's actions are done (watch_arm)."""
        try:
            refused = self.op.trial_gate(on)
        except OperatorError as exc:
            refused = f'pressure_controller did not answer ({exc})'
        if refused:
            self._disarmed = refused

    def _check_calls(self, wait: bool = False) -> None:
        """The target's and the front's calls on target_selector that were sent without waiting
        (the loop goes on judging gaze and presses meanwhile): their answers, in order; a refusal
        or a silence past its timeout raises OperatorError here, as a waited call would."""
        while self._calls:
            index, pending = self._calls[0]
            if wait:
                pending.wait()
            elif not pending.done():
                return
            self._calls.popleft()
            kind, decided, _sent = self.timing.events[index]
            self.timing.events[index] = (kind, decided, pending.done_at)

    def feed_gaze(self) -> None:
        """The samples appended to op.gaze since the last call, each once, in order: taken from
        its right end (op.gaze_total counts every append), so a poll costs the new samples, not
        the history's length; one captured before the last fed (or the start) is left out."""
        op = self.op
        with op.lock:
            new = min(op.gaze_total - self._gaze_seen, len(op.gaze))
            self._gaze_seen = op.gaze_total
            fresh = list(islice(reversed(op.gaze), new))
        fresh.reverse()
        now = time.monotonic()
        for stamp_ns, _origin, direction in fresh:
            if stamp_ns <= self._last_gaze_ns:
                continue
            self._last_gaze_ns = stamp_ns
            self.timing.gaze_age_s.append(now - self.steady(stamp_ns))
            self.handle(self.session.gaze(self.steady(stamp_ns), azimuth_deg(direction) or 0.0,
                                          elevation_deg(direction)))

    def handle(self, step) -> None:
        now = time.monotonic()
        if step.ignored is not None:
            self._ignored[step.ignored] += 1
        for p in step.presses:
            self.timing.press_latency_s.append(now - p['stamp'])
            self.timing.press_sources.append(p['source'])
            self.timing.events.append(('press', p['stamp'], now, p['accepted']))
        # A new block's condition (and its bag, whose recorder may take seconds to start) comes
        # after the finished trial's row is on disk and said; the vent before both.
        switch = next((i for i, a in enumerate(step.actions) if a.kind == 'set_condition'), len(step.actions))
        for action in step.actions[:switch]:
            self._carry_out(action)
        self._record(step, now)
        for action in step.actions[switch:]:
            self._carry_out(action)
        if switch < len(step.actions):
            # The rest starts once the graph is in the new condition: its start shortens no rest,
            # and gaze queued meanwhile cannot start the trial on a stale capture time.
            self.session.restart_rest(time.monotonic())
        if step.refused:
            self.say(f'  refused: {step.refused}')
        if self.session.phase == 'rest':
            self.prepare_trial()

    def _carry_out(self, action) -> None:
        pending = self.act(action)
        if action.kind in ('show_target', 'show_front', 'vent'):
            self.timing.events.append((action.kind.replace('show_', ''), action.t, time.monotonic()))
            if pending is not None:        # carried out when its answer comes (_check_calls)
                self._calls.append((len(self.timing.events) - 1, pending))

    def _record(self, step, now: float) -> None:
        """The step's finished trials on disk and on the terminal."""
        for row in step.rows:
            # A speed trial ends at its deadline, whether the tick or a gaze sample captured after
            # it told the session: its timer error is when the driver acted on the end (the vent).
            if row.get('protocol') == 'speed' and row.get('status') == 'ok' and row.get('trial_end_s') is not None:
                self.timing.timer_error_s.append(now - row['trial_end_s'])
        if not (step.rows or step.amended or step.blocks):
            return
        self.store.record(step)
        self.rows += step.rows
        for row in step.rows:
            self.say(f"  {row['block']} trial {row['repetition'] + 1}: {row['status']}" + (
                f", identified {row['identified']} of {row['presented']}" if row.get('identified') is not None
                else f", error h {row['h_error_deg']:.1f} v {row['v_error_deg']:.1f} deg"
                if row.get('h_error_deg') is not None else ''))
            if self._ignored:        # once per trial, not per press
                self.say(f"  ignored {sum(self._ignored.values())} press(es) from "
                         f"{', '.join(f'{k} ({n})' for k, n in sorted(self._ignored.items()))}: not a press "
                         f"source of this session ({', '.join(self.session.design.press_sources)})")
                self._ignored.clear()

    def prepare_trial(self) -> None:
        """before_trial for the session's next trial, once per trial run."""
        block, trial = self.session.block, self.session.trial
        if self.before_trial is None or block is None or trial is None:
            return
        key = (block.key, trial.repetition)
        if key != self._prepared:
            self.before_trial(block.condition, trial.repetition)
            self._prepared = key

    def act(self, action):
        """Carry out one of the Session's actions; a PendingCall for a call sent without waiting."""
        op, kind = self.op, action.kind
        if kind == 'set_condition':
            self.set_condition(action.condition)
        elif kind == 'open_gate':
            self.prepare_trial()
            self._prepared = None       # a repeat of this trial starts afresh too
            if self.timing.vented_from_ns is not None:
                self.timing.vented.append((self.timing.vented_from_ns, time.monotonic_ns()))
                self.timing.vented_from_ns = None
            self.gate(True)
        elif kind == 'vent':
            self.gate(False)
            self.timing.vented_from_ns = time.monotonic_ns()
        elif kind == 'show_target':
            visible = action.visible is not False
            if visible != self._drawn:            # set first: an unseen target is never drawn
                op.set_parameters('headset_display', draw_targets=visible)
                self._drawn = visible
            return op.show_target(*action.target, wait=False)
        elif kind == 'found':        # before show_front: the headset flashes the target it shows
            op.display(f'found {STUDY_TARGET}')
        elif kind in ('show_front', 'hide'):
            return op.to_front(wait=False)
        elif kind == 'prompt':
            op.display(f'prompt {action.text or ""}'.rstrip())
        elif kind == 'done':
            op.display(f'done {action.text or ""}'.rstrip())
