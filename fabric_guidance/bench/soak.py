"""fabric-guidance soak: the simulated lab graph guiding target after target for N minutes, with
the figures a lab checks before trusting the graph for an afternoon, one row per minute, and a
verdict on drift.

The graph is demo's (process_graph.sim_lab: mock_plc, plc_output, gaze_bridge, target_selector,
pressure_controller, headset_display, wearer_sim as the HoloLens), condition 1. target_selector
runs a sequence of the four targets of config/params/guidance.yaml repeated for longer than the
run can use, auto-advancing with the speed protocol's return to the front; the run is the
operator: it starts the task, and skips a target (next_target) the wearer has not found within
--target-timeout-s, so that a stall shows in the rows instead of ending the run.

Before the clock starts, data must flow end to end: gaze at the controller, the bridge's clock
estimate synchronised, and a gaze sample's command applied at the mock PLC's registers.

Per row (--row-seconds, 60 by default), appended to soak.csv as it ends (a killed run keeps its
rows): the gaze-to-register latency p50/p99/max (defined in soak.md), each node's RSS, CPU seconds
per minute, open file descriptors and threads (/proc), gaze datagrams received, lost and dropped
by gaze_bridge (its /diagnostics), control steps the run did not see and changed commands that
never reached the registers, the mock PLC's watchdog trips and refused stale writes, targets
reached and skipped, the median time to a target, and a stall column naming what stopped.
At the end: a least-squares slope per hour for every figure with its 95 % interval; a figure
drifts only when the interval excludes zero and the slope exceeds its threshold (10 % of its
mean per hour, at least a floor per unit). soak.md (verdict), soak.json, soak.png (every figure over
time) in --out.
"""
from __future__ import annotations

import argparse
from collections import Counter
import csv
import json
import math
import os
from pathlib import Path
import sys
import tempfile
import time

import numpy as np
import yaml

from .. import interface, subcommand
from ..atomic import write_text
from ..paths import config_path, node_parameters
from ..plc.register_log import RegisterLog
from ..graph.process_graph import (FILES, NODES, Graph, PlcInvariantError, Probe, sim_lab, start_nodes, start_task,
                                   wait_until)
from .graphs import cpu_s, fds, rss_mb, threads
from .soak_latency import LAND_TIMEOUT_S, LATENCY, PAIR_WAIT_S, LatencyMatcher
from .soak_report import harmful, number, plot, summary, verdicts
from .soak_watch import SoakWatch

HELP = ('the simulated lab graph guiding target after target for N minutes: latency, resources and '
        'losses per minute, a verdict on drift')

#: Processes whose resources each row reports: the graph's nodes, and this run's own (the observer).
OBSERVED = (*NODES, 'soak')


#: Cumulative counters of the nodes' /diagnostics a row reports as differences: column ->
#: (status name prefix, key). Lost: gaps in the wearer's sequence numbers (sent, never received,
#: or dropped as late before the sequence check); dropped: received and not published.
COUNTERS = dict(datagrams_received=('gaze_bridge:', 'received'), datagrams_lost=('gaze_bridge:', 'lost'),
                datagrams_dropped=('gaze_bridge:', 'dropped'), plc_watchdog_trips=('mock_plc:', 'watchdog trips'),
                plc_stale_writes=('mock_plc:', 'stale writes refused'))

#: Every column of soak.csv, in order.
COLUMNS = (['row', 't_start_s', 't_end_s', 'latency_p50_ms', 'latency_p99_ms', 'latency_max_ms', 'latency_samples',
            'command_p50_ms', 'command_p99_ms', 'command_max_ms', 'command_samples',
            'steps', 'steps_unseen', 'commands_changed', 'commands_not_landed', 'samples_unmatched',
            *COUNTERS, 'targets_reached', 'targets_skipped', 'time_to_target_s']
           + [f'{figure}.{node}' for figure in ('rss_mb', 'cpu_s_per_min', 'fds', 'threads') for node in OBSERVED]
           + ['warnings', 'stall'])

