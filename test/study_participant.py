"""A scripted participant for the study tests: drives a study Session on a fake steady clock
(gaze at 90 Hz), looks at the shown target after a reaction time, presses once on it, looks back
at the front when the target returns there. Also runs as a script (the kill test's child):
python study_participant.py STUDY_DIR PARTICIPANT_ID PROTOCOL TRIALS TRIAL_S writes each finished
trial as it goes; with STUDY_HANG_AFTER=N it stops still after its N-th trial is written (for a
test to kill it there).
"""
from __future__ import annotations

import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fabric_guidance.study.plan import StudyDesign, participant_blocks  # noqa: E402
from fabric_guidance.study.events import RecordedSession  # noqa: E402
from fabric_guidance.study.session import Session  # noqa: E402

FRAME_S = 1.0 / 90.0


def drive(session: Session, t0: float = 100.0, reaction_s: float = 0.6, miss_deg: float = 0.0,
          latency_s: float = 0.004, on_step=None, limit_s: float = 20000.0) -> list[dict]:
    """Run the session to its end on a fake clock; every Step goes to on_step(step) (default:
    collected). Returns the rows in order."""
    rows = []

    def take(step):
        rows.extend(step.rows)
        if on_step is not None:
            on_step(step)

    take(session.start(t0))
    t, k, shown_at, pressed = t0, 0, None, False
    looking = (0.0, 0.0)
    while session.phase not in ('done', 'stopped') and t < t0 + limit_s:
        k += 1
        t = t0 + k * FRAME_S
        take(session.tick(t))
        tr = session._trial
        if session.phase == 'target' and tr is not None:
            if shown_at != tr['appeared']:
                shown_at, pressed = tr['appeared'], False
            if t - shown_at >= reaction_s:
                looking = (tr['target'][0] + miss_deg, tr['target'][1])
        else:
            looking = (0.0, 0.0)
        take(session.gaze(t, *looking))
        if session.phase == 'target' and not pressed and t - shown_at >= reaction_s + 0.1:
            pressed = True
            take(session.press(t - 0.002, t + latency_s))
    return rows


def main(argv):
    from fabric_guidance.study.store import Study
    root, pid, protocol, trials, trial_s = argv[0], argv[1], argv[2], int(argv[3]), float(argv[4])
    design = StudyDesign(protocol, seed=7, trials=trials, trial_s=trial_s, rest_s=0.5, timeout_s=5.0)
    study = Study.open(root)
    p = study.add_participant(pid)
    store = study.session(pid, 1, design)
    if store.lost is not None:
        print(store.lost.line(), flush=True)
    blocks = store.remaining(participant_blocks(design, pid, p.index))

    hang_after = int(os.environ.get('STUDY_HANG_AFTER', '0'))
    written = []

    def on_step(step):
        store.record(step)
        for row in step.rows:
            written.append(row)
            print(f'trial {row["block"]} {row["repetition"]} {row["status"]}', flush=True)
            if len(written) == hang_after:
                print('hanging', flush=True)
                while True:             # until the test kills it
                    time.sleep(1.0)
        for b in step.blocks:
            print(f'block {b.key} done', flush=True)

    session = RecordedSession(Session(design, blocks, {'gaze_source': 'script', 'clock_state': '-'}), store)
    drive(session, on_step=on_step)
    print('finished', flush=True)


if __name__ == '__main__':
    main(sys.argv[1:])
