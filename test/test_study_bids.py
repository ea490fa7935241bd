"""The study folder is a BIDS dataset that tools the package did not write read: npm's
bids-validator (pinned: the Makefile's BIDS_VALIDATOR_VERSION) finds no error in a folder
holding both tasks, a participant whose block was cut and run again, the bags and logs; pybids'
BIDSLayout (validation on) finds every subject, both tasks, the beh datatype and each run's
events with their entities; each run's events start at its time anchor."""
from __future__ import annotations

import json
import os
from pathlib import Path
import re
import shutil
import subprocess
import sys

import pytest

from fabric_guidance.study.events import EVENT_COLUMNS
from fabric_guidance.study.plan import StudyDesign
from fabric_guidance.study.store import read_tsv
from test_study_store import DESIGN, run_participant  # noqa: E402 (test/ is on sys.path)
from rosgraph import log_tails  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
VALIDATOR = ROOT / '.npm-bids' / 'node_modules' / '.bin' / 'bids-validator'
PINNED = re.search(r'^BIDS_VALIDATOR_VERSION := (\S+)$', (ROOT / 'Makefile').read_text(), re.M).group(1)
ACCURACY = StudyDesign('accuracy', seed=7, trials=2, rest_s=0.5, timeout_s=5.0)


def bids_validator(folder: Path) -> dict:
    """bids-validator's JSON report on `folder` (skips when node or the pinned validator is absent)."""
    if shutil.which('node') is None:
        pytest.skip('node is absent (make system-deps installs nodejs npm)')
    if not VALIDATOR.exists():
        pytest.skip(f'bids-validator {PINNED} is not installed (make bids-validator)')
    version = subprocess.run([str(VALIDATOR), '--version'], capture_output=True, text=True, timeout=60).stdout.strip()
    if version != PINNED:
        pytest.skip(f'bids-validator {version} installed, {PINNED} pinned (make bids-validator)')
    res = subprocess.run([str(VALIDATOR), '--json', str(folder)], capture_output=True, text=True, timeout=300)
    return json.loads(res.stdout)


def errors(report: dict) -> list[str]:
    return [f"{e['key']}: {[f['file']['relativePath'] for f in e.get('files', [])][:3]}"
            for e in report['issues']['errors']]


@pytest.fixture(scope='module')
def study(tmp_path_factory) -> Path:
    """Both tasks in one folder; P3's speed block cut (the operator's stop) and run again; what the
    simulated study writes beside the data (logs, scene files, a bag) as it writes it."""
    root = tmp_path_factory.mktemp('bids') / 'study'
    for pid in ('P1', 'P2'):
        run_participant(root, pid)
        run_participant(root, pid, ACCURACY)
    run_participant(root, 'P3', stop_after=3)
    run_participant(root, 'P3')
    (root / 'sourcedata' / 'logs' / 'sub-01' / 'graph').mkdir(parents=True)
    (root / 'sourcedata' / 'logs' / 'sub-01' / 'graph' / 'mock_plc.log').write_text('log\n')
    (root / 'scene-speed.yaml').write_text('name: x\n')
    (root / 'timing-speed.json').write_text('{}\n')
    bag = root / 'sub-P1' / 'ses-1' / 'beh' / 'sub-P1_ses-1_task-speed_run-1_bag'
    bag.mkdir()
    (bag / 'metadata.yaml').write_text('rosbag2_bagfile_information: {}\n')
    (bag.with_name(bag.name + '_recorder.log')).write_text('log\n')
    return root


def test_the_bids_validator_finds_no_error_in_a_folder_of_both_tasks(study):
    report = bids_validator(study)
    assert not report['issues']['errors'], errors(report)
    summary = report['summary']
    # The validator lists subjects and tasks in the order it met them (no order is promised).
    assert sorted(summary['subjects']) == ['P1', 'P2', 'P3'] and sorted(summary['tasks']) == ['accuracy', 'speed']
    assert summary['sessions'] == ['1'] and 'beh' in summary['dataTypes'] and 'events' in summary['dataTypes']
    codes = {w['key'] for w in report['issues']['warnings']}
    # P3 did one task only (a subject without every file is a warning), and no authors are known
    assert codes <= {'INCONSISTENT_SUBJECTS', 'NO_AUTHORS'}, codes


def test_pybids_finds_every_subject_both_tasks_and_the_events(study):
    bids = pytest.importorskip('bids')
    layout = bids.BIDSLayout(study, validate=True)
    assert sorted(layout.get_subjects()) == ['P1', 'P2', 'P3']
    assert sorted(layout.get_tasks()) == ['accuracy', 'speed'] and layout.get_datatypes() == ['beh']
    beh = layout.get(suffix='beh', extension='.tsv', datatype='beh')
    assert len(beh) == 5
    events = layout.get(suffix='events', extension='.tsv', datatype='beh', subject='P3', task='speed')
    runs = sorted(e.get_entities()['run'] for e in events)
    assert runs == [1, 2, 3, 4, 5]          # blocks 1 and 2, then 2 run again, 3 and 4
    one = events[0].get_entities()
    assert {k: one[k] for k in ('subject', 'session', 'task', 'datatype', 'suffix')} == \
        {'subject': 'P3', 'session': '1', 'task': 'speed', 'datatype': 'beh', 'suffix': 'events'}
    meta = layout.get_metadata(beh[0].path)
    assert meta['trial_end_s']['Units'] == 's' and meta['TaskName'] in ('speed', 'accuracy')
    frame = beh[0].get_df()
    assert 'subject_index' in frame.columns and 'subject' not in frame.columns
    assert list(layout.get_dataset_description()['GeneratedBy'][0]) == ['Name', 'Version', 'Description']


