"""Live against headless: a simulated study's folder (`fabric-guidance study --simulated`) beside
the headless experiment on the same scene, seed and participants, with the simulation's own
seed-to-seed spread (the same study headless on other seeds) beside both. Speed adds mean_find_s
(target shown to its press), the phase a graph could lengthen.

python -m fabric_guidance.live_study.compare STUDY_DIR [--protocol speed] [--seeds 5] [--out TABLE.md]

Per condition and measure: the mean over participants of each participant's mean (as the
paper's tables), live and headless on the study's seed; the headless means on the study's seed
and the next seeds-1 seeds: their SD and range. The live study agrees with the headless one when
their difference is within that spread. Accuracy: the live error is the tracked gaze's (what
the graph sees), set beside the headless tracked error.
"""
from __future__ import annotations

import argparse
from pathlib import Path
import sys

import numpy as np
import yaml

from ..atomic import write_text
from ..sim.protocols import run_protocol, summarize
from ..sim.scene import scene_from_dict
from ..study.store import study_trials

MEASURES = {'speed': ('identified', 'presented', 'mean_find_s'),
            'accuracy': ('tracked_h_error_deg', 'tracked_v_error_deg', 'time_s')}


def condition_means(records, measure: str) -> dict[int, float]:
    return {c: row[measure] for c, row in summarize(records).items() if measure in row}


def _typed(row: dict) -> dict:
    """A trials file's text cells as numbers where they are."""
    out = {}
    for k, v in row.items():
        if v in ('', 'n/a'):
            out[k] = None
            continue
        for kind in (int, float):
            try:
                out[k] = kind(v)
                break
            except ValueError:
                continue
        else:
            out[k] = {'True': True, 'False': False}.get(v, v)
    return out


def _record(row: dict):
    from ..sim.protocols import TrialRecord
    from ..study.trial_columns import FILE_NAMES
    from dataclasses import fields
    return TrialRecord(**{f.name: row.get(FILE_NAMES.get(f.name, f.name)) for f in fields(TrialRecord)})


def compare(study: Path, seeds: int = 5, workers: int = 2, protocol: str = 'speed') -> str:
    scene_file = study / f'scene-{protocol}.yaml'
    data = yaml.safe_load(scene_file.read_text())
    rows = study_trials(study, protocol)
    n = len({r['subject_index'] for r in rows})
    live = [_record(_typed(r)) for r in rows]
    headless = {}
    for k in range(seeds):
        d = dict(data, seed=int(data['seed']) + k)
        scene = scene_from_dict(d, f'{scene_file} (seed {d["seed"]})')
        headless[d['seed']] = run_protocol(scene, n, workers)
    base = int(data['seed'])
    lines = [f'{protocol}: {n} participants, {data["repetitions"]} trials per condition'
             + (f', {data["protocol"]["trial_s"]:g} s trials' if protocol == 'speed' else '')
             + f'; live = the study through the graph on seed {base}; headless on seeds {base}-{base + seeds - 1}',
             '', '| condition | measure | live | headless, same seed | live - headless | headless seed SD '
             '| headless range over seeds |', '| --- | --- | --- | --- | --- | --- | --- |']
    for measure in MEASURES[protocol]:
        lv = condition_means(live, measure)
        per_seed = {s: condition_means(r, measure) for s, r in headless.items()}
        for c in sorted(lv):
            values = np.array([per_seed[s][c] for s in per_seed if c in per_seed[s]])
            same = per_seed[base].get(c, float('nan'))
            lines.append(f'| {c} | {measure} | {lv[c]:.2f} | {same:.2f} | {lv[c] - same:+.2f} | '
                         f'{values.std(ddof=1):.2f} | {values.min():.2f} - {values.max():.2f} |')
    return '\n'.join(lines) + '\n'


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog='python -m fabric_guidance.live_study.compare', description=__doc__.split('\n')[0])
    p.add_argument('study', type=Path)
    p.add_argument('--protocol', choices=sorted(MEASURES), default='speed')
    p.add_argument('--seeds', type=int, default=5)
    p.add_argument('--out', type=Path, default=None)
    args = p.parse_args(argv)
    table = compare(args.study, args.seeds, protocol=args.protocol)
    print(table)
    if args.out is not None:
        write_text(args.out, table)
    return 0


if __name__ == '__main__':
    sys.exit(main())
