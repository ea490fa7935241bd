"""fabric-guidance chaos --study: the chaos run with the study session running.

The graph is the simulated study's (live_study.simulated: mock_plc with its register log on,
plc_output, gaze_bridge, target_selector, pressure_controller, headset_display, wearer_sim as
participant 01 of the scene paper-speed, its haptic conditions 1-3 only, each a block). The
controller and plc_output are supervised: a process that dies is restarted, the controller
disarmed (start_enabled false), as the lab launch runs them. The session's driver runs on a
thread; the operator of this run arms once at the start and afterwards only through the
session's key `e` (live_session.operator_keys), as a person at its terminal does.

Faults, drawn from the seed, each injected while a trial has the suit under pressure:
- an outside vent (a safety officer's `ros2 service call .../vent` from a node of its own);
- a controller restart mid-block (SIGKILL; it respawns disarmed);
- a foreign Modbus writer after plc_output dies (bench/second_writer.py).

Held to, from the mock PLC's register log (plc/register_log.py): nothing above P_MAX; the vent
within its deadline (the same as `fabric-guidance chaos`'s) and held until the operator's key;
nothing applied before that key. From the session: after an outside vent or a restart it holds
(phase 'held', its one STOPPED line) until the operator's key and never resumes by itself; the
interrupted trial is recorded 'vented' and run again; the block ends with every planned trial
run; at the end no process of the graph is left. Output: progress per fault, then a table per
fault kind, chaos.md and chaos.json in --out.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
import json
from pathlib import Path
import random
import signal
import threading
import time

import yaml

from .. import interface
from ..atomic import write_text
from ..plc.register_log import Fault, RegisterLog, fault_vent, gate_breaches, late_vents, over_p_max, vent_time
from ..graph.process_graph import CONFIG, PlcInvariantError, wait_until
from . import second_writer
from .deadlines import CONTROLLER_VENT_S, OPERATOR_VENT_S, WATCHDOG_VENT_S
from .graphs import state

KINDS = ('outside_vent', 'controller_kill', 'foreign_writer')
TITLE = {'outside_vent': "outside vent mid-trial (another node's vent call)",
         'controller_kill': 'SIGKILL of pressure_controller mid-trial (respawned disarmed)',
         'foreign_writer': 'a foreign Modbus writer after plc_output dies'}
DEADLINE_S = {'outside_vent': OPERATOR_VENT_S, 'controller_kill': CONTROLLER_VENT_S,
              'foreign_writer': WATCHDOG_VENT_S}
#: The scene's haptic conditions (4, speech, puts no pressure on the suit), a block each.
CONDITIONS = [1, 2, 3]
#: A speed trial's time limit and the rest between trials [s] (the paper's 40 s trial is longer
#: than any fault needs).
TRIAL_S, REST_S = 10.0, 3.0
#: After an outside vent or a restart: the session holds within this [s] (the driver reads the
#: arm from the controller's status, 4 Hz, and a respawned controller must first be seen).
SESSION_HOLD_S = 15.0
#: How long the operator takes to press e [s], drawn per fault: the stop is seen to hold.
OPERATOR_S = (1.5, 3.0)
#: Into a trial's pressure before the fault [s], drawn per fault.
INTO_TRIAL_S = (0.0, 0.4)
#: The session's row of the trial a fault cut, once it holds [s]: the driver writes it after its
#: own vent call, which waits for a controller that may be restarting (Operator.call_begin: up to
#: 15 s for the service, then 5 s for the answer).
ROW_S = 30.0
#: The operator presses e again after this while the session still holds [s].
PRESS_AGAIN_S = 3.0
#: Graph start-up, a trial under pressure again, the session's end [s] (a loaded machine).
STARTUP_S, PRESSURE_S, FINISH_S = 90.0, 60.0, 180.0


@dataclass(frozen=True)
class StudyFault:
    kind: str
    into_trial_s: float
    operator_s: float


def schedule(seed: int, faults: int) -> list[StudyFault]:
    """Rounds of every kind once, each round shuffled, timings drawn per fault: the same seed,
    the same faults."""
    rng = random.Random(f'study-{seed}')
    out: list[StudyFault] = []
    while len(out) < faults:
        kinds = list(KINDS)
        rng.shuffle(kinds)
        out += [StudyFault(k, round(rng.uniform(*INTO_TRIAL_S), 2), round(rng.uniform(*OPERATOR_S), 2))
                for k in kinds]
    return out[:faults]


@dataclass
class StudyOutcome:
    index: int
    planned: StudyFault
    t: float
    t_enable: float | None = None
    vent_s: float | None = None
    held_s: float | None = None       # fault -> the session's phase 'held'
    recovery_s: float | None = None   # the operator's key (or the fault's end) -> pressure again
    writer: dict | None = None
    note: str = ''                                        # what happened, for the reader
    problems: list[str] = field(default_factory=list)     # broken invariants of the session

    def fault(self) -> Fault:
        if self.writer is not None:       # judged by second_writer.breaches, not by a deadline or gate here
            return Fault(TITLE[self.planned.kind], self.t, None, self.t)
        return Fault(TITLE[self.planned.kind], self.t, DEADLINE_S[self.planned.kind], self.t_enable, self.t_enable)


def study_scene(work: Path, trials: int):
    from ..sim.scene import load_scene, scene_path
    data = yaml.safe_load(scene_path('paper-speed').read_text())
    data.update(conditions=CONDITIONS, repetitions=trials)
    data['protocol']['trial_s'] = TRIAL_S
    path = work / 'scene.yaml'
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return load_scene(path)


class StudyChaosLab:
    """The simulated study's graph with its register log, the session on a thread, the operator."""

    def __init__(self, work: Path, trials: int, say):
        from ..live_study.driver import SessionDriver
        from ..live_study.live_session import operator_keys
        from ..live_study.simulated import SimulatedParticipant, design_of
        from ..plc import RegisterMap
        from ..study.plan import participant_blocks
        from ..study.session import Session
        from ..study.store import Study
        self.work, self.say = work, say
        self.lines: list[str] = []
        scene = study_scene(work, trials)
        design = dataclasses.replace(design_of(scene), rest_s=REST_S)
        blocks = participant_blocks(design, '01', 0)
        study = Study.open(work / 'study')
        study.add_participant('01')
        store = study.session('01', 1, design)
        self.log_path = work / 'register_log.jsonl'
        self.register_log = RegisterLog(self.log_path)
        self.p_max_counts = RegisterMap.load(CONFIG / 'hardware' / 'plc_register_map.yaml').p_max_counts
        self.part = SimulatedParticipant(scene, 0, blocks[0].condition, work / 'graph', self._line, design)
        self.part.lab.overrides['mock_plc']['register_log_file'] = str(self.log_path)
        self.planned_trials = len(blocks) * design.trials
        self.session = Session(design, blocks, {'gaze_source': 'wearer_sim'})
        self._store = store
        self._driver_cls, self._keys = SessionDriver, operator_keys
        self.driver = self.officer = None
        self.errors: list[BaseException] = []
        self._thread = self._operator = None
        self._operator_off = threading.Event()
        self._presses: list[float] = []

    def _line(self, text: str) -> None:
        self.lines.append(text)

    # ---- what second_writer.inject uses of a lab
    @property
    def graph(self):
        return self.part.graph

    @property
    def plc_port(self) -> int:
        return self.part.lab.plc_port

    def mark_log(self, node: str) -> None:
        pass    # second_writer's own offset into plc_output's log is all it reads

    def enable(self) -> float:
        """second_writer's operator, called once plc_output has vented the controller: from then
        until the fault is over the operator presses e whenever the session holds, after looking
        at the suit for OPERATOR_S[0] (an enable while the foreign writer still holds the PLC
        leaves the PLC's vent latch set: once plc_output has the PLC back it vents the controller
        again, and the session holds again). The time of the first press."""
        self.operator_stays()
        wait_until(lambda: self.check() or self._presses, SESSION_HOLD_S + PRESSURE_S,
                   what="the operator's key e after plc_output vented the controller")
        return self._presses[0]

    def operator_stays(self) -> None:
        """From now until operator_leaves(), the operator presses e whenever the session holds."""
        if self._operator is None:
            self._operator = threading.Thread(target=self._operator_loop, name='operator', daemon=True)
            self._operator.start()

    def _operator_loop(self) -> None:
        held_since = None
        while not self._operator_off.is_set():
            now = time.monotonic()
            if self.session.phase != 'held':
                held_since = None
            elif held_since is None:
                held_since = now
            elif now - held_since >= OPERATOR_S[0]:
                try:
                    self._presses.append(self.operator_arms('the foreign writer'))
                except AssertionError as exc:
                    self.errors.append(exc)
                    return
                held_since = None
            time.sleep(0.05)

    def operator_leaves(self) -> int:
        """The operator loop ended; the number of times it pressed e."""
        self._operator_off.set()
        if self._operator is not None:
            self._operator.join(PRESSURE_S + 5.0)
        presses, self._presses, self._operator = len(self._presses), [], None
        self._operator_off.clear()
        return presses

    def operator_arms(self, what: str) -> float:
        """The operator's key e at the session's terminal (enable, then the session resumes),
        pressed again every PRESS_AGAIN_S while the session holds (a respawned controller's
        enable service not yet discovered: the key's line says so); the first press's time."""
        press = self._keys(self.part.op, self.driver, self._line)
        t = time.monotonic()
        press('arm')     # its calls may wait for a restarting controller: the deadline from here
        last = pressed = time.monotonic()
        while self.session.phase == 'held':
            self.check()
            now = time.monotonic()
            if now > pressed + PRESSURE_S:
                raise AssertionError(f'{what}: the session did not resume within {PRESSURE_S:g} s of the key e')
            if now > last + PRESS_AGAIN_S:
                last = now
                press('arm')
            time.sleep(0.05)
        return t

    # ---- up and down
    def start(self) -> None:
        from std_srvs.srv import Trigger
        from ..graph.process_graph import Probe
        part = self.part
        part.start()
        part.graph.supervise('pressure_controller', 'plc_output', delay_s=0.5, max_delay_s=4.0)

        def set_condition(cond: int) -> None:
            if cond != part.condition:
                part.switch(cond)
        self.driver = self._driver_cls(part.op, self.session, self._store, self._line, set_condition,
                                       lambda c, r: part.op.set_parameters('wearer_sim', condition=c, repetition=r))
        self._thread = threading.Thread(target=self._run, name='study-session', daemon=True)
        self._thread.start()
        # A safety officer's node of its own, its vent service discovered before any fault.
        self.officer = Probe(part.graph.domain_id, 'safety_officer')
        self.officer._client(Trigger, interface.VENT, 30.0)

    def _run(self) -> None:
        try:
            self.driver.run()
        except BaseException as exc:  # noqa: BLE001 - the run reports it
            self.errors.append(exc)

    def close(self) -> list[str]:
        problems = []
        self.operator_leaves()
        if self._thread is not None and self._thread.is_alive():
            self.driver.command('stop')
            self._thread.join(30)
        if self.officer is not None:
            self.officer.close()
        try:
            self.part.close()
        except PlcInvariantError as exc:
            problems.append(str(exc))
        for key, pid in self.graph.pids:
            if state(pid) not in (None, 'Z'):
                problems.append(f'{key} pid {pid} still running after the run')
        return problems + [f'left behind: {line}' for line in self.graph.leftovers()]

    # ---- observation
    def pressurised(self) -> bool:
        self.register_log.poll()
        last = self.register_log.entries[-1] if self.register_log.entries else None
        return last is not None and not last.vented

    def check(self) -> None:
        if self.errors:
            raise AssertionError(f'the session ended with {self.errors[0]!r}')

    def in_trial_under_pressure(self) -> bool:
        self.check()
        return self.session.phase == 'target' and self.pressurised()

    # ---- one fault
    def inject(self, index: int, p: StudyFault) -> StudyOutcome:
        wait_until(self.in_trial_under_pressure, PRESSURE_S, what=f'fault {index}: a trial under pressure')
        time.sleep(p.into_trial_s)      # a drawn moment of the trial (a fixed span, not a wait)
        wait_until(self.in_trial_under_pressure, PRESSURE_S, what=f'fault {index}: a trial under pressure')
        in_trial = len(self.driver.rows)
        if p.kind == 'foreign_writer':
            try:
                w = second_writer.inject(self, index, 2 * p.operator_s, TITLE[p.kind], WATCHDOG_VENT_S)
            finally:
                presses = self.operator_leaves()
            self.check()
            # 0.0: vented before it fell silent (the respawned plc_output's vent request).
            note = (f'plc_output kept out until it requested the PLC vent: the operator pressed e {presses} time(s)'
                    if presses else 'plc_output back before its vent request')
            if 'claim_freed' in w:
                note += "; plc_output's own link failed during the refusals and the writer took the freed claim"
            return StudyOutcome(index, p, w['t_die'], t_enable=w.get('operator_enable'), writer=w,
                                recovery_s=w['recovery_s'], vent_s=vent_time(self.register_log.entries, w['t_die']),
                                note=note)
        g = self.graph
        restarts = g.restart_count('pressure_controller')
        t0 = time.monotonic()
        if p.kind == 'outside_vent':
            from std_srvs.srv import Trigger
            if not self.officer.call(Trigger, interface.VENT, Trigger.Request()).success:
                raise AssertionError(f'fault {index}: the outside vent was refused')
        else:
            g.processes['pressure_controller'].send_signal(signal.SIGKILL)
        out = StudyOutcome(index, p, t0)
        wait_until(lambda: self.check() or self.session.phase == 'held', SESSION_HOLD_S,
                   what=f'fault {index}: the session holding for the operator')
        out.held_s = time.monotonic() - t0
        if p.kind == 'controller_kill':
            wait_until(lambda: g.restart_count('pressure_controller') > restarts, PRESSURE_S,
                       what=f'fault {index}: the controller respawned')
        # The operator looks at the suit; meanwhile the session must stay held, vented.
        time.sleep(max(0.0, t0 + p.operator_s - time.monotonic()))
        if self.session.phase != 'held':
            out.problems.append(f'the session left its hold by itself (phase {self.session.phase})')
        # The trial the fault cut is recorded 'vented' (and run again: the session's end counts it);
        # one that ended in the instant before the session saw the arm drop, as it ended.
        # (The loop records it just after it holds: waited for, not read at once.)
        try:
            wait_until(lambda: len(self.driver.rows) > in_trial, ROW_S, what='the row')
        except AssertionError:
            out.problems.append(f'the session held without recording the trial the fault cut within {ROW_S:g} s')
        cut = [r['status'] for r in self.driver.rows[in_trial:]]
        out.note = f"the trial it cut recorded {', '.join(cut)}" if cut else ''
        out.t_enable = self.operator_arms(f'fault {index}')
        # Should the session hold again (a respawned controller's first trial gate not answered),
        # the operator presses e again, as at the terminal.
        self.operator_stays()
        try:
            wait_until(self.pressurised, PRESSURE_S, what=f'fault {index}: pressure again after the operator armed')
        finally:
            again = self.operator_leaves()
        self.check()
        out.recovery_s = time.monotonic() - out.t_enable
        if again:
            out.note += f'; the session held again and the operator pressed e {again} more time(s)'
        wait_until(lambda: self.register_log.poll().drained >= out.fault().held_until, 10.0,
                   what='the register log drained')
        out.vent_s, _ = fault_vent(self.register_log.entries, out.fault())
        return out


