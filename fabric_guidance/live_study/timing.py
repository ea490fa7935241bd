"""The study's timing on the simulated graph, the figures `fabric-guidance bench` reports beside
the loop's: a key press from its source's stamp to its recorded error as the session judges it
(wearer_sim's presses through the headset uplink, and the operator's keyboard), a trial timer's
error against its length, and the time a condition switch takes (to or from condition 3: the arm
layout), on the study package's Session driven on the graph.

The keyboard's presses are part of the timing run: during the speed trials a thread presses the
operator's key (Operator.press_key, frame_id 'keyboard', stamped on the PC clock) at random
intervals (KEY_INTERVAL_S, a seeded generator) while a target is shown, and the Session judges
them like any press (accepted within acceptance, refused otherwise: either way the press's
latency is its judgement's), beside wearer_sim's. They change what the trials identify: this run
is a measurement, not a study.

python -m fabric_guidance.live_study.timing --out FILE.json [--trial-s 40] [--keys 50] [--seed 0]
(bench runs it as a process: live_study and bench share a layer in the layers).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
import sys
import tempfile
import threading

import numpy as np
import yaml

from ..atomic import write_text
from ..sim.scene import load_scene, scene_path
from ..study.plan import participant_blocks
from ..study.session import Session
from .driver import SessionDriver
from .session_graph import VENT_GRACE_NS
from .simulated import SimulatedParticipant, design_of

#: The keyboard's presses during a trial: one every uniform(*KEY_INTERVAL_S) seconds [s].
KEY_INTERVAL_S = (0.2, 0.6)


def percentiles_ms(values_s) -> dict:
    v = np.asarray(values_s, dtype=float) * 1e3
    if not v.size:
        return {'n': 0}
    return {'n': int(v.size), 'p50': float(np.percentile(v, 50)), 'p99': float(np.percentile(v, 99)),
            'max': float(v.max())}


def press_keys(op, driver, keys: int, seed: int, stop: threading.Event) -> dict:
    """Press the operator's key up to `keys` times, at random intervals (KEY_INTERVAL_S, from
    `seed`) while the driver's session shows a target, until `stop`: {'sent': presses so far,
    'thread': the pressing thread}. Reads the session's phase only (the driver's loop alone
    changes the Session)."""
    rng = np.random.default_rng(seed)
    sent: dict = {'sent': 0}

    def run():
        while sent['sent'] < keys and not stop.wait(float(rng.uniform(*KEY_INTERVAL_S))):
            if driver.session.phase == 'target':
                op.press_key('keyboard')
                sent['sent'] += 1
    sent['thread'] = threading.Thread(target=run, name='timing-keyboard', daemon=True)
    sent['thread'].start()
    return sent


def measure(work: Path, trial_s: float = 40.0, keys: int = 50, say=print, seed: int = 0) -> dict:
    """A session of one participant (conditions 1 then 3, one speed trial each) on the simulated
    graph without the scene's modelled tracker latency (datagram_latency: the figure is the
    graph's) at 90 Hz gaze, wearer_sim pressing through the headset uplink and up to `keys`
    presses of the operator's keyboard among them (press_keys)."""
    from ..study.store import Study
    data = yaml.safe_load(scene_path('paper-speed').read_text())
    data.update(conditions=[1, 3], repetitions=1, sim_rate_hz=90.0)
    data['protocol']['trial_s'] = float(trial_s)
    data['effects'] = [e for e in data['effects'] if 'datagram_latency' not in e]
    work.mkdir(parents=True, exist_ok=True)
    (work / 'scene.yaml').write_text(yaml.safe_dump(data, sort_keys=False))
    scene = load_scene(work / 'scene.yaml')
    study = Study.open(work / 'study')
    design = design_of(scene)
    blocks = participant_blocks(design, '01', 0)
    study.add_participant('01')
    store = study.session('01', 1, design)
    part = SimulatedParticipant(scene, 0, blocks[0].condition, work / 'graph', say, design)
    stop = threading.Event()
    try:
        part.start()
        op = part.op
        say(f'  conditions {[b.condition for b in blocks]}, a {trial_s:g} s speed trial each (wearer_sim pressing, '
            f'and up to {keys} presses of the keyboard) ...')

        def set_condition(cond):
            if cond != part.condition:
                part.switch(cond)
        driver = SessionDriver(op, Session(design, blocks, {'gaze_source': 'wearer_sim'}), store, say, set_condition,
                               lambda c, r: op.set_parameters('wearer_sim', condition=c, repetition=r))
        sent = press_keys(op, driver, keys, seed, stop)
        driver.run()
        stop.set()
        vented = [part.op.commands_between(a + VENT_GRACE_NS, b) for a, b in driver.timing.vented]
    finally:
        stop.set()
        part.close()
    t = driver.timing
    by_source = t.press_latency_by_source()
    keyboard = by_source.pop('keyboard', [])
    judged = [e for e in t.events if e[0] == 'press']
    return {
        'press_to_error_ms': percentiles_ms([x for v in by_source.values() for x in v]),
        'press_sources': sorted(by_source),
        'keyboard_to_error_ms': percentiles_ms(keyboard),
        'keyboard_presses': {'sent': sent['sent'], 'judged': len(keyboard),
                             'accepted': sum(1 for e, s in zip(judged, t.press_sources) if s == 'keyboard' and e[3])},
        'gaze_age_ms': percentiles_ms(t.gaze_age_s),
        'gaze_rate_hz': 90.0,
        'trial_s': trial_s,
        'timer_error_ms': [e * 1e3 for e in t.timer_error_s],
        'condition_switch': [{'condition': c, 's': s, 'how': how} for c, s, how in part.timing.switch_s],
        'commands_between_trials': {'checked': sum(len(v) for v in vented),
                                    'above_0_kpa': sum(1 for v in vented for x in v if x > 0.0)},
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog='python -m fabric_guidance.live_study.timing', description=__doc__.split('\n')[0])
    p.add_argument('--out', type=Path, required=True)
    p.add_argument('--trial-s', type=float, default=40.0)
    p.add_argument('--keys', type=int, default=50, help="the most presses of the operator's keyboard in the trials")
    p.add_argument('--seed', type=int, default=0, help="the keyboard's intervals")
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix='study-timing-') as work:
        figures = measure(Path(work), args.trial_s, args.keys, lambda s: print(s, flush=True), args.seed)
    write_text(args.out, json.dumps(figures, indent=1))
    print(json.dumps(figures))
    return 0


if __name__ == '__main__':
    sys.exit(main())
