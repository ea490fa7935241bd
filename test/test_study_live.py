"""A live session with a first-time participant on a graph that is already running, as a lab
runs it (`fabric-guidance study --participant ID` against `ros2 launch ...`): here the simulated
graph in a namespace, wearer_sim as the person (pressing confirm), no calibration file of the
participant anywhere. The controller starts disarmed, as the lab launch starts it; the session
waits for the operator's arm (the test plays the operator once), calibrates them from the
running graph, runs their block and writes what `analyze` reads."""
import io
import os
from pathlib import Path
import threading

import pytest
import yaml

from fabric_guidance.graph.process_graph import FILES, Graph, fresh_domain_id, loopback_dds_env, sim_lab, start_nodes
from fabric_guidance.live_study.driver import OPERATOR_COMMANDS, SessionDriver
from fabric_guidance.live_study.keyboard import KeyboardSource
from fabric_guidance.live_study.live_session import operator_keys, run_live_session, status_line
from fabric_guidance.live_study.simulated import graph_overrides
from fabric_guidance.live_study.study_command import main as study_main
from fabric_guidance.sim.scene import load_scene, scene_path
from fabric_guidance.study.store import read_tsv
from rosgraph import wait_until

NAMESPACE = 'suit_live'


def short_speed_scene(tmp_path: Path) -> Path:
    data = yaml.safe_load(scene_path('paper-speed').read_text())
    data.update(conditions=[1], repetitions=1)
    data['protocol']['trial_s'] = 6.0      # a target or more found in it (the check is >= 1)
    path = tmp_path / 'short-speed.yaml'
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


@pytest.mark.graph
def test_a_first_time_participant_is_calibrated_on_the_running_graph_and_runs_their_block(tmp_path, monkeypatch):
    scene = load_scene(short_speed_scene(tmp_path))
    cal_dir = tmp_path / 'calibrations'
    domain_id = fresh_domain_id()
    lab = sim_lab(1, 'suit', cal_dir)
    # The lab's graph before the participant arrives: nobody's calibration in it.
    graph_overrides(lab, scene, 0, 1, cal_dir / 'nobody.yaml', min(scene.sim_rate_hz, 90.0))
    # A short Algorithm 1 (5 pressures, 1.5 s dwell of which the last 0.3 s are recorded, 1.5 s rest):
    # long enough for wearer_sim's wearer to reach each step and settle between directions. A
    # shorter one (0.6 s dwell, 0.5 s rest) fed the fit the wearer's lag, and the acceptance now
    # refuses such fits by their shape (docs/calibration.md, Acceptance).
    # A gaze timeout of 1 s: a loaded machine's stall of the simulated headset must not abort the
    # calibration under test (the stale-gaze abort has tests of its own).
    lab.overrides['pressure_controller'].update(calibration_dir=str(cal_dir), calibration_steps=5,
                                                calibration_dwell_s=1.5, calibration_rest_s=1.5,
                                                calibration_window_s=0.3, gaze_timeout_s=1.0)
    graph = Graph(tmp_path / 'graph', domain_id=domain_id, namespace=NAMESPACE)
    monkeypatch.setenv('ROS_DOMAIN_ID', str(domain_id))
    for key, value in loopback_dds_env().items():
        monkeypatch.setenv(key, value)
    lines, refused = [], []

    def wearer_sim_trial(op, condition, repetition):
        # wearer_sim is the person: its streams follow the trial, as in study --simulated
        op.set_parameters('wearer_sim', condition=condition, repetition=repetition)
    from std_srvs.srv import SetBool
    from fabric_guidance import interface
    from fabric_guidance.graph.process_graph import Probe
    try:
        start_nodes(graph, lab, FILES)
        out = tmp_path / 'study'

        def operator_arms():
            # The person at the console arms the controller once the session waits for it.
            wait_until(lambda: any("the operator's arm is off" in line for line in lines), 60.0,
                       what='the session asking for the arm')
            with Probe(domain_id, 'lab_operator', NAMESPACE) as probe:
                assert probe.call(SetBool, interface.ENABLE, SetBool.Request(data=True), attempts=3).success
        arming = threading.Thread(target=operator_arms, daemon=True)
        arming.start()
        code = run_live_session(scene, 'P01', 1, out, lines.append, namespace=NAMESPACE, keyboard=False,
                                again=lambda reason: refused.append(reason) or len(refused) < 3,
                                before_trial=wearer_sim_trial)
    finally:
        graph.stop_all()
    assert code == 0, '\n'.join(lines)
    text = '\n'.join(lines)
    # it asked for the operator's arm before calibrating, and armed nothing itself
    assert text.index("the operator's arm is off") < text.index('calibration of P01 written'), text
    assert 'P01: no calibration yet; calibrating now' in text
    assert (cal_dir / 'P01.yaml').is_file(), text           # written by the graph's controller, as <id>.yaml
    header, rows = read_tsv(out / 'sub-P01' / 'ses-1' / 'beh' / 'sub-P01_ses-1_task-speed_beh.tsv')
    assert [(r['condition'], r['status']) for r in rows] == [('1', 'ok')], rows
    # wearer_sim presses as the headset's clicker does (its uplink)
    assert int(rows[0]['identified']) >= 1 and rows[0]['press_source'] == 'headset', text
    assert rows[0]['calibration_file'] == 'P01.yaml' and len(rows[0]['calibration_sha256']) == 64
    assert rows[0]['clock_state'] == 'synced'      # gaze_bridge's clock estimate of wearer_sim's headset clock
    assert list((out / 'sub-P01' / 'ses-1' / 'beh').glob('*_run-1_bag')), 'the block has its bag'


