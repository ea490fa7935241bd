"""The simulated study from participant to study folder: participants in turn, each block of
their condition order, every trial written as it ends.

The folder (BIDS-like): participants.tsv; sub-<NN>/ses-01/sub-<NN>_ses-01_task-<protocol>_trials.tsv
(one row per trial: the columns of sim.protocols.TrialRecord, so the headless tools read it,
then the live ones) with its JSON sidecar; timing.json (the session's timing); one table per
measure, subjects x conditions, for `fabric-guidance analyze`. A trials file is rewritten
atomically after every trial: a kill keeps every finished trial; a run on the same folder keeps
the finished blocks, drops the trials of a block cut short (it says how many) and redoes it.
"""
from __future__ import annotations

import csv
from dataclasses import fields
import io
import json
import math
from pathlib import Path
import statistics
import time
from typing import Callable

from ..atomic import write_text
from ..sim.protocols import CONDITION_NAMES, MEASURES, TrialRecord, format_summary, ProtocolResults
from .simulated import SimulatedParticipant, design_of, participant_order

RECORD_FIELDS = [f.name for f in fields(TrialRecord)]
LIVE_FIELDS = ['presses', 'presses_refused', 'press_error_deg', 'press_source', 'trial_wall_s', 'calibration_file']


def participant_id(subject: int) -> str:
    return f'{subject + 1:02d}'


def trials_path(out: Path, subject: int, protocol: str) -> Path:
    sid = participant_id(subject)
    return out / f'sub-{sid}' / 'ses-01' / f'sub-{sid}_ses-01_task-{protocol}_trials.tsv'


def _value(text: str):
    if text in ('', 'n/a'):
        return None
    if text in ('True', 'False'):
        return text == 'True'
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def load_rows(path: Path) -> list[dict]:
    if not path.exists():
        return []
    with path.open(newline='') as f:
        return [{k: _value(v) for k, v in row.items()} for row in csv.DictReader(f, delimiter='\t')]


def save_rows(path: Path, rows: list[dict]) -> None:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, RECORD_FIELDS + LIVE_FIELDS, delimiter='\t', lineterminator='\n')
    writer.writeheader()
    for row in rows:
        writer.writerow({k: ('n/a' if row.get(k) is None or (isinstance(row.get(k), float) and math.isnan(row[k]))
                             else row[k]) for k in RECORD_FIELDS + LIVE_FIELDS})
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, buf.getvalue())


def finished_blocks(rows: list[dict], repetitions: int) -> tuple[list[dict], int]:
    """The rows of complete blocks (every repetition of a condition) and how many rows of an
    incomplete one were dropped."""
    counts: dict[int, int] = {}
    for r in rows:
        counts[r['condition']] = counts.get(r['condition'], 0) + 1
    kept = [r for r in rows if counts[r['condition']] >= repetitions]
    return kept, len(rows) - len(kept)


