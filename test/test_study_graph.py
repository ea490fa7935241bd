"""The study session through the simulated graph: wearer_sim presses confirm as the headless
model does, the session judges the press on the gaze at its stamp, switches the condition within
the graph, keeps the suit vented between trials, writes every trial as it ends, and a session
killed with SIGKILL mid-block resumes at that block with the finished trials intact."""
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

import pytest
import yaml

from fabric_guidance.sim.scene import load_scene, scene_path
from fabric_guidance.live_study.session_graph import run_study_session
from fabric_guidance.study.store import read_tsv, study_trials
from rosgraph import wait_until

pytestmark = pytest.mark.graph


def short_scene(tmp_path: Path, conditions=(1, 3), trials=1, trial_s=6.0, protocol='speed') -> Path:
    """paper-speed / paper-accuracy with two conditions (a switch to the arm layout) and short blocks."""
    data = yaml.safe_load(scene_path(f'paper-{protocol}').read_text())
    data.update(conditions=list(conditions), repetitions=trials)
    if protocol == 'speed':
        data['protocol']['trial_s'] = trial_s
    path = tmp_path / f'short-{protocol}.yaml'
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def rows_of(out: Path, protocol: str) -> list[dict]:
    return read_tsv(out / 'sub-01' / 'ses-1' / 'beh' / f'sub-01_ses-1_task-{protocol}_beh.tsv')[1]


def test_speed_session_wearer_presses_and_no_command_between_trials(tmp_path):
    scene = load_scene(short_scene(tmp_path))
    out = tmp_path / 'study'
    lines = []
    assert run_study_session(scene, 1, out, lines.append) == 0
    rows = rows_of(out, 'speed')
    assert sorted(int(r['condition']) for r in rows) == [1, 3] and {r['status'] for r in rows} == {'ok'}
    for r in rows:
        # wearer_sim pressed confirm and the session accepted presses within 5 deg
        assert int(r['presses']) >= int(r['identified']) >= 1, r
        assert int(r['presented']) >= int(r['identified']) and r['press_source'] == 'headset'
    timing = next(line for line in lines if line.startswith('timing:'))
    # the controller publishes every step, vented too: commands were seen between trials, none above 0
    checked = int(timing.rsplit(' of ', 1)[1].split()[0])
    assert checked > 0 and timing.endswith(f'0 of {checked} commands between trials above 0 kPa'), timing
    # the switch 1 -> 3 by the live parameter within the running graph, nothing restarted
    assert 'condition switch ' in timing and '(parameter)' in timing and 'restart' not in timing, timing
    # every found target's phases on the graph were measured
    assert 'per found target, mean s: target_call ' in timing and 'front_return ' in timing, timing
    # what analyze reads of the folder: both trials, finished
    assert sorted(int(r['condition']) for r in study_trials(out, 'speed')) == [1, 3]


def test_accuracy_session_records_the_error_at_the_press(tmp_path):
    scene = load_scene(short_scene(tmp_path, conditions=(1,), trials=2, protocol='accuracy'))
    out = tmp_path / 'study'
    assert run_study_session(scene, 1, out, lambda line: None) == 0
    rows = rows_of(out, 'accuracy')
    assert len(rows) == 2
    for r in rows:
        assert r['status'] == 'ok' and r['press_source'] == 'headset' and r['timed_out'] == 'False', r
        assert 0.0 <= float(r['h_error_deg']) < 60.0 and 0.0 <= float(r['v_error_deg']) < 60.0
        assert float(r['time_s']) < scene.protocol.timeout_s


def _study(scene: Path, out: Path, **kw):
    cmd = [sys.executable, '-m', 'fabric_guidance.live_study.study_command', '--simulated', '--participants', '1',
           '--protocol', 'speed', '--scene', str(scene), '--out', str(out)]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, **kw)


def test_sigkill_mid_block_resumes_at_that_block(tmp_path):
    # 2 s trials: what is tested is where the kill falls (between trials, mid-block), not what a trial finds
    scene = short_scene(tmp_path, conditions=(1, 2), trials=2, trial_s=2.0)
    out = tmp_path / 'study'
    tsv = out / 'sub-01' / 'ses-1' / 'beh' / 'sub-01_ses-1_task-speed_beh.tsv'
    # its own session: SIGKILL to the group takes the seven nodes down with it, as a power loss would
    proc = _study(scene, out, start_new_session=True)
    try:
        wait_until(lambda: tsv.exists() and len(read_tsv(tsv)[1]) >= 3, 240, 0.05, what='three trials written')
        os.killpg(proc.pid, signal.SIGKILL)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(10)
    before = read_tsv(tsv)[1]
    assert len(before) == 3          # block 1 whole, one trial of block 2: the kill was mid-block
    time.sleep(0.5)
    rerun = _study(scene, out)
    output, _ = rerun.communicate(timeout=300)
    assert rerun.returncode == 0, output
    assert f"block {before[2]['block']} was cut off: its 1 finished trial(s) are kept as 'interrupted'" in output
    after = read_tsv(tsv)[1]
    assert after[:2] == before[:2]     # the finished block is intact
    assert after[2]['status'] == 'interrupted'
    redone = [r for r in after[3:] if r['block'] == before[2]['block']]
    assert [(r['status'], r['repetition']) for r in redone] == [('ok', '0'), ('ok', '1')]
    # the analysis reads the finished trials only
    assert len(study_trials(out, 'speed')) == 4


