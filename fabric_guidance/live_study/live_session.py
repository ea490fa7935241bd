"""`fabric-guidance study --participant ID`: the paper's study with a person, on a graph that is
already running (`ros2 launch fabric_guidance guidance.launch.py ... study:=speed`), found on
ROS_DOMAIN_ID and in `--namespace`.

For the participant: registered in the study folder (their index decides their condition order
and targets, study/plan.py), calibrated from the running graph when pressure_controller has no
calibration of theirs (pressure_controller `wearer` set to the id: a returning participant's
`<calibration_dir>/<id>.yaml` is loaded by it; otherwise `start_calibration` with progress on the
terminal, and a refused calibration says why and is repeated or ends the session), then their
blocks through study/session.py's Session (driver.SessionDriver), one bag per block
(block_bag.BlockBags), every finished trial written at once (study/store.py). The suit is vented
(the session's trial gate closed) between trials, on any error, on Ctrl-C and at the end.

The session never arms the controller: the operator does, with the key e (it calls `enable`) or
`ros2 service call .../enable`, before the calibration and whenever the arm dropped (an outside
vent, a controller restart, a lost controller: the session stops the trial, says so in one line
and waits; e arms and resumes). docs/study.md, "When the session stops for the arm".

The operator's keys (keyboard.py): space or Enter presses confirm when the keyboard is a press
source; e arm (enable) and resume, p pause, c resume, r repeat, s skip, q stop (vents at once).
The terminal shows one status line (participant, condition, block, trial, phase, time left,
identified, last result, why it holds).
"""
from __future__ import annotations

import hashlib
import os
from pathlib import Path
import sys
import time
from typing import Callable

from ..core.calibration_state import DONE, FAILED, REFUSED
from ..graph.process_graph import wait_until
from ..study.plan import participant_blocks
from ..study.events import RecordedSession
from ..study.session import Session
from ..study.store import Study
from .block_bag import BlockBags
from .driver import SessionDriver
from .keyboard import KeyboardSource
from .operator import Operator, OperatorError
from .session_graph import _commit
from .simulated import design_of

#: The graph's controller must show up within this [s] (discovery on a loaded machine).
GRAPH_TIMEOUT_S = 30.0
#: A calibration (4 directions x the node's steps x dwell, rests between) ends within this [s].
CALIBRATION_TIMEOUT_S = 600.0
#: Calibration attempts when nobody is at the keyboard to decide (a refused one is repeated).
UNATTENDED_ATTEMPTS = 3
#: How long the session waits for the operator to arm the controller before it gives up [s].
ARM_WAIT_S = 900.0


class LiveStudyError(RuntimeError):
    """The live session cannot go on (the message says why; the suit is vented)."""


def status_line(st: dict) -> str:
    """The operator's one line of the session's status."""
    parts = [f"sub-{st['participant']}" if st.get('participant') else 'no participant',
             f"condition {st['condition']}" if st.get('condition') else '', f"block {st['block']}",
             f"trial {st['trial']}" if st.get('trial') else '', st['phase']]
    if st.get('time_left_s') is not None:
        parts.append(f"{st['time_left_s']:4.1f} s left")
    if st.get('identified') is not None:
        parts.append(f"identified {st['identified']}")
    if st.get('last_result'):
        parts.append(f"last: {st['last_result']}")
    if st.get('hold'):
        parts.append(f"HELD: {st['hold']}: e arms and resumes")
    return ' | '.join(p for p in parts if p)


def operator_keys(op, driver, say: Callable[[str], None]) -> Callable[[str], None]:
    """The keyboard's command callback: the command to the session's loop (`driver` None: no
    session loop yet, the calibration's wait for the arm). `stop` closes the trial gate first,
    from the key's own thread, so the suit does not wait for a call the loop may be in. `arm` is
    the operator's act: the trial gate closed first (a restarted controller's is open), then
    `enable`, then the session resumes."""
    def command(name: str) -> None:
        if name == 'stop':
            try:
                op.trial_gate(False)
            except OperatorError as exc:      # the loop's stop vents again
                say(f'  stop: {exc}')
        if name == 'arm':
            try:
                op.trial_gate(False)
                op.enable(True)
                say('  operator: armed (enable)')
            except OperatorError as exc:
                say(f'  arm: {exc}')
                return
        if driver is not None:
            driver.command(name)
    return command


