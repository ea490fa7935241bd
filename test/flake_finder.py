"""The flake finder (`make flakes`): the graph and timing-sensitive tests run several times, as
`make test` runs them (two pytest-xdist workers, whole files to a worker) but with added CPU load
on the machine, and each test's pass rate over the runs. A test that fails in any run fails by
chance on a loaded machine, which is how CI's machine is loaded: fix its cause (a deadline that
ignores what load adds, a judge that misreads a legitimate order of events, a race in start-up),
never with a retry or a longer sleep.

    python test/flake_finder.py [--runs N] [--load K] [--out DIR] [-- PYTEST ARGS...]

The load is K busy processes of its own at normal priority (default: one per core), started
before each run and stopped after it. Each run writes DIR/run-N/junit.xml and its pytest output;
a run with a failure keeps its pytest temporary folder (the graph tests' node logs, register
logs, bags) as DIR/run-N/tmp, a clean run's is removed. The table (test, runs, passes, failures,
the first failure's message) is printed and written to DIR/flakes.md and DIR/flakes.json. Exit
status 1 when any test failed in any run.
"""
from __future__ import annotations

import argparse
import json
import multiprocessing
import os
from pathlib import Path
import shutil
import subprocess
import sys
import time
import xml.etree.ElementTree as ET

ROOT = Path(__file__).resolve().parent.parent
#: What runs by default: every test that starts a process graph, and the others marked as waiting
#: on processes, sockets or the clock (pytest.ini's markers).
DEFAULT_SELECTION = ['-m', 'graph or serial or timing', 'test/']


def _spin() -> None:
    while True:
        pass


def start_load(k: int) -> list[multiprocessing.Process]:
    procs = [multiprocessing.Process(target=_spin, daemon=True) for _ in range(k)]
    for p in procs:
        p.start()
    return procs


def stop_load(procs: list[multiprocessing.Process]) -> None:
    for p in procs:
        p.terminate()
    for p in procs:
        p.join(timeout=10)


def outcomes(junit: Path) -> dict[str, tuple[str, str]]:
    """test id -> (passed | failed | error | skipped, first line of the message)."""
    found = {}
    if not junit.exists():
        return found
    for case in ET.parse(junit).getroot().iter('testcase'):
        name = f"{case.get('classname', '')}::{case.get('name')}"
        status, message = 'passed', ''
        for child in case:
            if child.tag in ('failure', 'error', 'skipped'):
                status = {'failure': 'failed'}.get(child.tag, child.tag)
                message = (child.get('message') or '').strip().splitlines()[0:1]
                message = message[0][:160] if message else ''
                break
        if status == 'error' and name in found:   # a teardown error after the call's outcome
            name += ' (teardown)'
        found[name] = (status, message)
    return found


def run_once(index: int, out: Path, load: int, pytest_args: list[str], workers: int) -> dict:
    folder = out / f'run-{index}'
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    junit, tmp = folder / 'junit.xml', folder / 'tmp'
    cmd = [sys.executable, '-m', 'pytest', '-n', str(workers), '--dist', 'loadfile', '-p', 'no:cacheprovider',
           '-q', '--junitxml', str(junit), '--basetemp', str(tmp), *pytest_args]
    if workers == 0:
        cmd[3:7] = []
    procs = start_load(load)
    t0 = time.monotonic()
    try:
        with open(folder / 'pytest.log', 'w') as log:
            rc = subprocess.call(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, env=dict(os.environ, CI='true'))
    finally:
        stop_load(procs)
    results = outcomes(junit)
    failed = any(s in ('failed', 'error') for s, _ in results.values()) or rc not in (0, 5)
    if not failed:
        shutil.rmtree(tmp, ignore_errors=True)
    return {'run': index, 'rc': rc, 'seconds': round(time.monotonic() - t0, 1), 'load_1min': os.getloadavg()[0],
            'results': results}


