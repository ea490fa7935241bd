"""The study folder: its BIDS-like layout and sidecar, bad input in one line (another format
version, an unknown participant, other parameters, a full disk), the resume after a crash, and
a session killed with SIGKILL mid-block: the finished trials intact, the block redone, the
analysis equal to an uninterrupted run's. Also `analyze STUDY_DIR` reads what the store writes."""
from __future__ import annotations

import errno
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import threading

import pytest

from fabric_guidance import atomic
from fabric_guidance.experiments import analyze, study_folder
from fabric_guidance.experiments.stats import analyze_trials
from fabric_guidance.graph.process_graph import wait_until
from fabric_guidance.study import store as store_module
from fabric_guidance.study.plan import StudyDesign, participant_blocks
from fabric_guidance.study.events import RecordedSession
from fabric_guidance.study.session import Session
from fabric_guidance.study.store import DiskFull, Study, StudyError, read_tsv, study_trials
from fabric_guidance.study.trial_columns import COLUMNS
from study_participant import drive  # noqa: E402 (test/ is on sys.path)

HERE = Path(__file__).resolve().parent
DESIGN = StudyDesign('speed', seed=7, trials=2, trial_s=5.0, rest_s=0.5, timeout_s=5.0)


def run_participant(root: Path, pid: str, design: StudyDesign = DESIGN, stop_after: int | None = None):
    """One participant's session in process, written as it goes; stop_after: stop (the operator's
    stop) after that many rows."""
    study = Study.open(root)
    p = study.add_participant(pid)
    st = study.session(pid, 1, design)
    session = RecordedSession(Session(design, st.remaining(participant_blocks(design, pid, p.index)),
                                      {'gaze_source': 'test'}), st)
    count = [0]

    def on_step(step):
        st.record(step)
        count[0] += len(step.rows)
        if stop_after is not None and count[0] >= stop_after and session.phase not in ('stopped', 'done'):
            st.record(session.stop(session._history[-1].t if session._history else 0.0))

    drive(session, on_step=on_step)
    return st


def test_the_layout_participants_and_the_sidecar(tmp_path):
    root = tmp_path / 'study'
    st = run_participant(root, 'P1')
    run_participant(root, 'P2')
    desc = json.loads((root / 'dataset_description.json').read_text())
    assert desc['FabricGuidanceStudyFormat'] == 2 and desc['BIDSVersion'] == '1.10.0'
    generated = desc['GeneratedBy'][0]
    assert generated['Name'] == 'fabric_guidance' and generated['Version'] not in ('', 'n/a', 'unknown')
    assert generated['Description'].startswith('git commit ')
    assert (root / 'README.md').is_file() and '**/*_bag/' in (root / '.bidsignore').read_text()
    header, rows = read_tsv(root / 'participants.tsv')
    assert header == ['participant_id', 'index', 'registered_utc']
    assert [(r['participant_id'], r['index']) for r in rows] == [('sub-P1', '0'), ('sub-P2', '1')]
    assert st.trials_path == root / 'sub-P1' / 'ses-1' / 'beh' / 'sub-P1_ses-1_task-speed_beh.tsv'
    header, rows = read_tsv(st.trials_path)
    assert header == list(COLUMNS) and len(rows) == 8 and {r['status'] for r in rows} == {'ok'}
    side = json.loads(st.sidecar_path.read_text())
    assert StudyDesign.from_dict(side['Parameters']).as_dict() == DESIGN.as_dict()
    # every column described at the sidecar's top level (where BIDS tools read it), a unit where there is one
    assert set(COLUMNS) <= set(side) and all(side[c]['Description'] for c in COLUMNS)
    assert side['trial_end_s']['Units'] == 's' and side['h_error_deg']['Units'] == 'deg'
    assert 'Units' not in side['block'] and 'subject' not in header and 'session' not in header
    assert {r['package_version'] for r in rows} == {generated['Version']}
    assert len(side['BlocksDone']) == 4
    assert not list(root.rglob('.*.tmp'))
    assert {r['wearer'] for r in study_trials(root)} == {'P1', 'P2'}


