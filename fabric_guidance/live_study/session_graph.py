"""The simulated study with the study package's Session and study folder: per participant a
simulated graph (simulated.SimulatedParticipant), the Session over the blocks the folder has
not finished (store.SessionStore.remaining), driven on the graph (driver.SessionDriver), every
finished trial written at once (store.SessionStore.record). `fabric-guidance analyze DIR` reads
the folder.
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path
import subprocess
from typing import Callable

import numpy as np

from ..atomic import write_text
from ..study.plan import participant_blocks
from ..study.events import RecordedSession
from ..study.session import Session
from ..study.store import Study, StudyError
from .block_bag import BlockBags
from .driver import SessionDriver, target_phases
from .simulated import SimulatedParticipant, Timing, design_of

#: A command already on its way when the vent was acknowledged is not counted [ns].
VENT_GRACE_NS = 50_000_000


def participant_label(subject: int) -> str:
    return f'{subject + 1:02d}'


def _commit() -> str:
    try:
        return subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], capture_output=True, text=True, timeout=5,
                              cwd=Path(__file__).resolve().parent).stdout.strip() or '-'
    except (OSError, subprocess.SubprocessError):
        return '-'


def run_participant(scene, design, study: Study, subject: int, say, timing: dict) -> list[dict]:
    pid = participant_label(subject)
    p = study.add_participant(pid)
    if p.index != subject:
        raise StudyError(f'{study.root / "participants.tsv"}: participant {pid} was registered with index {p.index}, '
                         f'not {subject}: the simulated participants are registered in order (use a new --out)')
    store = study.session(pid, 1, design)
    if store.lost is not None:
        say(f'sub-{pid}: {store.lost.line()}')
    blocks = store.remaining(participant_blocks(design, pid, subject))
    if not blocks:
        return []
    # The graph's logs and calibration are source data (BIDS: sourcedata/, which BIDS tools pass over).
    logs = study.root / 'sourcedata' / 'logs' / f'sub-{pid}'
    part = SimulatedParticipant(scene, subject, blocks[0].condition, logs, say, design)
    try:
        part.start()
        cal = part.calibration_file
        context = {'gaze_source': 'wearer_sim', 'clock_state': 'synced', 'calibration_file': cal.name,
                   'calibration_sha256': hashlib.sha256(cal.read_bytes()).hexdigest(), 'git_commit': _commit(),
                   'scene': scene.name}
        bags = BlockBags(part.op, store, say=say)
        session = RecordedSession(Session(design, blocks, context), bags)     # its events per run

        def set_condition(cond: int) -> None:
            if cond != part.condition:
                part.switch(cond)
            bags.begin(session.block)     # after a switch: the recorder hears the restarted nodes

        def before_trial(cond: int, repetition: int) -> None:
            part.check_nodes()
            part.op.set_parameters('wearer_sim', condition=cond, repetition=repetition)
        driver = SessionDriver(part.op, session, bags, say, set_condition, before_trial)
        try:
            rows = driver.run()
        finally:
            bags.close()
        t = driver.timing
        timing['press_latency_s'] += t.press_latency_s
        timing['timer_error_s'] += t.timer_error_s
        timing['switch_s'] += part.timing.switch_s
        for k, v in target_phases(t.events).items():
            timing['phases_s'].setdefault(k, []).extend(v)
        for start, end in t.vented:
            values = part.op.commands_between(start + VENT_GRACE_NS, end)
            timing['vented_checked'] += len(values)
            timing['vented_commands'] += sum(1 for v in values if v > 0.0)
        return rows
    finally:
        part.close()


def duration_line(design, participants: int) -> str:
    """What the run will take, said before it starts (the default study is about 1.5 h): the
    clock's part of it (a speed trial's length, every rest), the rest depends on the wearers."""
    n = participants * len(design.conditions) * design.trials
    if design.protocol == 'speed':
        minutes = n * (design.trial_s + design.rest_s) / 60.0
        what = (f'at least {minutes:.0f} min: {participants} participants x {len(design.conditions)} conditions x '
                f'{design.trials} trials x ({design.trial_s:g} s + {design.rest_s:g} s rest)')
    else:
        minutes = n * (design.timeout_s + design.rest_s) / 60.0
        what = (f'at most about {minutes:.0f} min: {n} trials of up to {design.timeout_s:g} s, '
                f'{design.rest_s:g} s rest each')
    options = '--participants, --trials and --trial-s' if design.protocol == 'speed' else '--participants and --trials'
    return (f'study: {what}, and a calibration per participant; {options} shorten it, Ctrl-C stops it and the '
            'same command resumes')


def run_study_session(scene, participants: int, out: Path, say: Callable[[str], None],
                      order: str = 'random', press_sources: tuple[str, ...] = ()) -> int:
    design = design_of(scene, order, press_sources)
    study = Study.open(out, name=f'{scene.name} simulated')
    timing = {'press_latency_s': [], 'timer_error_s': [], 'switch_s': [], 'phases_s': {}, 'vented_commands': 0,
              'vented_checked': 0}
    say(f'study: {design.protocol} protocol on the simulated graph, scene {scene.name} (seed {scene.seed}), '
        f'{participants} participants, {design.trials} trials per condition; folder {out}')
    say(duration_line(design, participants))
    for subject in range(participants):
        run_participant(scene, design, study, subject, say, timing)
    write_text(out / f'timing-{design.protocol}.json', json.dumps(timing, indent=1))
    say(timing_line(timing))
    say(f'analysis: fabric-guidance analyze {out}')
    return 0


def timing_line(timing: dict) -> str:
    lat = np.asarray(timing['press_latency_s']) * 1e3
    parts = []
    if lat.size:
        parts.append(f'key press to recorded error p50 {np.percentile(lat, 50):.2f} ms, p99 '
                     f'{np.percentile(lat, 99):.2f} ms ({lat.size} presses)')
    if timing['timer_error_s']:
        parts.append(f"trial timer error max {np.abs(timing['timer_error_s']).max() * 1e3:.2f} ms")
    if timing['switch_s']:
        parts.append('condition switch ' + ', '.join(f'{s:.2f} s ({how})' for _, s, how in timing['switch_s']))
    phases = {k: v for k, v in timing.get('phases_s', {}).items() if v}
    if phases:
        parts.append('per found target, mean s: ' + ', '.join(f'{k} {np.mean(v):.3f}' for k, v in phases.items()))
    parts.append(f"{timing['vented_commands']} of {timing['vented_checked']} commands between trials above 0 kPa")
    return 'timing: ' + '; '.join(parts)


__all__ = ['Timing', 'run_study_session', 'timing_line']
