"""The study's timing on the simulated graph, the figures `fabric-guidance bench` reports beside
the loop's: a key press from its source's stamp to its recorded error (wearer_sim's presses
during speed trials and the operator's keyboard), a trial timer's error against its length,
and the time a condition switch takes (conditions 1 -> 3: the arm layout).

python -m fabric_guidance.live_study.timing --out FILE.json [--trial-s 40] [--keys 50]
(bench runs it as a process: live_study and bench share a layer in the layers).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
import sys
import tempfile
import time

import numpy as np
import yaml

from ..atomic import write_text
from ..sim.scene import load_scene, scene_path
from .simulated import SimulatedParticipant


def percentiles_ms(values_s) -> dict:
    v = np.asarray(values_s, dtype=float) * 1e3
    if not v.size:
        return {'n': 0}
    return {'n': int(v.size), 'p50': float(np.percentile(v, 50)), 'p99': float(np.percentile(v, 99)),
            'max': float(v.max())}


def measure(work: Path, trial_s: float = 40.0, keys: int = 50, say=print) -> dict:
    data = yaml.safe_load(scene_path('paper-speed').read_text())
    data.update(conditions=[1, 3], repetitions=1)
    data['protocol']['trial_s'] = float(trial_s)
    work.mkdir(parents=True, exist_ok=True)
    (work / 'scene.yaml').write_text(yaml.safe_dump(data, sort_keys=False))
    scene = load_scene(work / 'scene.yaml')
    part = SimulatedParticipant(scene, 0, 1, work / 'graph', say)
    keyboard = []
    try:
        part.start()
        say(f'  a {trial_s:g} s speed trial under condition 1 (wearer_sim pressing confirm) ...')
        part.run_trial(0)
        say(f'  {keys} key presses at the operator\'s keyboard ...')
        op = part.op
        op.drain_presses()
        for _ in range(keys):
            op.press_key('keyboard')
            press = op.next_press(2.0)
            if press is None:
                continue
            op.settled_error_at(press.stamp_ns, None)
            keyboard.append((op.now_ns() - press.stamp_ns) * 1e-9)
            time.sleep(0.02)
        say('  switching to condition 3 (the arm) ...')
        part.switch(3)
        part.run_trial(0)
    finally:
        part.close()
    t = part.timing
    return {
        'press_to_error_ms': percentiles_ms(t.press_latency_s),
        'keyboard_to_error_ms': percentiles_ms(keyboard),
        'trial_s': trial_s,
        'timer_error_ms': [e * 1e3 for e in t.timer_error_s],
        'condition_switch': [{'condition': c, 's': s, 'how': how} for c, s, how in t.switch_s],
        'commands_between_trials': {'checked': t.vented_checked, 'above_0_kpa': t.vented_commands},
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog='python -m fabric_guidance.live_study.timing', description=__doc__.split('\n')[0])
    p.add_argument('--out', type=Path, required=True)
    p.add_argument('--trial-s', type=float, default=40.0)
    p.add_argument('--keys', type=int, default=50)
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix='study-timing-') as work:
        figures = measure(Path(work), args.trial_s, args.keys, lambda s: print(s, flush=True))
    write_text(args.out, json.dumps(figures, indent=1))
    print(json.dumps(figures))
    return 0


if __name__ == '__main__':
    sys.exit(main())