def test_each_runs_events_start_at_its_anchor_and_hold_each_press(study):
    folder = study / 'sub-P1' / 'ses-1' / 'beh'
    side = json.loads((folder / 'sub-P1_ses-1_task-speed_beh.json').read_text())
    trials = read_tsv(folder / 'sub-P1_ses-1_task-speed_beh.tsv')[1]
    for started in side['BlocksStarted']:
        header, events = read_tsv(folder / started['events'])
        assert header == list(EVENT_COLUMNS)
        first = events[0]
        # the anchor: onset 0 is the run's start, on the steady clock and in UTC
        assert first['trial_type'] == 'run_start' and float(first['onset']) == 0.0
        assert float(first['steady_s']) == started['started_steady_s'] and first['value'] == started['started_utc']
        onsets = [float(e['onset']) for e in events]
        assert onsets == sorted(onsets) and min(onsets) >= 0.0
        for e in events:
            assert abs(float(e['steady_s']) - started['started_steady_s'] - float(e['onset'])) < 1e-9
        kinds = [e['trial_type'] for e in events]
        block_rows = [r for r in trials if r['block'] == started['block']]
        assert kinds.count('trial') == len(block_rows) == DESIGN.trials
        found = sum(int(r['identified']) for r in block_rows)
        assert kinds.count('target_found') == found and kinds.count('target_shown') == \
            sum(int(r['presented']) for r in block_rows)
        presses = [e for e in events if e['trial_type'] == 'press']
        assert len(presses) == sum(int(r['presses']) + int(r['refused_presses']) for r in block_rows)
        assert all(float(p['press_latency_s']) > 0 and p['press_source'] == 'keyboard' for p in presses)


@pytest.mark.graph
def test_both_simulated_protocols_into_one_folder_pass_the_validator(tmp_path):
    """`study --simulated` speed, then accuracy, into one folder (one participant, one short
    block each): what the command writes beside the data (logs, scene files, timing, bags) is
    passed over, the data valid."""
    if shutil.which('node') is None or not VALIDATOR.exists():
        bids_validator(tmp_path)          # skips with the reason
    out = tmp_path / 'study'
    for protocol, extra in (('speed', ['--trial-s', '3']), ('accuracy', [])):
        res = subprocess.run([sys.executable, '-m', 'fabric_guidance.live_study.study_command', '--simulated',
                              '--participants', '1', '--protocol', protocol, '--trials', '1', '--out', str(out),
                              *extra], capture_output=True, text=True, timeout=600,
                             env=dict(os.environ, PYTHONUNBUFFERED='1'))
        assert res.returncode == 0, res.stdout + res.stderr + log_tails(out / 'sourcedata' / 'logs')
    report = bids_validator(out)
    assert not report['issues']['errors'], errors(report)
    assert sorted(report['summary']['tasks']) == ['accuracy', 'speed'] and report['summary']['subjects'] == ['01']
    assert sorted(p.name for p in out.glob('scene-*.yaml')) == ['scene-accuracy.yaml', 'scene-speed.yaml']
    assert list((out / 'sub-01' / 'ses-1' / 'beh').glob('*_run-1_bag'))


def test_noting_a_steps_events_writes_nothing_before_its_vent_is_carried_out(tmp_path, monkeypatch):
    """RecordedSession notes a Step before the driver carries out its actions: a block's end
    (vent, then the next condition) must not wait on the disk; its files come with the bag's
    reservation or the trial's row."""
    from fabric_guidance.study import store as store_module
    from fabric_guidance.study.events import RecordedSession
    from fabric_guidance.study.plan import participant_blocks
    from fabric_guidance.study.session import Session
    from fabric_guidance.study.store import Study
    study = Study.open(tmp_path / 's')
    study.add_participant('P1')
    st = study.session('P1', 1, DESIGN)
    blocks = participant_blocks(DESIGN, 'P1', 0)
    session = RecordedSession(Session(DESIGN, blocks), st)
    writes = []
    real = store_module._write
    monkeypatch.setattr(store_module, '_write', lambda path, text: (writes.append(path.name), real(path, text)))
    step = session.start(100.0)
    assert [a.kind for a in step.actions][:2] == ['vent', 'set_condition'] and writes == []
    path = st.bag_path(blocks[0])                   # the driver's set_condition reserves the bag
    assert path.name == 'sub-P1_ses-1_task-speed_run-1_bag'
    assert sorted(writes) == ['sub-P1_ses-1_task-speed_beh.json', 'sub-P1_ses-1_task-speed_run-1_events.json',
                              'sub-P1_ses-1_task-speed_run-1_events.tsv']