#: Figures the verdict fits: column (or prefix for one per node) -> unit (its floor's kind).
FIGURES = {'latency_p50_ms': 'ms', 'latency_p99_ms': 'ms', 'latency_max_ms': 'ms',
           'command_p50_ms': 'ms', 'command_p99_ms': 'ms', 'command_max_ms': 'ms',
           'rss_mb': 'MB', 'cpu_s_per_min': 's/min', 'fds': 'count', 'threads': 'count',
           'datagrams_lost': 'per row', 'datagrams_dropped': 'per row', 'commands_not_landed': 'per row',
           'steps_unseen': 'per row', 'targets_reached': 'per row', 'time_to_target_s': 's'}


def target_sequence(minutes: float) -> list[str]:
    """The four targets repeated for more than the run can reach (one a second at most)."""
    params = node_parameters('params/guidance.yaml', 'target_selector')
    names = [n for n in params.get('sequence') or [] if n] or list(params['target_names'])
    return names * (int(minutes * 60 / len(names)) + 2)


class Soak:
    """One run: the graph, its probe, the rows."""

    def __init__(self, out: Path, minutes: float, row_seconds: float, target_timeout_s: float, say):
        from ..plc import RegisterMap
        self.out, self.minutes, self.row_s, self.say = out, minutes, row_seconds, say
        self.target_timeout_s = target_timeout_s
        self.graph = Graph(out / 'logs')
        regmap = RegisterMap.load(config_path('hardware/plc_register_map.yaml'))
        self.matcher = LatencyMatcher(regmap.encode, (0,) * len(regmap))
        self.register_log = RegisterLog(out / 'register_log.jsonl')
        self.applied = None   # the latest entry of the register log
        self.probe = None
        self.watch = None
        self.rows: list[dict] = []
        self.skipped = 0
        self.csv_path = out / 'soak.csv'

    # ---- up
    def start(self, startup_timeout_s: float) -> None:
        lab = sim_lab(1, 'suit', self.out / 'calibrations')
        lab.overrides['mock_plc'].update(register_log_file=str(self.register_log.path))
        sequence = self.out / 'target_sequence.yaml'
        write_text(sequence, yaml.safe_dump({'/**/target_selector': {'ros__parameters': {
            'sequence': target_sequence(self.minutes)}}}))
        start_nodes(self.graph, lab, FILES, {'target_selector': (str(sequence),)})
        self.probe = Probe(self.graph.domain_id, 'soak_watch')
        self.watch = SoakWatch(self.probe, self.matcher)
        w = self.watch
        wait_until(lambda: self.check_alive() or (w.heard['gaze'] and w.heard['controller_input']
                                                  and w.heard['pressure_command'] and w.active is not None),
                   startup_timeout_s, what='gaze, control steps, commands and the task at the run')
        wait_until(lambda: self.check_alive() or w.value('gaze_bridge:', 'clock_state') == 'synchronised',
                   startup_timeout_s, what="gaze_bridge's estimate of the headset clock")
        start_task(self.probe, lambda: w.active)
        # End to end: a gaze sample's command applied at the PLC's registers.
        wait_until(lambda: self.check_alive() or self.poll() or self.matcher.latencies,
                   startup_timeout_s, what="a gaze sample's command at the PLC registers")
        # A row reports each counter as the difference from the row before: the first row needs
        # every counter's first value (mock_plc's /diagnostics come at their own, slower rate).
        wait_until(lambda: self.check_alive() or None not in self.counters().values(), startup_timeout_s,
                   what='a first value of every counter on /diagnostics: ' + ', '.join(
                       f'{prefix} {key}' for prefix, key in COUNTERS.values()))

    def check_alive(self) -> bool:
        dead = {n: p.returncode for n, p in self.graph.processes.items() if p.poll() is not None}
        if dead:
            raise RuntimeError(f'node(s) exited: {dead}; logs in {self.graph.log_dir}')
        return False

    def poll(self) -> bool:
        """Feed the register log's new lines to the matcher and match; False (for wait_until)."""
        log = self.register_log.poll()
        for e in log.entries:
            if e.cause == 'write':
                self.matcher.registers(int(round(e.t * 1e9)), e.counts)
        if log.entries:
            self.applied = log.entries[-1]
        log.entries.clear()   # handed to the matcher: the log's list would grow with the run
        drained = int(log.drained * 1e9) if math.isfinite(log.drained) else 0
        self.matcher.update(time.monotonic_ns(), drained)
        return False

    # ---- the operator
    def skip_if_stuck(self) -> None:
        """A target not found (or the front not reached) within target_timeout_s: next_target."""
        w = self.watch
        with w.lock:
            stuck = time.monotonic() - w.active_since > self.target_timeout_s
        if stuck:
            from std_srvs.srv import Trigger
            self.probe.send(Trigger, interface.NEXT_TARGET, Trigger.Request())
            with w.lock:
                w.active_since = time.monotonic()   # the request's outcome shows on active_target
            self.skipped += 1

    # ---- rows
    def resources(self) -> dict:
        pids = {n: p.pid for n, p in self.graph.processes.items()}
        pids['soak'] = os.getpid()
        return {n: (rss_mb(pid), cpu_s(pid), fds(pid), threads(pid)) for n, pid in pids.items()}

    def counters(self) -> dict:
        return {col: number(self.watch.value(prefix, key), None) for col, (prefix, key) in COUNTERS.items()}

    def run(self) -> None:
        """The rows until the time is up; each written and printed as it ends."""
        total_s = self.minutes * 60.0
        t0 = time.monotonic()
        self.matcher.take(time.monotonic_ns())            # the start-up's samples are not a row's
        self.watch.take()
        self.skipped = 0
        before, counters = self.resources(), self.counters()
        n_rows = max(1, math.ceil(total_s / self.row_s - 1e-9))
        with open(self.csv_path, 'w', newline='') as f:
            writer = csv.DictWriter(f, COLUMNS)
            writer.writeheader()
            _sync(f)
            for i in range(n_rows):
                start, end = t0 + i * self.row_s, t0 + min((i + 1) * self.row_s, total_s)
                while time.monotonic() < end:
                    self.check_alive()
                    self.poll()
                    self.skip_if_stuck()
                    time.sleep(0.1)
                after, now_counters = self.resources(), self.counters()
                skipped, self.skipped = self.skipped, 0
                found, warnings = self.watch.take()
                # The row's samples: wait until every command published before its end is settled.
                end_ns = int(end * 1e9)
                try:
                    wait_until(lambda: self.poll() or self.matcher.settled(end_ns), LAND_TIMEOUT_S + PAIR_WAIT_S + 2.0,
                               interval=0.05, what='the commands of the row')
                except AssertionError:
                    pass   # counted as not landed in the next row at the latest
                latencies, to_command, counts = self.matcher.take(end_ns)
                row = make_row(i + 1, start - t0, end - t0, latencies, to_command, counts, before, after,
                               counters, now_counters, found, skipped, warnings, self.target_timeout_s)
                before, counters = after, now_counters
                self.rows.append(row)
                writer.writerow(row)
                _sync(f)
                self.say(progress(row, n_rows))

    # ---- down
    def close(self) -> list[str]:
        """Everything down, the lab side first (the registers must read vented while the mock
        still runs); what went wrong on the way."""
        problems = []
        if self.probe is not None:
            self.probe.close()
        try:
            for node in reversed(NODES[1:]):
                if node in self.graph.processes:
                    self.graph.stop(node)
            stopped = time.monotonic()
            wait_until(lambda: self.poll() or self.register_log.drained > stopped, 10.0,
                       what="the mock PLC's register log after the lab nodes stopped")
            if self.applied is not None and not self.applied.vented:
                problems.append(f'the suit was not vented at shutdown: registers {list(self.applied.counts)}')
        except AssertionError as exc:
            problems.append(str(exc))
        try:
            self.graph.stop_all(check=True)
        except PlcInvariantError as exc:
            problems.append(str(exc))
        problems += [f'left behind: {line}' for line in self.graph.leftovers()]
        return problems