def run_study(scene, participants: int, out: Path, say: Callable[[str], None], order: str = 'random') -> int:
    protocol = scene.protocol.kind
    design = design_of(scene, order)
    reps = scene.repetitions
    out.mkdir(parents=True, exist_ok=True)
    write_text(out / 'participants.tsv', 'participant_id\twearer_index\tcondition_order\n' + ''.join(
        f'sub-{participant_id(i)}\t{i}\t{",".join(map(str, participant_order(design, i)))}\n'
        for i in range(participants)))
    timing = {'press_latency_s': [], 'timer_error_s': [], 'switch_s': [], 'vented_commands': 0,
              'vented_checked': 0}
    say(f'study: {protocol} protocol on the simulated graph, scene {scene.name} (seed {scene.seed}), '
        f'{participants} participants, {reps} trials per condition; folder {out}')
    for subject in range(participants):
        path = trials_path(out, subject, protocol)
        order = participant_order(design, subject)
        rows, dropped = finished_blocks(load_rows(path), reps)
        done = {r['condition'] for r in rows}
        if dropped or rows:
            say(f'sub-{participant_id(subject)}: resuming; {len(done)} finished blocks kept'
                + (f', {dropped} trials of an unfinished block dropped (the block is redone)' if dropped else ''))
            save_rows(path, rows)
        pending = [c for c in order if c not in done]
        if not pending:
            continue
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text(path.with_suffix('.json'), json.dumps({
            'TaskName': protocol, 'scene': scene.name, 'seed': scene.seed, 'repetitions': reps,
            'protocol': {k: getattr(scene.protocol, k) for k in vars(scene.protocol)},
            'condition_order': list(order), 'design': design.as_dict()}, indent=2, default=str))
        part = SimulatedParticipant(scene, subject, pending[0], out / 'logs' / f'sub-{participant_id(subject)}', say,
                                    design)
        try:
            part.start()
            for index, cond in enumerate(order, start=1):
                if cond in done:
                    continue
                if cond != part.condition:
                    part.switch(cond)
                for rep in range(reps):
                    t0 = time.monotonic()
                    measures = part.run_trial(rep)
                    row = dict(scene=scene.name, protocol=protocol, subject=subject,
                               wearer=f'S{subject + 1:02d}', condition=cond, repetition=rep, order=index,
                               trial_wall_s=round(time.monotonic() - t0, 3),
                               calibration_file=part.calibration_file.name, **measures)
                    rows.append(row)
                    save_rows(path, rows)
                    say(f'  sub-{participant_id(subject)} condition {cond} trial {rep + 1}/{reps}: ' + (
                        f"identified {row['identified']} of {row['presented']}" if protocol == 'speed' else
                        f"error h {row['h_error_deg']:.1f} v {row['v_error_deg']:.1f} deg in {row['time_s']:.1f} s"))
            part.done()
        finally:
            part.close()
        t = part.timing
        timing['press_latency_s'] += t.press_latency_s
        timing['timer_error_s'] += t.timer_error_s
        timing['switch_s'] += t.switch_s
        timing['vented_commands'] += t.vented_commands
        timing['vented_checked'] += t.vented_checked
    write_text(out / 'timing.json', json.dumps(timing, indent=1))
    records = [TrialRecord(**{k: r.get(k) for k in RECORD_FIELDS})
               for i in range(participants) for r in load_rows(trials_path(out, i, protocol))]
    write_tables(out, records, protocol)
    say(format_summary(scene, ProtocolResults(records)))
    say(timing_line(timing))
    return 0


def write_tables(out: Path, records: list[TrialRecord], protocol: str) -> None:
    """Per measure: subjects x conditions (each subject's mean), the table `analyze` reads."""
    conds = sorted({r.condition for r in records})
    for measure in MEASURES[protocol]:
        lines = ['subject,' + ','.join(CONDITION_NAMES[c] for c in conds)]
        for subject in sorted({r.subject for r in records}):
            vals = []
            for c in conds:
                xs = [getattr(r, measure) for r in records if r.subject == subject and r.condition == c
                      and getattr(r, measure) is not None]
                vals.append(f'{statistics.fmean(xs):.4f}' if xs else '')
            lines.append(f'sub-{participant_id(subject)},' + ','.join(vals))
        write_text(out / f'table_{measure}.csv', '\n'.join(lines) + '\n')


def timing_line(timing: dict) -> str:
    import numpy as np
    lat = np.asarray(timing['press_latency_s']) * 1e3
    parts = []
    if lat.size:
        parts.append(f'key press to recorded error p50 {np.percentile(lat, 50):.2f} ms, p99 '
                     f'{np.percentile(lat, 99):.2f} ms ({lat.size} presses)')
    if timing['timer_error_s']:
        err = np.abs(timing['timer_error_s']) * 1e3
        parts.append(f'trial timer error max {err.max():.2f} ms')
    if timing['switch_s']:
        parts.append('condition switch ' + ', '.join(f'{s:.2f} s ({how})' for _, s, how in timing['switch_s']))
    parts.append(f"{timing['vented_commands']} of {timing['vented_checked']} commands between trials above 0 kPa")
    return 'timing: ' + '; '.join(parts)
