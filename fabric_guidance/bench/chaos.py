"""fabric-guidance chaos: a seeded schedule of faults on the lab graph, held to invariants read
from the mock PLC's own register log.

The graph: mock_plc (its register log on), a fault proxy on the Modbus link, plc_output,
gaze_bridge fed by a gaze stub (the wearer looks ahead; one target 40 deg left, so guidance
holds L1 and L2 at a steady pressure), target_selector, pressure_controller, headset_display and
bag_recorder (the session is recorded throughout). Every node but mock_plc is supervised
(process_graph.Graph.supervise): a node that dies is restarted with back-off, as the lab launch
respawns it, and the controller starts disabled (start_enabled false), so every start of it,
first or respawned, waits for the operator's enable, which this run calls.

Each fault is drawn from the seed: SIGKILL, or SIGSTOP then SIGCONT, of each node in turn and
of two at once; the Modbus link dropping every byte or delayed beyond the request timeout; the
gaze stream paused or flooded; plc_output frozen while the controller is killed (freeze + kill:
the commands the controller sent before its death wait in the frozen process and must never be
written after SIGCONT); the operator's own calls: `enable false` during a calibration, and `vent`
followed by a lifecycle deactivate and activate; a second Modbus writer (second_writer.py, closing
each round). Each is injected while the suit is pressurised, during guidance or during a
calibration (start_calibration), then healed (for the operator's calls: by the operator's
`enable`), and guidance must come back.

Invariants, from the register log alone (plc/register_log.py), checked after every fault and
again at the end: no command above P_MAX ever sent; every fault that must vent has every
register at 0 within its deadline (docs/safety.md); after a controller restart, the operator's
`enable false` or `vent` (deactivate and activate included), nothing nonzero is applied before the
operator's enable; at the end no process of the graph is left; a second writer is refused while
plc_output holds the PLC, and once it holds it and dies the suit vents within the watchdog's
deadline and its command never comes back. Output: progress per fault, then a table of every
fault kind with its deadline and worst measured time, as Markdown and JSON in --out. --study:
the same with the study session running (bench/chaos_study.py).
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass, field
import itertools
import json
import os
from pathlib import Path
import random
import re
import signal
import socket
import sys
import tempfile
import time

from .. import interface, subcommand
from ..atomic import write_text
from ..plc.register_log import Fault, RegisterLog, fault_vent, gate_breaches, late_vents, over_p_max, vent_time
from ..graph.process_graph import CONFIG, Graph, PlcInvariantError, free_port, wait_until
from . import second_writer
from .deadlines import (CONTROLLER_VENT_S, GAZE_STALE_VENT_S, LINK_DELAY_S, LINK_DELAY_VENT_S,
                        OPERATOR_VENT_S, WATCHDOG_VENT_S)
from .faultproxy import FaultProxy
from .gaze_stub import FLOOD_RATE_HZ, GazeStub
from .graphs import state

HELP = 'a seeded schedule of faults on the lab graph, invariants checked from the PLC register log'

FILES = ('params/guidance.yaml', 'params/sim.yaml')
NODES = ('pressure_controller', 'plc_output', 'gaze_bridge', 'target_selector', 'headset_display', 'bag_recorder')
#: The nodes a fault of the run may kill or stop: all but mock_plc, which stands for the PLC (a
#: real one outlives the PC's processes; its log is what the run is judged by) and never restarts.
SUPERVISED = NODES

#: Per node, the deadline of a SIGKILL or SIGSTOP; None: the suit need not vent (the controller
#: keeps the latched target when target_selector dies silently; headset_display and
#: bag_recorder only listen).
NODE_VENT_S = {'pressure_controller': CONTROLLER_VENT_S, 'plc_output': WATCHDOG_VENT_S,
               'gaze_bridge': GAZE_STALE_VENT_S, 'target_selector': None, 'headset_display': None,
               'bag_recorder': None}
#: A fault ended (SIGCONT, a respawn, the link healed, the gaze back) -> pressure again at the
#: registers: a cold start of a node on two loaded cores, plc_output's longest backoff.
RECOVERY_DEADLINE_S = 45.0
#: A restarted controller is watched this long, vented and disabled, before the operator's
#: enable: the window in which the enable gate must hold.
GATE_WATCH_S = 1.0
#: How long a lasting fault (a stop, a link or gaze fault) holds [s]: longer than any deadline,
#: so that the vent is seen to hold.
HOLD_S = (1.6, 2.6)
#: freeze + kill: plc_output is stopped, then the controller killed this much later (its commands
#: meanwhile queue in the frozen process), and plc_output continued at the end of the hold.
FREEZE_KILL = ('plc_output', 'pressure_controller')
FREEZE_KILL_AFTER_S = 0.3

#: The line a lifecycle node logs once active (nodes/managed.py), by itself or by a transition.
ACTIVE = re.compile(r'\]: (configured and )?active( \(autostart\))?$', re.M)
#: The target: 40 deg left of the stub's gaze (guided_lab's, as the fault tests).
TARGET = [1.5321, 1.2856, 1.2]


#: The operator's calls a round ends with (after the shuffled faults, so that a seed's first
#: faults stay what they were).
OPERATOR = ('disable', 'vent_cycle')


def pair_deadline(nodes) -> float | None:
    """Two nodes at once: each node's own way of venting is independent of the other's, so the
    suit is vented by the latest of the deadlines that apply; None when neither must vent."""
    deadlines = [NODE_VENT_S[n] for n in nodes if NODE_VENT_S[n] is not None]
    return max(deadlines) if deadlines else None


@dataclass(frozen=True)
class Planned:
    """One fault of the schedule."""
    # kill, stop, freeze_kill, link_drop, link_delay, gaze_pause, gaze_flood, disable, vent_cycle,
    # two_writers
    action: str
    nodes: tuple[str, ...] = ()
    phase: str = 'guidance'     # guidance or calibration
    hold_s: float = 2.0         # how long a stop, a link fault or a gaze fault lasts

    @property
    def kind(self) -> str:
        who = ' + '.join(self.nodes)
        return {'kill': f'SIGKILL of {who}', 'stop': f'SIGSTOP of {who}, then SIGCONT',
                'link_drop': 'Modbus link drops every byte',
                'link_delay': f'Modbus link delayed {LINK_DELAY_S:g} s each way',
                'freeze_kill': 'SIGSTOP of plc_output, SIGKILL of pressure_controller meanwhile, then SIGCONT',
                'gaze_pause': 'gaze stream paused',
                'gaze_flood': f'gaze stream flooded ({FLOOD_RATE_HZ:.0f} datagrams/s)',
                'disable': 'enable false during a calibration',
                'vent_cycle': 'operator vent, then deactivate and activate',
                'two_writers': 'a second Modbus writer holds the PLC, then falls silent'}[self.action]

    @property
    def deadline_s(self) -> float | None:
        if self.action in ('kill', 'stop'):
            return pair_deadline(self.nodes)
        return {'freeze_kill': WATCHDOG_VENT_S, 'link_drop': WATCHDOG_VENT_S, 'link_delay': LINK_DELAY_VENT_S,
                'gaze_pause': GAZE_STALE_VENT_S, 'gaze_flood': None, 'disable': OPERATOR_VENT_S,
                'vent_cycle': OPERATOR_VENT_S, 'two_writers': WATCHDOG_VENT_S}[self.action]


def schedule(seed: int, faults: int) -> list[Planned]:
    """`faults` faults from `seed`: rounds of every kind once (each node killed and stopped in
    turn, a pair killed and a pair stopped, every link and gaze fault), each round shuffled;
    phase and hold drawn per fault; then the operator's calls (OPERATOR), enable false always
    during a calibration; a second writer closes each round (drawn from its own generator: the
    other faults of a seed stay as they were). The same seed gives the same schedule."""
    rng = random.Random(seed)
    extra = random.Random(f'{seed}-two-writers')
    out: list[Planned] = []
    while len(out) < faults:
        pairs = list(itertools.combinations(NODES, 2))
        kinds = ([('kill', (n,)) for n in NODES] + [('stop', (n,)) for n in NODES]
                 + [('kill', rng.choice(pairs)), ('stop', rng.choice(pairs))]
                 + [(a, ()) for a in ('link_drop', 'link_delay', 'gaze_pause', 'gaze_flood')]
                 + [('freeze_kill', FREEZE_KILL)])
        rng.shuffle(kinds)
        for action, nodes in kinds:
            out.append(Planned(action, tuple(nodes), rng.choice(('guidance', 'calibration')),
                               round(rng.uniform(HOLD_S[0], HOLD_S[1]), 2)))
        for action in OPERATOR:
            phase = 'calibration' if action == 'disable' else rng.choice(('guidance', 'calibration'))
            out.append(Planned(action, (), phase, round(rng.uniform(HOLD_S[0], HOLD_S[1]), 2)))
        out.append(Planned('two_writers', ('plc_output',), extra.choice(('guidance', 'calibration')),
                           round(extra.uniform(HOLD_S[0], HOLD_S[1]), 2)))
    return out[:faults]


@dataclass
class Outcome:
    """One fault as it happened."""
    index: int
    planned: Planned
    t: float
    t_end: float | None = None     # when the fault ended: SIGCONT, healed, restarted
    vent_s: float | None = None
    recovery_s: float | None = None
    t_enable: float | None = None
    notes: list[str] = field(default_factory=list)
    #: a second writer's fault: its start, plc_output's kill, its refusals before the kill
    writer: dict | None = None


class ChaosLab:
    """The graph of the run, its fault proxy, gaze stub, register log and probe."""

    def __init__(self, work: Path, say):
        from ..plc import RegisterMap
        self.work, self.say = work, say
        self.plc_port = free_port()
        self.gaze_port = free_port(socket.SOCK_DGRAM)
        self.graph = Graph(work / 'logs')
        self.log_path = work / 'register_log.jsonl'
        self.bags = work / 'bags'
        self.bags.mkdir(parents=True, exist_ok=True)
        self.p_max_counts = RegisterMap.load(CONFIG / 'hardware' / 'plc_register_map.yaml').p_max_counts
        self.proxy = None
        self.gaze = None
        self.probe = None
        self.register_log = RegisterLog(self.log_path)
        self._offsets: dict[str, int] = {}

    # ---- up and down
    def start(self) -> None:
        g = self.graph
        g.start('mock_plc', FILES, port=self.plc_port, register_log_file=str(self.log_path))
        wait_until(lambda: _listening(self.plc_port), 30.0, what='mock_plc listening')
        self.proxy = FaultProxy('127.0.0.1', self.plc_port)
        g.start('plc_output', FILES, plc_port=self.proxy.port)
        g.start('gaze_bridge', FILES, port=self.gaze_port)
        g.start('target_selector', FILES, target_names=['left40'], target_positions=TARGET, auto_advance=False)
        # stall_timeout_s 0: the stub's gaze never moves, and the no-progress vent would end the
        # guidance the faults interrupt. A short calibration (3 steps, 0.3 s dwell) fits between
        # faults; with the stub's still gaze it fails at its fit, keeping the calibration file.
        g.start('pressure_controller', FILES, calibration_file=str(CONFIG / 'calibrations' / 'sim-wearer.yaml'),
                calibration_dir=str(self.work / 'calibrations'), stall_timeout_s=0.0, start_enabled=False,
                calibration_steps=3, calibration_dwell_s=0.3, calibration_rest_s=0.3, calibration_window_s=0.1)
        g.start('headset_display', FILES, headset_address='127.0.0.1', display_port=free_port(socket.SOCK_DGRAM))
        g.start('bag_recorder', (), output=str(self.bags / 'session-0'))
        # A restarted recorder writes a new bag: the one its predecessor left stays as it was.
        g.supervise(*SUPERVISED, delay_s=0.5, max_delay_s=4.0, stable_s=10.0,
                    fresh={'bag_recorder': lambda n: {'output': str(self.bags / f'session-{n}')}})
        self.gaze = GazeStub(self.gaze_port)
        from ..graph.process_graph import Probe
        self.probe = Probe(g.domain_id, 'chaos_operator')
        self.wait_active('pressure_controller', 60.0)
        self.enable()
        # The operator's other services discovered now: an operator fault is timed from the
        # request, not from this probe's discovery of the service.
        from lifecycle_msgs.srv import ChangeState
        from std_srvs.srv import Trigger
        for srv_type, name in ((Trigger, interface.VENT), (ChangeState, '/pressure_controller/change_state')):
            self.probe._client(srv_type, name, 30.0)
        self.wait_pressurised(RECOVERY_DEADLINE_S, 'first guidance')

    def close(self) -> list[str]:
        """Everything down; the problems found on the way (leftover processes, PLC records)."""
        problems = []
        if self.probe is not None:
            self.probe.close()
        if self.gaze is not None:
            self.gaze.close()
        try:
            self.graph.stop_all(check=True)
        except PlcInvariantError as exc:
            problems.append(str(exc))
        if self.proxy is not None:
            self.proxy.close()
        for key, pid in self.graph.pids:
            if _alive(pid):
                problems.append(f'{key} pid {pid} still running after the run')
        problems += [f'left behind: {line}' for line in self.graph.leftovers()]
        return problems

    # ---- observation
    def pressurised(self) -> bool:
        self.register_log.poll()
        last = self.register_log.entries[-1] if self.register_log.entries else None
        return last is not None and not last.vented

    def wait_pressurised(self, timeout: float, what: str) -> float:
        t0 = time.monotonic()
        wait_until(self.pressurised, timeout, what=f'{what}: pressure at the registers')
        return time.monotonic() - t0

    def wait_active(self, node: str, timeout: float) -> None:
        """The node logged that it is active (a lifecycle node's own line) since mark_log(node):
        a restarted node's log is appended to its predecessor's."""
        wait_until(lambda: ACTIVE.search(self.graph.log(node), self._offsets.get(node, 0)), timeout,
                   what=f'{node} active')

    def mark_log(self, node: str) -> None:
        """From now on, wait_active looks only at what the node logs after this point."""
        self._offsets[node] = len(self.graph.log(node))

    def enable(self) -> float:
        """The operator's enable; returns the time the request was sent."""
        from std_srvs.srv import SetBool
        t = time.monotonic()
        response = self.probe.call(SetBool, interface.ENABLE, SetBool.Request(data=True), timeout=3.0, attempts=10)
        if not response.success:
            raise AssertionError(f'enable refused: {response.message}')
        return t

    def disable(self) -> None:
        from std_srvs.srv import SetBool
        response = self.probe.call(SetBool, interface.ENABLE, SetBool.Request(data=False), timeout=3.0, attempts=5)
        if not response.success:
            raise AssertionError(f'enable false refused: {response.message}')

    def vent_cycle(self) -> None:
        """The operator's vent, then a lifecycle deactivate and activate of the controller."""
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState
        from std_srvs.srv import Trigger
        if not self.probe.call(Trigger, interface.VENT, Trigger.Request(), timeout=3.0, attempts=5).success:
            raise AssertionError('vent refused')
        for transition in (Transition.TRANSITION_DEACTIVATE, Transition.TRANSITION_ACTIVATE):
            request = ChangeState.Request(transition=Transition(id=transition))
            if not self.probe.call(ChangeState, '/pressure_controller/change_state', request, timeout=10.0).success:
                raise AssertionError(f'lifecycle transition {transition} refused')

    def start_calibration(self) -> None:
        from std_srvs.srv import Trigger
        response = self.probe.call(Trigger, interface.START_CALIBRATION, Trigger.Request(), timeout=3.0, attempts=5)
        if not response.success and 'already running' not in response.message:
            raise AssertionError(f'start_calibration refused: {response.message}')

    # ---- one fault
    def inject(self, index: int, p: Planned) -> Outcome:
        g = self.graph
        if p.phase == 'calibration':
            t_call = time.monotonic()
            self.start_calibration()
            # The calibration begins vented (its rest before the first direction): wait for that
            # vent, so that the fault hits one of its pressure steps, not the guidance before it.
            wait_until(lambda: any(e.vented for e in self.register_log.poll().entries if e.t > t_call),
                       RECOVERY_DEADLINE_S, what=f'fault {index}: the calibration begun (vented rest)')
        # Injected while the suit is pressurised: a vent is then a change the log must show.
        self.wait_pressurised(RECOVERY_DEADLINE_S, f'fault {index} ({p.phase})')
        if p.action == 'two_writers':
            return self.two_writers(index, p)
        restarts = {n: g.restart_count(n) for n in p.nodes}
        for n in p.nodes:
            self.mark_log(n)
        pids = [g.processes[n].pid for n in p.nodes]
        t0 = time.monotonic()
        out = Outcome(index, p, t0)
        if p.action == 'kill':
            for pid in pids:
                os.kill(pid, signal.SIGKILL)
        elif p.action == 'stop':
            for pid in pids:
                os.kill(pid, signal.SIGSTOP)
        elif p.action == 'freeze_kill':
            frozen, killed = pids
            os.kill(frozen, signal.SIGSTOP)
            time.sleep(FREEZE_KILL_AFTER_S)
            os.kill(killed, signal.SIGKILL)
        elif p.action == 'link_drop':
            self.proxy.drop()
        elif p.action == 'link_delay':
            self.proxy.delay(LINK_DELAY_S)
        elif p.action == 'gaze_pause':
            self.gaze.mode = 'pause'
        elif p.action == 'gaze_flood':
            self.gaze.mode = 'flood'
        elif p.action == 'disable':
            self.disable()
        elif p.action == 'vent_cycle':
            self.vent_cycle()
        # A lasting fault holds for hold_s (a fixed fault duration, not a wait for anything).
        if p.action != 'kill':
            time.sleep(max(0.0, t0 + p.hold_s - time.monotonic()))
        # Heal.
        t_heal = out.t_end = time.monotonic()
        if p.action == 'stop':
            for pid in pids:
                os.kill(pid, signal.SIGCONT)
        elif p.action == 'freeze_kill':
            os.kill(pids[0], signal.SIGCONT)
            # The dead controller's queued commands must not reach the registers: the enable gate
            # (judged from the vent to the operator's enable) covers the time after SIGCONT.
            self.controller_back(out, ('pressure_controller',), restarts, t0)
            out.t_end = max(t_heal, out.t_end)
        elif p.action in ('link_drop', 'link_delay'):
            self.proxy.heal()
        elif p.action in ('gaze_pause', 'gaze_flood'):
            self.gaze.mode = 'send'
        elif p.action in OPERATOR:
            # Only the operator's enable ends it: the log is judged for nothing applied before it.
            out.t_enable = self.enable()
        elif p.action == 'kill':
            self.controller_back(out, p.nodes, restarts, t0)
        self.wait_pressurised(RECOVERY_DEADLINE_S, f'fault {index}: {p.kind}: guidance back')
        out.recovery_s = time.monotonic() - t_heal
        fault = as_fault(out)
        wait_until(lambda: self.register_log.poll().drained >= fault.held_until, 10.0, what='the register log drained')
        out.vent_s, _ = fault_vent(self.register_log.entries, fault)
        return out

    def two_writers(self, index: int, p: Planned) -> Outcome:
        """A second Modbus writer (second_writer.py); its death is the fault's time."""
        w = second_writer.inject(self, index, p.hold_s, p.kind, WATCHDOG_VENT_S)
        out = Outcome(index, p, w['t_die'], t_end=w['t_die'], recovery_s=w['recovery_s'], writer=w)
        out.vent_s = vent_time(self.register_log.entries, w['t_die'])
        return out

    def controller_back(self, out: Outcome, killed, restarts: dict, t0: float) -> None:
        """Killed nodes restarted; a restarted controller watched vented, then enabled."""
        g = self.graph
        for n in killed:
            wait_until(lambda: g.restart_count(n) > restarts[n], RECOVERY_DEADLINE_S, what=f'{n} restarted')
        # The fault ends with the first of the new processes (it may pressurise from then).
        out.t_end = min(r.started for r in g.restarts if r.node in killed and r.started > t0)
        if 'pressure_controller' in killed:
            self.wait_active('pressure_controller', RECOVERY_DEADLINE_S)
            # Up, vented and disabled: watched for GATE_WATCH_S with gaze and target present,
            # then the operator enables. The log is judged for that window at the end.
            wait_until(lambda: self.register_log.poll().drained > time.monotonic() - 0.01 and
                       vent_time(self.register_log.entries, t0, time.monotonic() - 0.01) is not None,
                       RECOVERY_DEADLINE_S, what='the vent in the register log')
            t_watch = time.monotonic()
            while time.monotonic() < t_watch + GATE_WATCH_S:
                if self.pressurised():
                    out.notes.append('pressure before enable')
                    break
                time.sleep(0.02)
            out.t_enable = self.enable()


def _listening(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.2)
        return s.connect_ex(('127.0.0.1', port)) == 0


def _alive(pid: int) -> bool:
    return state(pid) not in (None, 'Z')


def as_fault(o: Outcome) -> Fault:
    # A second writer's vent is judged by second_writer.breaches: from its death to the first
    # vent (the respawned plc_output may guide again as soon as the PLC is free).
    deadline = None if o.writer is not None else o.planned.deadline_s
    return Fault(o.planned.kind, o.t, deadline, o.t_end, o.t_enable)


def judge(log: RegisterLog, outcomes: list[Outcome], p_max_counts: int) -> list[str]:
    """Every breach of the invariants the register log shows for these faults."""
    faults = [as_fault(o) for o in outcomes]
    return (over_p_max(log.entries, p_max_counts) + late_vents(log.entries, faults, log.drained)
            + gate_breaches(log.entries, faults)
            + second_writer.breaches(log.entries, [(o.planned.kind, o.writer) for o in outcomes if o.writer],
                                     WATCHDOG_VENT_S, log.drained))


def table(outcomes: list[Outcome]) -> list[dict]:
    """Per fault kind: count, deadline, worst time to vent, worst time to guidance back."""
    rows: dict[str, dict] = {}
    for o in outcomes:
        r = rows.setdefault(o.planned.kind, {'kind': o.planned.kind, 'count': 0, 'deadline_s': o.planned.deadline_s,
                                             'worst_vent_s': None, 'worst_recovery_s': None, 'phases': []})
        r['count'] += 1
        if o.planned.phase not in r['phases']:
            r['phases'].append(o.planned.phase)
        for key, value in (('worst_vent_s', o.vent_s), ('worst_recovery_s', o.recovery_s)):
            if value is not None and (r[key] is None or value > r[key]):
                r[key] = value
    return sorted(rows.values(), key=lambda r: r['kind'])


def markdown(rows: list[dict], seed: int, faults: int, violations: list[str]) -> str:
    def s(v):
        return '—' if v is None else f'{v:.3f} s'
    lines = [f'Chaos run, seed {seed}, {faults} faults: '
             + ('every invariant held.' if not violations else f'{len(violations)} invariant(s) broken.'), '',
             '| fault | count | phases | deadline (vented by) | worst vent | worst back to guidance |',
             '| --- | --- | --- | --- | --- | --- |']
    for r in rows:
        deadline = s(r['deadline_s']) if r['deadline_s'] is not None else 'none (need not vent)'
        lines.append(f"| {r['kind']} | {r['count']} | {', '.join(r['phases'])} | {deadline} | "
                     f"{s(r['worst_vent_s'])} | {s(r['worst_recovery_s'])} |")
    if violations:
        lines += ['', 'Broken invariants:', ''] + [f'- {v}' for v in violations]
    return '\n'.join(lines) + '\n'


def run_chaos(seed: int, faults: int, out: Path, say,
              plan: list[Planned] | None = None) -> tuple[list[dict], list[str]]:
    """The run; returns the table's rows and every broken invariant ([] when all held). plan:
    these faults instead of the seed's schedule (a test of chosen kinds)."""
    out = Path(out).resolve()   # the nodes run in the package's folder: their paths must not be relative
    out.mkdir(parents=True, exist_ok=True)
    plan = schedule(seed, faults) if plan is None else list(plan)
    faults = len(plan)
    lab = ChaosLab(out, say)
    outcomes: list[Outcome] = []
    violations: list[str] = []
    t_start = time.monotonic()
    try:
        say(f'chaos: seed {seed}, {faults} faults; graph logs in {out / "logs"}')
        lab.start()
        say(f'chaos: graph up and guiding after {time.monotonic() - t_start:.1f} s')
        for i, p in enumerate(plan, 1):
            o = lab.inject(i, p)
            outcomes.append(o)
            # Checked as the run goes, on what the log holds now.
            found = [v for v in judge(lab.register_log, outcomes, lab.p_max_counts) if v not in violations]
            violations += found
            deadline = f'{p.deadline_s:.3f} s' if p.deadline_s is not None else 'none'
            vent = f'vented in {o.vent_s:.3f} s' if o.vent_s is not None else 'not vented'
            gate = ', enable gate held' if o.t_enable is not None and not o.notes else ''
            since = 'the kill' if p.action == 'kill' else 'the heal'
            say(f'[{i}/{faults}] {p.kind} ({p.phase}): {vent} (deadline {deadline}); '
                f'guidance back {o.recovery_s:.2f} s after {since}{gate}'
                + (f'; BROKEN: {"; ".join(found)}' if found else ''))
    finally:
        problems = lab.close()
        violations += problems
    lab.register_log.poll()
    violations = sorted(set(violations + judge(lab.register_log, outcomes, lab.p_max_counts)))
    rows = table(outcomes)
    restarts = len(lab.graph.restarts)
    summary = {'seed': seed, 'faults': faults, 'duration_s': time.monotonic() - t_start, 'restarts': restarts,
               'processes_started': len(lab.graph.pids), 'bags': sorted(p.name for p in lab.bags.iterdir()),
               'rows': rows, 'violations': violations,
               'faults_run': [{'index': o.index, 'kind': o.planned.kind, 'phase': o.planned.phase,
                               'hold_s': o.planned.hold_s, 'deadline_s': o.planned.deadline_s, 'vent_s': o.vent_s,
                               'recovery_s': o.recovery_s,
                               'enabled_after_s': (o.t_enable - o.t) if o.t_enable else None}
                              for o in outcomes]}
    write_text(out / 'chaos.json', json.dumps(summary, indent=1) + '\n')
    write_text(out / 'chaos.md', markdown(rows, seed, faults, violations))
    return rows, violations


def configure(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    parser.add_argument('--seed', type=int, required=True,
                        help='the schedule of faults (the same seed, the same faults)')
    parser.add_argument('--faults', type=int, default=20, help='how many faults (default 20)')
    parser.add_argument('--out', default=None, help='folder for chaos.md, chaos.json, the register log, the bags '
                        'and the node logs (default: a new temporary folder)')
    parser.add_argument('--study', action='store_true', help='with the study session running: outside vents, '
                        'controller restarts, foreign Modbus writers mid-trial (bench/chaos_study.py)')
    return parser


def add_parser(subparsers) -> argparse.ArgumentParser:
    return subcommand.add(subparsers, 'chaos', HELP, __doc__, configure, run)


def run(args, stream=sys.stdout) -> int:
    say = subcommand.printer(stream)
    if args.faults < 1:
        subcommand.error('fabric-guidance chaos', f'--faults must be 1 or more, got {args.faults}')
        return 2
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix='fabric-guidance-chaos-'))
    if args.study:
        from .chaos_study import run_study_chaos
        rows, violations = run_study_chaos(args.seed, args.faults, out, say)
    else:
        rows, violations = run_chaos(args.seed, args.faults, out, say)
    say('')
    say((out / 'chaos.md').read_text())
    say(f'written: {out / "chaos.md"}, {out / "chaos.json"}')
    return 1 if violations else 0


if __name__ == '__main__':
    sys.exit(subcommand.main('python -m fabric_guidance.bench.chaos', __doc__, configure, run))