def _sync(f) -> None:
    f.flush()
    os.fsync(f.fileno())


def _delta(a, b):
    return None if a is None or b is None else b - a


def make_row(index: int, t_start: float, t_end: float, latencies_ns: list[int], to_command_ns: list[int],
             counts: Counter, before: dict, after: dict, counters: dict, now_counters: dict, found: list[float],
             skipped: int, warnings: Counter, target_timeout_s: float) -> dict:
    """One row of soak.csv from what was measured over it. Its stall column names what stopped:
    no target reached in a row long enough for one (target_timeout_s), a target skipped, no
    gaze sample at the registers."""
    row = {'row': index, 't_start_s': round(t_start, 3), 't_end_s': round(t_end, 3)}
    for name, values in (('latency', latencies_ns), ('command', to_command_ns)):
        ms = np.asarray(values, dtype=float) / 1e6
        for q in (50, 99):
            row[f'{name}_p{q}_ms'] = round(float(np.percentile(ms, q)), 3) if len(ms) else None
        row[f'{name}_max_ms'] = round(float(ms.max()), 3) if len(ms) else None
        row[f'{name}_samples'] = len(ms)
    row.update(steps=counts['steps'], steps_unseen=counts['steps_unseen'],
               commands_changed=counts['changed'], commands_not_landed=counts['not_landed'],
               samples_unmatched=counts['unmatched'])
    for col in COUNTERS:
        row[col] = _delta(counters.get(col), now_counters.get(col))
    row.update(targets_reached=len(found), targets_skipped=skipped,
               time_to_target_s=round(float(np.median(found)), 3) if found else None)
    minutes = max(t_end - t_start, 1e-9) / 60.0
    for node in OBSERVED:
        rss, cpu, fd, th = after.get(node, (None,) * 4)
        cpu0 = before.get(node, (None,) * 4)[1]
        row[f'rss_mb.{node}'] = None if rss is None else round(rss, 2)
        used = _delta(cpu0, cpu)
        row[f'cpu_s_per_min.{node}'] = None if used is None else round(used / minutes, 3)
        row[f'fds.{node}'], row[f'threads.{node}'] = fd, th
    row['warnings'] = '; '.join(f'{text} (x{n})' for text, n in warnings.most_common(3))
    stall = []
    if not found and t_end - t_start >= target_timeout_s:
        stall.append('no target reached')
    if skipped:
        stall.append(f'{skipped} target(s) skipped after {target_timeout_s:g} s')
    if not latencies_ns:
        stall.append('no gaze sample reached the registers')
    row['stall'] = '; '.join(stall)
    return row