def test_one_folder_holds_both_tasks_each_sidecar_with_its_own_design(tmp_path):
    """A participant does speed one day and accuracy the next, in the study's one folder."""
    root = tmp_path / 'study'
    speed = run_participant(root, 'P1')
    accuracy_design = StudyDesign('accuracy', seed=7, trials=2, rest_s=0.5, timeout_s=5.0)
    study = Study.open(root)
    accuracy = study.session('P1', 2, accuracy_design)
    session = RecordedSession(Session(accuracy_design, participant_blocks(accuracy_design, 'P1', 0),
                                      {'gaze_source': 'test'}), accuracy)
    drive(session, on_step=accuracy.record)
    for st, task, absent in ((speed, 'speed', 'timeout_s'), (accuracy, 'accuracy', 'dummies')):
        side = json.loads(st.sidecar_path.read_text())
        assert side['Parameters']['protocol'] == task and absent not in side['Parameters'], side['Parameters']
        assert f'task-{task}' in st.trials_path.name and len(read_tsv(st.trials_path)[1]) == 8
    assert 'trial_s' not in json.loads(accuracy.sidecar_path.read_text())['Parameters']
    # both reopen as they were (a resumed day), and analyze takes either task from the folder
    study.session('P1', 1, DESIGN)
    study.session('P1', 2, accuracy_design)
    assert {r['protocol'] for r in study_trials(root)} == {'speed', 'accuracy'}


def test_bad_input_in_one_line(tmp_path):
    root = tmp_path / 's'
    run_participant(root, 'P1')
    study = Study.open(root)
    cases = []
    with pytest.raises(StudyError) as info:
        study.session('P9', 1, DESIGN)
    cases.append((info, 'unknown participant'))
    with pytest.raises(StudyError) as info:
        study.session('P1', 1, DESIGN.with_(trial_s=40.0))
    cases.append((info, "trial_s 5.0 recorded, 40.0 given"))
    with pytest.raises(StudyError) as info:
        study.add_participant('P_1')
    cases.append((info, 'letters or digits'))
    (tmp_path / 'other').mkdir()
    (tmp_path / 'other' / 'x.txt').write_text('x')
    with pytest.raises(StudyError) as info:
        Study.open(tmp_path / 'other')
    cases.append((info, 'not a study folder'))
    desc = json.loads((root / 'dataset_description.json').read_text())
    # a folder of format 1 (before the BIDS layout) is refused: finished with the version that wrote it
    (root / 'dataset_description.json').write_text(json.dumps({**desc, 'FabricGuidanceStudyFormat': 1}))
    with pytest.raises(StudyError) as info:
        Study.open(root)
    cases.append((info, 'study format version 1, this fabric_guidance reads version 2'))
    for info, text in cases:
        assert text in str(info.value) and '\n' not in str(info.value), str(info.value)


def test_a_session_of_another_version_is_refused_in_one_line_and_left_as_it_was(tmp_path):
    """Within a study folder of this version: a participant's sidecar or trials file written by
    another version (format number, columns) is refused naming the file; nothing is rewritten."""
    root = tmp_path / 's'
    st = run_participant(root, 'P1', stop_after=1)
    side, trials = st.sidecar_path.read_bytes(), st.trials_path.read_bytes()
    data = json.loads(side)
    st.sidecar_path.write_text(json.dumps({**data, 'FabricGuidanceStudyFormat': 0}))
    with pytest.raises(StudyError) as info:
        Study.open(root).session('P1', 1, DESIGN)
    text = str(info.value)
    assert str(st.sidecar_path) in text and 'study format version 0' in text and '\n' not in text, text
    st.sidecar_path.write_bytes(side)
    header, *rest = trials.decode().split('\n')
    st.trials_path.write_text('\n'.join([header.replace('repetition', 'rep'), *rest]))
    other = st.trials_path.read_bytes()
    with pytest.raises(StudyError) as info:
        Study.open(root).session('P1', 1, DESIGN)
    text = str(info.value)
    assert str(st.trials_path) in text and 'columns differ' in text and 'rep' in text and '\n' not in text, text
    # nothing recorded was touched: the sidecar and the trials file are as they were
    assert st.sidecar_path.read_bytes() == side and st.trials_path.read_bytes() == other


def test_a_full_disk_loses_nothing_recorded(tmp_path, monkeypatch):
    root = tmp_path / 's'
    st = run_participant(root, 'P1', stop_after=1)
    before = st.trials_path.read_bytes()
    real = atomic.atomic_write

    def full(path, write, mode='wb', check=None):
        raise OSError(errno.ENOSPC, 'No space left on device', str(path))

    monkeypatch.setattr(atomic, 'atomic_write', full)
    monkeypatch.setattr(store_module, 'write_text', lambda path, text: full(path, None))
    row = {**dict.fromkeys(COLUMNS), 'block': 'speed-order1-cond1', 'repetition': 5, 'status': 'ok'}
    del row['recorded_utc']
    with pytest.raises(DiskFull) as info:
        st.append(row)
    assert 'disk full: cannot write' in str(info.value) and 'intact' in str(info.value)
    assert '\n' not in str(info.value)
    assert st.trials_path.read_bytes() == before
    monkeypatch.setattr(store_module, 'write_text', atomic.write_text)
    monkeypatch.setattr(atomic, 'atomic_write', real)
    st.flush()                                               # space again: the held row lands
    assert read_tsv(st.trials_path)[1][-1]['repetition'] == '5'