def test_keyboard_keys_press_confirm_and_send_commands():
    import io

    from fabric_guidance.live_study.keyboard import KeyboardSource
    presses, commands = [], []
    src = KeyboardSource(lambda: presses.append(1), commands.append, io.StringIO(' x\nprs q '))
    src.start().join(5)
    assert len(presses) == 3 and commands == ['pause', 'repeat', 'skip', 'stop']   # nothing read after q


def children_of(pid: int) -> dict[int, str]:
    """Live processes whose parent is `pid` (pid -> command line); a zombie has ended."""
    found = {}
    for entry in Path('/proc').iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / 'stat').read_text().rsplit(')', 1)[1].split()
            if int(fields[1]) == pid and fields[0] != 'Z':
                found[int(entry.name)] = (entry / 'cmdline').read_bytes().replace(b'\0', b' ').decode()
        except (OSError, ValueError, IndexError):
            continue
    return found


def alive(pid: int) -> bool:
    try:
        state = (Path('/proc') / str(pid) / 'stat').read_text().rsplit(')', 1)[1].split()[0]
    except OSError:
        return False
    return state != 'Z'


def test_a_study_killed_with_sigkill_leaves_no_process_and_resumes_into_clean_logs(tmp_path):
    scene = short_scene(tmp_path, conditions=(1,), trials=2, trial_s=2.0)
    out = tmp_path / 'study'
    tsv = out / 'sub-01' / 'ses-1' / 'beh' / 'sub-01_ses-1_task-speed_beh.tsv'
    proc = _study(scene, out)
    try:
        wait_until(lambda: proc.poll() is not None or (tsv.exists() and len(read_tsv(tsv)[1]) >= 1), 240, 0.05,
                   what='a trial written')
        assert proc.poll() is None, proc.communicate()[0]     # a study that stopped says why
        nodes = {p: c for p, c in children_of(proc.pid).items() if 'fabric_guidance.nodes.' in c}
        assert len(nodes) >= 7, nodes          # the graph's seven nodes (and the block's recorder)
        proc.send_signal(signal.SIGKILL)        # the study process alone, not its group
        assert proc.wait(10) == -signal.SIGKILL
        wait_until(lambda: not any(alive(p) for p in nodes), 30.0, 0.05,
                   what=f'the killed study\'s nodes to end: {[c[-60:] for p, c in nodes.items() if alive(p)]}')
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    rerun = _study(scene, out)
    output, _ = rerun.communicate(timeout=300)
    assert rerun.returncode == 0, output
    assert 'was cut off' in output, output
    logs = sorted((out / 'sourcedata' / 'logs' / 'sub-01').glob('graph*'))
    assert [p.name for p in logs] == ['graph', 'graph-2']       # the resumed run's own logs
    for log in logs[1].glob('*.log'):
        assert b'\0' not in log.read_bytes(), log
    side = json.loads((out / 'sub-01' / 'ses-1' / 'beh' / 'sub-01_ses-1_task-speed_beh.json').read_text())
    cut = side['BlocksInterrupted'][0]
    assert cut['bags'] == ['sub-01_ses-1_task-speed_run-1_bag'], cut
    assert (out / 'sub-01' / 'ses-1' / 'beh' / cut['bags'][0]).is_dir()


def test_a_node_lost_mid_session_stops_the_study_before_its_next_trial(tmp_path):
    """plc_output ended under a running simulated session (CI once saw it gone, its log empty, while
    the session went on): the next trial is not run without it, the study says which node it lost
    and with what status, and the trials already written stay."""
    scene = short_scene(tmp_path, conditions=(1,), trials=6, trial_s=2.0)
    out = tmp_path / 'study'
    tsv = out / 'sub-01' / 'ses-1' / 'beh' / 'sub-01_ses-1_task-speed_beh.tsv'
    proc = _study(scene, out)
    try:
        wait_until(lambda: tsv.exists() and len(read_tsv(tsv)[1]) >= 1, 240, 0.05, what='a trial written')
        plc_output = [p for p, c in children_of(proc.pid).items() if 'fabric_guidance.nodes.plc_output ' in c]
        assert len(plc_output) == 1, children_of(proc.pid)
        os.kill(plc_output[0], signal.SIGKILL)
        output, _ = proc.communicate(timeout=240)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    assert proc.returncode == 1, output
    assert 'lost plc_output (exit -9): no trial is run without it' in output, output
    rows = read_tsv(tsv)[1]
    assert 1 <= len(rows) < 6, rows     # stopped before the block's end, nothing written lost