def progress(row: dict, n_rows: int) -> str:
    def ms(v):
        return '-' if v is None else f'{v:.1f}'
    rss = {k.split('.', 1)[1]: v for k, v in row.items() if k.startswith('rss_mb.') and v is not None}
    top = max(rss, key=rss.get) if rss else None
    line = (f"[{row['row']}/{n_rows}] {row['t_end_s'] / 60:5.1f} min: latency p50 {ms(row['latency_p50_ms'])} "
            f"p99 {ms(row['latency_p99_ms'])} max {ms(row['latency_max_ms'])} ms ({row['latency_samples']} samples); "
            f"targets {row['targets_reached']} reached, {row['targets_skipped']} skipped; datagrams "
            f"{row['datagrams_received']} received, {row['datagrams_lost']} lost, {row['datagrams_dropped']} "
            f"dropped; commands not landed {row['commands_not_landed']}")
    if top is not None:
        line += f'; largest RSS {rss[top]:.0f} MB ({top})'
    if row['stall']:
        line += f"; STALL: {row['stall']}" + (f" [{row['warnings']}]" if row['warnings'] else '')
    return line


# ---------------------------------------------------------------- the command
def run_soak(minutes: float, out: Path, say, row_seconds: float = 60.0, target_timeout_s: float = 30.0,
             startup_timeout_s: float = 120.0) -> tuple[list[dict], dict, list[str]]:
    """The run; its rows, the verdict per figure and the problems met ([] when none). Writes
    soak.csv (as it goes), soak.md, soak.json and soak.png in `out`."""
    out = Path(out).resolve()   # the nodes run in the package's folder: their paths must not be relative
    out.mkdir(parents=True, exist_ok=True)
    soak = Soak(out, minutes, row_seconds, target_timeout_s, say)
    problems: list[str] = []
    t_start = time.monotonic()
    try:
        say(f'soak: {minutes:g} min in rows of {row_seconds:g} s on ROS_DOMAIN_ID {soak.graph.domain_id}; '
            f'logs in {out / "logs"}')
        soak.start(startup_timeout_s)
        say(f'soak: data flows end to end after {time.monotonic() - t_start:.1f} s; the clock starts')
        soak.run()
    except (RuntimeError, AssertionError) as exc:
        problems.append(str(exc))
        say(f'soak: stopped: {exc}')
    except KeyboardInterrupt:
        problems.append(f'interrupted after {len(soak.rows)} rows')
    finally:
        problems += soak.close()
    rows = soak.rows
    results = verdicts(rows, FIGURES, COLUMNS)
    args = {'minutes': minutes, 'row_seconds': row_seconds, 'target_timeout_s': target_timeout_s}
    write_text(out / 'soak.json', json.dumps({'args': args, 'latency': LATENCY, 'rows': rows, 'verdicts': results,
                                              'problems': problems}, indent=1) + '\n')
    write_text(out / 'soak.md', summary(rows, results, args, problems, LATENCY))
    if rows:
        plot(rows, out / 'soak.png', OBSERVED)
    return rows, results, problems