def test_the_operators_keys_reach_the_session_as_its_commands():
    """p c r s e q become the session's pause, resume, repeat, skip, arm and stop (in that order), and
    the confirm keys a press; the driver takes any of its commands and refuses others."""
    got, presses = [], []
    src = KeyboardSource(lambda: presses.append(1), got.append, io.StringIO('p c r s x e \nq'))
    src.start().join(5)
    assert got == ['pause', 'resume', 'repeat', 'skip', 'arm', 'stop'] and len(presses) == 7   # spaces, a newline
    assert set(got) == set(OPERATOR_COMMANDS)

    class Recorder:
        def __init__(self):
            self.calls = []

        def __getattr__(self, name):
            return lambda t: self.calls.append(name) or type('Step', (), {
                'refused': None, 'presses': [], 'actions': [], 'rows': [], 'amended': [], 'blocks': [],
                'ignored': None})()
    session = Recorder()

    class ArmedOp:      # the controller armed: the session may take `arm`
        controller_started = '1'

        def arm_dropped(self, started):
            return ''
    driver = SessionDriver(op=ArmedOp(), session=session, store=None)
    for name in got:
        driver.command(name)
    with pytest.raises(ValueError, match='unknown session command'):
        driver.command('explode')
    driver._apply_commands(1.0)
    assert session.calls == got


def test_the_status_line_says_who_where_and_how_long():
    line = status_line({'phase': 'target', 'participant': 'P07', 'condition': 3, 'block': '2/4', 'trial': '1/6',
                        'time_left_s': 12.34, 'identified': 4, 'last_result': 'target 4 found (2.1 deg)'})
    assert line == 'sub-P07 | condition 3 | block 2/4 | trial 1/6 | target | 12.3 s left | identified 4 | ' \
                   'last: target 4 found (2.1 deg)'


def test_a_live_session_without_a_graph_says_so_in_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv('ROS_DOMAIN_ID', str(fresh_domain_id()))
    monkeypatch.setattr('fabric_guidance.live_study.live_session.GRAPH_TIMEOUT_S', 2.0)
    code = study_main(['--participant', 'P02', '--protocol', 'accuracy', '--out', str(tmp_path / 's'), '--no-keys'])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1, err
    assert "no pressure_controller answers in namespace '/'" in err[0] and 'launch the graph first' in err[0]
    # registered, nothing else: the folder is a study a later run resumes
    assert (tmp_path / 's' / 'participants.tsv').read_text().count('sub-P02') == 1
    assert os.path.isdir(tmp_path / 's')


@pytest.mark.parametrize('argv, why', [
    (['--participant', 'P_01'], 'participant must be 1-64 letters or digits'),
    (['--participant', 'P01', '--simulated'], 'either --simulated'),
    (['--participant', 'P01', '--session', '0'], '--session: 1 or more'),
    (['--participant', 'P01', '--press-source', 'keyboard,clicker'],
     "--press-source: unknown press source 'clicker': one of keyboard, headset, wearer_sim, ros"),
    (['--simulated', '--press-source', 'mouse'], "--press-source: unknown press source 'mouse'"),
])
def test_bad_live_options_are_refused_in_one_line(tmp_path, capsys, argv, why):
    assert study_main([*argv, '--out', str(tmp_path / 's')]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and why in err[0], err


def test_the_press_source_option_reaches_the_session_design(tmp_path, monkeypatch):
    got = {}

    def fake_live(scene, participant, session_no, out, say, order, namespace, keyboard, press_sources=()):
        got['live'] = press_sources
        return 0

    def fake_simulated(scene, participants, out, say, order='random', press_sources=()):
        got['simulated'] = press_sources
        return 0
    monkeypatch.setattr('fabric_guidance.live_study.live_session.run_live_session', fake_live)
    monkeypatch.setattr('fabric_guidance.live_study.session_graph.run_study_session', fake_simulated)
    assert study_main(['--participant', 'P01', '--press-source', 'keyboard', '--out', str(tmp_path / 'a')]) == 0
    assert study_main(['--simulated', '--participants', '1', '--out', str(tmp_path / 'b')]) == 0
    assert got == {'live': ('keyboard',), 'simulated': ()}
    assert study_main(['--simulated', '--press-source', 'headset,ros', '--out', str(tmp_path / 'c')]) == 0
    assert got['simulated'] == ('headset', 'ros')


def test_q_vents_from_the_keys_thread_before_the_stop_reaches_the_session():
    log = []

    class Op:
        def trial_gate(self, on):
            log.append(('gate', on))
            return ''

        def enable(self, on):
            log.append(('enable', on))

    class Driver:
        def command(self, name):
            log.append(('session', name))
    keys = operator_keys(Op(), Driver(), log.append)
    keys('pause')
    keys('stop')
    assert log == [('session', 'pause'), ('gate', False), ('session', 'stop')]
    # e: the operator's arm, the only enable the session's terminal sends: gate closed, enable, then resume
    log.clear()
    keys('arm')
    assert log == [('gate', False), ('enable', True), '  operator: armed (enable)', ('session', 'arm')]