def judge(lab: StudyChaosLab, outcomes: list[StudyOutcome]) -> list[str]:
    entries = lab.register_log.entries
    faults = [o.fault() for o in outcomes]
    return (over_p_max(entries, lab.p_max_counts) + late_vents(entries, faults, lab.register_log.drained)
            + gate_breaches(entries, faults)
            + second_writer.breaches(entries, [(TITLE[o.planned.kind], o.writer) for o in outcomes if o.writer],
                                     WATCHDOG_VENT_S, lab.register_log.drained)
            + [f'fault {o.index} ({o.planned.kind}): {n}' for o in outcomes for n in o.problems])


def table(outcomes: list[StudyOutcome]) -> list[dict]:
    rows: dict[str, dict] = {}
    for o in outcomes:
        r = rows.setdefault(o.planned.kind, {'kind': TITLE[o.planned.kind], 'count': 0,
                                             'deadline_s': DEADLINE_S[o.planned.kind], 'worst_vent_s': None,
                                             'worst_held_s': None, 'worst_recovery_s': None})
        r['count'] += 1
        for key, value in (('worst_vent_s', o.vent_s), ('worst_held_s', o.held_s),
                           ('worst_recovery_s', o.recovery_s)):
            if value is not None and (r[key] is None or value > r[key]):
                r[key] = value
    return [rows[k] for k in KINDS if k in rows]