def table(runs: list[dict]) -> list[dict]:
    rows: dict[str, dict] = {}
    for r in runs:
        for test, (status, message) in r['results'].items():
            row = rows.setdefault(test, {'test': test, 'runs': 0, 'passes': 0, 'failures': 0, 'skips': 0,
                                         'first_failure': '', 'failed_in': []})
            row['runs'] += 1
            if status == 'passed':
                row['passes'] += 1
            elif status == 'skipped':
                row['skips'] += 1
            else:
                row['failures'] += 1
                row['failed_in'].append(r['run'])
                row['first_failure'] = row['first_failure'] or message
    return sorted(rows.values(), key=lambda row: (-row['failures'], row['test']))


def markdown(rows: list[dict], runs: list[dict], load: int, every_test: bool = True) -> str:
    """The table: the tests that failed in a run first, then (every_test) all the others."""
    ran = [row for row in rows if row['runs'] > row['skips']]
    flaky = [row for row in ran if row['failures']]
    lines = [f"{len(runs)} runs under {load} busy processes on {os.cpu_count()} cores: "
             + ', '.join(f"run {r['run']} {r['seconds']:.0f} s (exit {r['rc']})" for r in runs), '',
             f'{len(ran)} tests ran, {len(flaky)} failed at least once.', '',
             '| test | runs | passes | failures | failed in runs | first failure |',
             '| --- | --- | --- | --- | --- | --- |']
    for row in (ran if every_test else flaky):
        lines.append(f"| {row['test']} | {row['runs'] - row['skips']} | {row['passes']} | {row['failures']} | "
                     f"{', '.join(map(str, row['failed_in']))} | {row['first_failure'].replace('|', '/')} |")
    if not every_test:
        lines.append(f"| all others ({len(ran) - len(flaky)} tests) | {len(runs)} each | every run | 0 | | |")
    passes = sum(row['passes'] for row in ran)
    executions = sum(row['runs'] - row['skips'] for row in ran)
    lines += ['', f'{passes} passes of {executions} test runs.']
    return '\n'.join(lines) + '\n'


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    pytest_args = []
    if '--' in argv:
        at = argv.index('--')
        argv, pytest_args = argv[:at], argv[at + 1:]
    ap = argparse.ArgumentParser(prog='python test/flake_finder.py', description=__doc__.split('\n\n')[0])
    ap.add_argument('--runs', type=int, default=3, help='how many times to run the selection (default 3)')
    ap.add_argument('--load', type=int, default=os.cpu_count() or 2,
                    help='busy processes beside each run (default: one per core)')
    ap.add_argument('--workers', type=int, default=2, help='pytest-xdist workers, as make test (default 2)')
    ap.add_argument('--out', type=Path, default=ROOT / 'flakes', help='where runs and the table go (default flakes/)')
    args = ap.parse_args(argv)
    if args.runs < 1 or args.load < 0:
        ap.error('--runs must be at least 1 and --load at least 0')
    selection = pytest_args or DEFAULT_SELECTION
    args.out.mkdir(parents=True, exist_ok=True)
    runs = []
    for i in range(1, args.runs + 1):
        print(f'flake finder: run {i} of {args.runs} under {args.load} busy processes: pytest {" ".join(selection)}',
              flush=True)
        r = run_once(i, args.out, args.load, selection, args.workers)
        bad = sorted(t for t, (s, _) in r['results'].items() if s in ('failed', 'error'))
        print(f"  {len(r['results'])} tests in {r['seconds']:.0f} s, exit {r['rc']}; "
              f"failed: {', '.join(bad) or 'none'}", flush=True)
        runs.append(r)
    rows = table(runs)
    (args.out / 'flakes.md').write_text(markdown(rows, runs, args.load))
    (args.out / 'flakes.json').write_text(json.dumps({'runs': [{k: v for k, v in r.items() if k != 'results'}
                                                               for r in runs], 'tests': rows}, indent=1))
    print(markdown(rows, runs, args.load, every_test=False)
          + f'(every test in {args.out}/flakes.md; logs of failed runs in {args.out}/run-N/)')
    return 1 if any(row['failures'] for row in rows) or any(r['rc'] not in (0, 5) for r in runs) else 0


if __name__ == '__main__':
    sys.exit(main())