def wait_for_arm(op: Operator, say: Callable[[str], None], timeout_s: float = ARM_WAIT_S) -> None:
    """Until the operator has armed the controller (LiveStudyError after timeout_s)."""
    if op.arm_dropped(None) == '' and op.armed:
        return
    say("  the operator's arm is off: check the suit, then press e to arm (it calls enable)")
    try:
        wait_until(lambda: op.armed is True, timeout_s, 0.05, what="the operator's arm")
    except AssertionError:
        raise LiveStudyError(f'the operator did not arm the controller within {timeout_s:.0f} s; the session '
                             'did not go on') from None


def calibration_path(op: Operator, participant: str) -> Path | None:
    """Where pressure_controller keeps the participant's calibration (None: it does not say)."""
    cal_dir, cal_file = op.get_parameters('pressure_controller', 'calibration_dir', 'calibration_file')
    base = cal_dir or (str(Path(cal_file).parent) if cal_file else '')
    return Path(base) / f'{participant}.yaml' if base else None


def calibrate(op: Operator, participant: str, say: Callable[[str], None], again: Callable[[str], bool],
              timeout_s: float = CALIBRATION_TIMEOUT_S) -> None:
    """Calibrate `participant` (pressure_controller's wearer already) on the running graph, until
    a calibration is written or `again(reason)` says to give up (LiveStudyError). Each attempt
    waits for the operator's arm, then opens the trial gate for it and closes it after."""
    from std_srvs.srv import Trigger
    from .. import interface
    while True:
        op.calibration_state = None            # only what this attempt publishes counts
        wait_for_arm(op, say)
        reason = op.trial_gate(True) or None
        if reason is None:
            response = op.call(Trigger, interface.START_CALIBRATION, Trigger.Request())
            reason = None if response.success else response.message
        shown = None
        deadline = time.monotonic() + timeout_s
        while reason is None:
            state = op.calibration_state
            if state is not None and state.wearer == participant:
                line = f'  calibration {state.phase} {state.direction} {state.step}/{state.steps} ' \
                       f'{state.pressure_kpa:.0f} kPa ({state.progress:.0%})'
                if state.phase in (DONE, FAILED, REFUSED):
                    if state.phase != DONE:
                        reason = state.error or state.phase
                    break
                if (state.phase, state.direction, state.step) != shown:    # a line per step, not per tick
                    say(line)
                    shown = (state.phase, state.direction, state.step)
            if time.monotonic() > deadline:
                reason = f'no end of the calibration within {timeout_s:.0f} s'
                break
            time.sleep(0.05)
        op.trial_gate(False)
        if reason is None:
            wait_until(lambda: op.controller_calibration == participant, 10.0,
                       what=f"pressure_controller guiding with {participant}'s calibration")
            say(f'  calibration of {participant} written and in use ({op.calibration_state.file})')
            return
        say(f'  calibration of {participant} refused: {reason}; nothing was written and {participant} has '
            'no calibration yet')
        if not again(reason):
            raise LiveStudyError(f'calibration of {participant} refused ({reason}); the session did not start')


def ask_operator(stream=None, out=None) -> Callable[[str], bool]:
    """again(reason) for a refused calibration: at a terminal the operator answers r (repeat) or q;
    unattended (no terminal) it repeats up to UNATTENDED_ATTEMPTS times."""
    stream = stream or sys.stdin
    out = out or sys.stdout
    tries = {'n': 0}

    def again(reason: str) -> bool:
        tries['n'] += 1
        if not (hasattr(stream, 'isatty') and stream.isatty()):
            return tries['n'] < UNATTENDED_ATTEMPTS
        out.write('  r repeat the calibration, q end: ')
        out.flush()
        while True:
            key = stream.readline().strip().lower()[:1]
            if key in ('r', 'q'):
                return key == 'r'
    return again