def test_a_stopped_session_resumes_at_its_unfinished_block(tmp_path):
    root = tmp_path / 's'
    first = run_participant(root, 'P1', stop_after=3)       # block 1 done, block 2 cut after 1 trial
    rows = first.rows()
    assert [r['status'] for r in rows] == ['ok', 'ok', 'ok']
    study = Study.open(root)
    again = study.session('P1', 1, DESIGN)
    assert again.lost is not None and again.lost.block == rows[2]['block'] and again.lost.trials == 1
    assert 'is run again' in again.lost.line()
    assert [r['status'] for r in again.rows()] == ['ok', 'ok', 'interrupted']
    assert Study.open(root).session('P1', 1, DESIGN).lost is None      # said once
    blocks = participant_blocks(DESIGN, 'P1', 0)
    assert [b.key for b in again.remaining(blocks)] == [b.key for b in blocks[1:]]
    # runs 1 and 2 were the first session's blocks (run 2 the cut one, named in BlocksInterrupted);
    # a block started (its bag reserved) and not finished is cut off too
    side = json.loads(again.sidecar_path.read_text())
    assert side['BlocksInterrupted'][0]['runs'] == [2]
    assert (again.folder / 'sub-P1_ses-1_task-speed_run-2_events.tsv').is_file()
    assert again.bag_path(blocks[1]).name == 'sub-P1_ses-1_task-speed_run-3_bag'
    third = Study.open(root).session('P1', 1, DESIGN)
    assert third.lost == store_module.Lost(blocks[1].key, 0)
    assert third.bag_path(blocks[1]).name.endswith('_run-4_bag')