def above_zero(text: str) -> float:
    """An option's value: a finite number above 0."""
    value = float(text)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f'must be above 0, got {text}')
    return value


def configure(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    options = (('--minutes', 60.0, 'how long the clock runs'),
               ('--row-seconds', 60.0, 'one row of figures per this many seconds'),
               ('--target-timeout-s', 30.0, 'a target not found within this is skipped, as an operator would'),
               ('--startup-timeout-s', 120.0, 'how long the graph may take until data flows end to end'))
    for flag, default, text in options:
        parser.add_argument(flag, type=above_zero, default=default, help=f'{text} (default {default:g})')
    parser.add_argument('--out', default=None, help='folder for soak.csv, soak.md, soak.json, soak.png, the '
                        'register log and the node logs (default: a new temporary folder)')
    return parser


def add_parser(subparsers) -> argparse.ArgumentParser:
    return subcommand.add(subparsers, 'soak', HELP, __doc__, configure, run)


def run(args, stream=sys.stdout) -> int:
    """0 when every row was written, none stalled, nothing drifts and the run met no problem."""
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix='fabric-guidance-soak-'))
    say = subcommand.printer(stream)
    rows, results, problems = run_soak(args.minutes, out, say, args.row_seconds, args.target_timeout_s,
                                       args.startup_timeout_s)
    say('')
    say((out / 'soak.md').read_text())
    written = ['soak.csv', 'soak.md', 'soak.json'] + (['soak.png'] if rows else [])
    say('written: ' + ', '.join(str(out / name) for name in written))
    failed = problems or any(r['stall'] for r in rows) or any(harmful(c, v) for c, v in results.items())
    return 1 if failed or not rows else 0


if __name__ == '__main__':
    sys.exit(subcommand.main('python -m fabric_guidance.bench.soak', __doc__, configure, run))