def markdown(rows: list[dict], seed: int, faults: int, session: dict, violations: list[str]) -> str:
    def s(v):
        return '—' if v is None else f'{v:.3f} s'
    lines = [f'Chaos run with the study session, seed {seed}, {faults} faults: '
             + ('every invariant held.' if not violations else f'{len(violations)} invariant(s) broken.'), '',
             '| fault | count | deadline (vented by) | worst vent | worst until the session held | '
             "worst back to pressure after the operator's e (a writer: after its silence) |",
             '| --- | --- | --- | --- | --- | --- |']
    for r in rows:
        lines.append(f"| {r['kind']} | {r['count']} | {s(r['deadline_s'])} | {s(r['worst_vent_s'])} | "
                     f"{s(r['worst_held_s'])} | {s(r['worst_recovery_s'])} |")
    lines += ['', f"The session: {session['phase']}, {session['trials_run']} of {session['planned']} planned "
                  f"trials run, {session['vented']} recorded vented and run again."]
    if violations:
        lines += ['', 'Broken invariants:', ''] + [f'- {v}' for v in violations]
    return '\n'.join(lines) + '\n'


def run_study_chaos(seed: int, faults: int, out: Path, say) -> tuple[list[dict], list[str]]:
    """The run; returns the table's rows and every broken invariant ([] when all held)."""
    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    plan = schedule(seed, faults)
    # Enough trials: a fault's trial is run again when the fault cut it (a foreign writer's trial
    # may go on), so each fault takes at most one planned trial.
    lab = StudyChaosLab(out, -(-faults // len(CONDITIONS)), say)
    outcomes: list[StudyOutcome] = []
    violations: list[str] = []
    t_start = time.monotonic()
    try:
        say(f'chaos --study: seed {seed}, {faults} faults, {lab.planned_trials} trials planned; logs in {out}')
        lab.start()
        for i, p in enumerate(plan, 1):
            try:
                o = lab.inject(i, p)
            except AssertionError as exc:     # a wait ran out: the run ends here, said in one line
                violations.append(f'fault {i} ({TITLE[p.kind]}): {exc}')
                say(f'[{i}/{faults}] {TITLE[p.kind]}: BROKEN: {exc}')
                break
            outcomes.append(o)
            found = [v for v in judge(lab, outcomes) if v not in violations]
            violations += found
            held = f'session held after {o.held_s:.2f} s; ' if o.held_s is not None else ''
            vent = f'vented in {o.vent_s:.3f} s' if o.vent_s is not None else 'not vented'
            say(f'[{i}/{faults}] {TITLE[p.kind]}: {vent} '
                f'(deadline {DEADLINE_S[p.kind]:.3f} s); {held}pressure again {o.recovery_s:.2f} s after '
                + ('it fell silent' if o.writer is not None else "the operator's e")
                + (f'; {o.note}' if o.note else '') + (f'; BROKEN: {"; ".join(found)}' if found else ''))
        else:
            try:
                wait_until(lambda: lab.check() or lab.session.phase in ('done', 'stopped'), FINISH_S,
                           what='the session to run its remaining trials')
            except AssertionError as exc:
                violations.append(str(exc))
    finally:
        violations += lab.close()
    lab.register_log.poll()
    violations = sorted(set(violations + judge(lab, outcomes)))
    statuses = [r['status'] for r in lab.driver.rows] if lab.driver is not None else []
    session = {'phase': lab.session.phase, 'planned': lab.planned_trials, 'vented': statuses.count('vented'),
               'trials_run': len(statuses) - statuses.count('vented')}
    if session['phase'] != 'done' or session['trials_run'] != session['planned']:
        violations.append(f"the session ended {session['phase']} with {session['trials_run']} of "
                          f"{session['planned']} planned trials run")
    rows = table(outcomes)
    summary = {'seed': seed, 'faults': faults, 'duration_s': time.monotonic() - t_start, 'session': session,
               'restarts': len(lab.graph.restarts), 'rows': rows, 'violations': violations,
               'faults_run': [{'index': o.index, 'kind': o.planned.kind, 'operator_s': o.planned.operator_s,
                               'vent_s': o.vent_s, 'held_s': o.held_s, 'recovery_s': o.recovery_s,
                               'note': o.note, 'problems': o.problems} for o in outcomes],
               'session_lines': [line for line in lab.lines if 'STOPPED' in line or 'operator' in line]}
    write_text(out / 'chaos.json', json.dumps(summary, indent=1) + '\n')
    write_text(out / 'chaos.md', markdown(rows, seed, faults, session, violations))
    return rows, violations