class Child:
    """The scripted participant as a process, its output lines collected as they come."""

    def __init__(self, root: Path, pid: str, hang_after: int | None = None):
        env = dict(os.environ, PYTHONPATH=str(HERE.parent) + os.pathsep + os.environ.get('PYTHONPATH', ''))
        if hang_after:
            env['STUDY_HANG_AFTER'] = str(hang_after)
        self.proc = subprocess.Popen([sys.executable, str(HERE / 'study_participant.py'), str(root), pid, 'speed',
                                      str(DESIGN.trials), str(DESIGN.trial_s)],
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
        self.lines: list[str] = []
        self.reader = threading.Thread(target=lambda: self.lines.extend(iter(self.proc.stdout.readline, '')),
                                       daemon=True)
        self.reader.start()

    def finish(self, timeout=120.0) -> list[str]:
        assert self.proc.wait(timeout) == 0, self.lines
        self.reader.join(10.0)
        return self.lines


def study_table(root: Path):
    frame, _ = analyze.study_frame(root)
    return analyze_trials(frame, 'identified').table, frame


def test_a_session_killed_mid_block_keeps_its_trials_and_resumes(tmp_path):
    killed, whole = tmp_path / 'killed', tmp_path / 'whole'
    # Uninterrupted: two participants.
    for pid in ('P1', 'P2'):
        Child(whole, pid).finish()
    # Killed with SIGKILL after its 3rd trial (block 2 of 4, one trial into it), then run again.
    Child(killed, 'P1').finish()
    child = Child(killed, 'P2', hang_after=3)
    wait_until(lambda: 'hanging\n' in child.lines, 120.0, what='the third trial written')
    on_disk = read_tsv(killed / 'sub-P2' / 'ses-1' / 'beh' / 'sub-P2_ses-1_task-speed_beh.tsv')[1]
    child.proc.send_signal(signal.SIGKILL)
    assert child.proc.wait(30.0) == -signal.SIGKILL
    assert [f'trial {r["block"]} {r["repetition"]} {r["status"]}\n' for r in on_disk] == \
        [ln for ln in child.lines if ln.startswith('trial ')]          # every trial it had reported
    lines = Child(killed, 'P2').finish()
    assert lines[0].startswith(f'block {on_disk[2]["block"]} was cut off: its 1 finished trial(s)')
    after = read_tsv(killed / 'sub-P2' / 'ses-1' / 'beh' / 'sub-P2_ses-1_task-speed_beh.tsv')[1]
    assert after[:2] == on_disk[:2]                                     # the finished block untouched
    assert after[2] == {**on_disk[2], 'status': 'interrupted'}
    assert [r['block'] for r in after[3:5]] == [on_disk[2]['block']] * 2  # the block redone whole
    assert len(after) == 2 + 1 + 6
    killed_table, killed_frame = study_table(killed)
    whole_table, whole_frame = study_table(whole)
    assert killed_table.equals(whole_table)
    cols = ['wearer', 'condition', 'repetition', 'identified', 'presented']
    assert killed_frame[cols].sort_values(cols).reset_index(drop=True).equals(
        whole_frame[cols].sort_values(cols).reset_index(drop=True))


def test_analyze_reads_the_study_folder_as_the_store_writes_it(tmp_path, capsys):
    assert study_folder.FORMAT == (store_module.FORMAT_KEY, store_module.FORMAT_VERSION)
    root = tmp_path / 's'
    for pid in ('P1', 'P2', 'P3'):
        run_participant(root, pid)
    assert sorted(root.glob(analyze.STUDY_TRIALS)) == store_module.trials_files(root)
    assert analyze.main([str(root), '--table', str(tmp_path / 't.csv')]) == 0
    out = capsys.readouterr().out
    assert 'speed: identified, per participant mean' in out and '3 subjects (blocks) x 4 conditions' in out
    table = (tmp_path / 't.csv').read_text().splitlines()
    assert table[0] == 'subject,surface_adjusted,surface_fixed,simple_adjusted,speech'
    assert [ln.split(',')[0] for ln in table[1:]] == ['P1', 'P2', 'P3']
    assert analyze.main([str(tmp_path / 't.csv')]) == 0                 # the table it wrote reads back


def test_analyze_refuses_a_folder_that_is_no_study_in_one_line(tmp_path, capsys):
    (tmp_path / 'x').mkdir()
    assert analyze.main([str(tmp_path / 'x')]) == 2
    err = capsys.readouterr().err.strip()
    assert 'not a study folder' in err and '\n' not in err
    run_participant(tmp_path / 's', 'P1', StudyDesign('accuracy', seed=1, trials=2, rest_s=0.5, timeout_s=3.0))
    run_participant(tmp_path / 's', 'P2', StudyDesign('accuracy', seed=1, trials=2, rest_s=0.5, timeout_s=3.0))
    assert analyze.main([str(tmp_path / 's'), '--protocol', 'speed']) == 2
    assert 'no finished speed trials' in capsys.readouterr().err
    assert analyze.main([str(tmp_path / 's')]) == 0
    out = capsys.readouterr().out
    assert 'accuracy: h_error_deg' in out and 'accuracy: v_error_deg' in out


def test_docs_study_describes_every_column_and_parameter():
    text = (HERE.parent / 'docs' / 'study.md').read_text()
    for name, (unit, _) in COLUMNS.items():
        assert f'| `{name}` | {unit} |' in text, f'docs/study.md: no row for the column {name} ({unit})'
    for name in DESIGN.as_dict():
        assert f'| `{name}` |' in text, f'docs/study.md: no row for the parameter {name}'


def test_the_press_sources_are_recorded_and_a_sidecar_from_before_them_resumes(tmp_path):
    root = tmp_path / 's'
    st = run_participant(root, 'P1', DESIGN.with_(press_sources=('keyboard',)), stop_after=1)
    assert json.loads(st.sidecar_path.read_text())['Parameters']['press_sources'] == ['keyboard']
    with pytest.raises(StudyError, match=r"press_sources \['keyboard'\] recorded, \[\] given"):
        Study.open(root).session('P1', 1, DESIGN)
    # a sidecar written before the parameter press_sources resumes with its default (all)
    st = run_participant(root, 'P2', stop_after=1)
    side = json.loads(st.sidecar_path.read_text())
    del side['Parameters']['press_sources']
    st.sidecar_path.write_text(json.dumps(side))
    st = run_participant(root, 'P2')                 # resumes; nothing recorded is lost
    header, rows = read_tsv(st.trials_path)
    assert header == list(COLUMNS) and rows[0]['status'] == 'interrupted' and len(rows) == 1 + 8
    assert json.loads(st.sidecar_path.read_text())['Parameters']['press_sources'] == []