def run_live_session(scene, participant: str, session_no: int, out: Path, say: Callable[[str], None],
                     order: str = 'random', namespace: str = '', keyboard: bool = True, stream=None,
                     again: Callable[[str], bool] | None = None,
                     before_trial: Callable[[Operator, int, int], None] | None = None,
                     press_sources: tuple[str, ...] = ()) -> int:
    """The participant's session on the running graph (see the module docstring); 0 when every
    block is done, 1 when the session was stopped. before_trial(op, condition, repetition) runs
    before each trial (a simulated person's streams; nothing for a person). press_sources: the
    confirm sources judged (study.plan.PRESS_SOURCES; (): all)."""
    design = design_of(scene, order, press_sources)
    study = Study.open(out, name=f'{scene.name} live')
    p = study.add_participant(participant)
    store = study.session(participant, session_no, design)
    if store.lost is not None:
        say(f'sub-{participant}: {store.lost.line()}')
    blocks = store.remaining(participant_blocks(design, participant, p.index))
    if not blocks:
        say(f'sub-{participant} session {session_no}: every block is done')
        return 0
    say(f'sub-{participant} (index {p.index}): {design.protocol}, conditions in the order '
        f'{", ".join(str(b.condition) for b in blocks)}, {design.trials} trials each; presses judged from '
        f'{", ".join(design.press_sources) or "every source"}')
    op = Operator(namespace=namespace)
    try:
        try:
            wait_until(lambda: op.controller_condition is not None, GRAPH_TIMEOUT_S,
                       what='pressure_controller')
        except AssertionError:
            raise LiveStudyError(f"no pressure_controller answers in namespace '/{op.namespace}' on ROS_DOMAIN_ID "
                                 f"{os.environ.get('ROS_DOMAIN_ID', '0')} within {GRAPH_TIMEOUT_S:.0f} s: "
                                 'launch the graph first (docs/study.md)') from None
        op.trial_gate(False)     # the session's gate: closed until a calibration or a trial opens it
        keys = {'driver': None}
        if keyboard:
            KeyboardSource(lambda: op.press_key('keyboard'),
                           lambda name: operator_keys(op, keys['driver'], say)(name), stream).start()
        op.set_parameters('pressure_controller', wearer=participant)
        wait_until(lambda: op.controller_wearer == participant, 10.0, what=f'pressure_controller wearer {participant}')
        if op.controller_calibration == participant:
            say(f'  {participant}: their calibration is loaded')
        else:
            say(f'  {participant}: no calibration yet; calibrating now (the participant looks straight ahead)')
            calibrate(op, participant, say, again or ask_operator(stream))
        cal = calibration_path(op, participant)
        readable = cal is not None and cal.is_file()
        context = {'gaze_source': 'headset', 'clock_state': op.clock_state(), 'git_commit': _commit(),
                   'calibration_file': cal.name if cal is not None else f'{participant}.yaml',
                   'calibration_sha256': hashlib.sha256(cal.read_bytes()).hexdigest() if readable else '-',
                   'scene': scene.name}
        bags = BlockBags(op, store, namespace or '/', say=say)
        session = RecordedSession(Session(design, blocks, context), bags)     # its events per run

        def set_condition(cond: int) -> None:
            op.set_condition(cond)
            bags.begin(session.block)

        def prepare_trial(cond: int, repetition: int) -> None:
            # Each trial carries the headset clock's state as it is now (gaze_bridge's diagnostics).
            session.set_context(clock_state=op.clock_state())
            if before_trial is not None:
                before_trial(op, cond, repetition)
        wait_for_arm(op, say)
        driver = SessionDriver(op, session, bags, say, set_condition, prepare_trial)
        keys['driver'] = driver
        tty = hasattr(sys.stdout, 'isatty') and sys.stdout.isatty()
        if tty:
            driver.on_status = lambda st: (sys.stdout.write('\r' + status_line(st)[:150].ljust(150)),
                                           sys.stdout.flush())
        if keyboard:
            say('  keys: space/Enter confirm' + ('' if design.judges('keyboard') else
                                                 ' (not judged: the keyboard is not a press source)') +
                ', e arm (enable) and resume, p pause, c resume, r repeat, s skip, q stop (vents)')
        try:
            driver.run()
        except KeyboardInterrupt:
            say('interrupted: vented; the finished trials are in the study folder')
            return 1
        finally:
            bags.close()
            op.trial_gate(False)
        if session.phase == 'stopped':
            say(f'sub-{participant}: stopped by the operator, vented; run the same command again to resume')
            return 1
        say(f'sub-{participant}: every block done; the suit is vented. analysis: fabric-guidance analyze {out}')
        return 0
    except OperatorError as exc:
        raise LiveStudyError(f'{exc} (the suit was told to vent)') from None
    finally:
        if op.controller_condition is not None:     # a controller was there: leave it vented
            try:
                op.trial_gate(False)
            except Exception:   # noqa: BLE001 - closing anyway: the error that brought us here is reported
                pass
        op.close()


__all__ = ['LiveStudyError', 'ask_operator', 'calibrate', 'operator_keys', 'run_live_session', 'status_line',
           'wait_for_arm']
