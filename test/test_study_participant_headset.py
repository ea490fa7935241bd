"""A live speed session, as `fabric-guidance study --participant P01 --press-source headset` runs
it (run_live_session, the headset the only press source), on the study's lab graph
(guidance.yaml with study-speed.yaml: gaze_bridge, target_selector, headset_display,
pressure_controller; no wearer_sim) with the compiled C# headset as the participant: a scripted
person reads what the harness receives, looks at each target it is shown and presses confirm
(headset_participant.py). What it got and what it did are then held against the session's
records:

(a) a `found` event reaches the headset for each target the rows count as identified, after the
    press that found it;
(b) every dummy of every set lies within headset_display's field (dummy_azimuth_deg,
    dummy_elevation_deg) seen from the eye, at the target's distance from the eye;
(c) the events' targets are those it saw, the presses recorded are its presses (source
    headset, stamps where it pressed, latencies), their errors as small as its aim.
"""
from __future__ import annotations

from datetime import datetime
import json
import math
from pathlib import Path
import socket
import statistics
import threading
import time

import pytest
import yaml

from fabric_guidance import interface
from fabric_guidance.graph.process_graph import loopback_dds_env
from fabric_guidance.live_study.live_session import run_live_session
from fabric_guidance.live_study.operator import TARGET_DISTANCE_M
from fabric_guidance.sim.scene import load_scene, scene_path
from fabric_guidance.sim.wearer import angle_between_deg
from fabric_guidance.study.store import read_tsv
from headset_harness import Harness, build_harness
from headset_participant import HeadsetParticipant, direction_to, yaw_pitch_deg
from rosgraph import ROOT, Graph, Probe, free_port, log_tails, wait_until

pytestmark = pytest.mark.graph

FILES = ('params/guidance.yaml', 'params/study-speed.yaml')
SIM_CAL = ROOT / 'config' / 'calibrations' / 'sim-wearer.yaml'
PARTICIPANT = 'P01'
#: Two blocks of two short trials: targets found, block changes, rests (about 60 s in all).
CONDITIONS, TRIALS, TRIAL_S = [1, 2], 2, 8.0
#: Positions travel rounded to 0.1 mm (display_wire.POSITION_DECIMALS): angles to about 0.005 deg.
ANGLE_TOL_DEG, DISTANCE_TOL_M = 0.05, 1e-3
#: The participant aims at the target it sees: the session's error of its accepted presses [deg].
MAX_ERROR_DEG = 0.5
#: How far a press's recorded stamp may lie from when the participant typed `confirm` [s]: before
#: it by the error of gaze_bridge's clock mapping (half its best ping's round trip), after it by
#: the harness's threads on a loaded machine. Loose on purpose: the bounds say "stamped at the
#: press, on the mapped headset clock", not how fast a loaded machine is.
STAMP_BEFORE_S, STAMP_AFTER_S = 0.25, 2.0
#: Between two presses the mapping may have moved by a better ping (half a round trip) [s].
MAPPING_MOVE_S = 0.1
#: A press judged within this of its stamp (the gaze sample after it, on a loaded machine) [s].
JUDGED_WITHIN_S = 2.0


@pytest.fixture(scope='module', autouse=True)
def harness_built():
    build_harness()


def short_speed_scene(tmp_path: Path) -> Path:
    data = yaml.safe_load(scene_path('paper-speed').read_text())
    data.update(conditions=CONDITIONS, repetitions=TRIALS)
    data['protocol']['trial_s'] = TRIAL_S
    path = tmp_path / 'short-speed.yaml'
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def number(cell: str) -> float | None:
    return None if cell in ('', 'n/a') else float(cell)


def display_parameters(domain_id: int) -> dict:
    """headset_display's field and eye, as the running node has them."""
    from rcl_interfaces.srv import GetParameters
    from rclpy.parameter import parameter_value_to_python
    names = ['dummies', 'dummy_azimuth_deg', 'dummy_elevation_deg', 'eye_height_m']
    with Probe(domain_id) as probe:
        response = probe.call(GetParameters, '/headset_display/get_parameters', GetParameters.Request(names=names))
    return dict(zip(names, (parameter_value_to_python(v) for v in response.values)))


def dummy_sets(person: HeadsetParticipant) -> dict[int, list]:
    """Each dummy set the headset received (set > 0), its parts joined."""
    parts: dict[int, dict[int, list]] = {}
    for m in person.messages('dummies'):
        if m['set'] > 0:
            parts.setdefault(m['set'], {})[m['part']] = m['positions']
    return {s: [p for _, ps in sorted(by_part.items()) for p in ps] for s, by_part in parts.items()}


def test_the_c_sharp_headset_as_a_scripted_participant_in_a_live_speed_session(tmp_path, monkeypatch):
    listen, uplink = free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_DGRAM)
    cal_dir = tmp_path / 'calibrations'
    cal_dir.mkdir()
    # The participant's own calibration (the simulated wearer's fit under their name): the session
    # loads it and calibrates nobody (a calibration has its own tests).
    own = SIM_CAL.read_text().replace('wearer: sim-wearer', f'wearer: {PARTICIPANT}')
    (cal_dir / f'{PARTICIPANT}.yaml').write_text(own)
    # The eye at the immersive frame's eye height, looking straight ahead (docs/headset.md).
    poses = tmp_path / 'poses.jsonl'
    poses.write_text(json.dumps({'gaze_origin': [0.0, 1.2, 0.0], 'gaze_direction': [0.0, 0.0, 1.0],
                                 'head_position': [0.0, 1.2, 0.0], 'head_orientation': [0.0, 0.0, 0.0, 1.0]}) + '\n')
    graph = Graph(tmp_path / 'logs')
    monkeypatch.setenv('ROS_DOMAIN_ID', str(graph.domain_id))
    for key, value in loopback_dds_env().items():
        monkeypatch.setenv(key, value)
    harness = person = None
    lines: list[str] = []
    out = tmp_path / 'study'
    try:
        graph.start('gaze_bridge', FILES, port=uplink, headset_address='127.0.0.1', display_port=listen)
        graph.start('target_selector', FILES)
        graph.start('headset_display', FILES, headset_address='127.0.0.1', display_port=listen)
        # stall_timeout_s 0: the scripted person's gaze does not follow the suit (the no-progress
        # vent is not under test); start_enabled false, as the lab launch starts it
        graph.start('pressure_controller', FILES, calibration_file=str(SIM_CAL), calibration_dir=str(cal_dir),
                    stall_timeout_s=0.0, start_enabled=False)
        harness = Harness(tmp_path / 'harness.log', '--uplink', f'127.0.0.1:{uplink}', '--listen',
                          f'127.0.0.1:{listen}', '--poses', str(poses), '--rate', '90', '--duration', '300',
                          '--commands', 'stdin', '--culture', 'de-DE')
        field = display_parameters(graph.domain_id)
        person = HeadsetParticipant(harness, eye_height_m=field['eye_height_m']).start()

        def operator_arms():
            # The person at the console arms the controller once the session waits for it.
            from std_srvs.srv import SetBool
            wait_until(lambda: any("the operator's arm is off" in line for line in lines), 60.0,
                       what='the session asking for the arm')
            with Probe(graph.domain_id, 'lab_operator') as probe:
                assert probe.call(SetBool, interface.ENABLE, SetBool.Request(data=True), attempts=3).success
        threading.Thread(target=operator_arms, daemon=True).start()
        # the steady clock of the session's files against the PC clock of the display's stamps
        pc_minus_steady = time.time() - time.monotonic()
        code = run_live_session(load_scene(short_speed_scene(tmp_path)), PARTICIPANT, 1, out, lines.append,
                                keyboard=False, press_sources=('headset',))
        assert code == 0, '\n'.join(lines)
    except BaseException:
        print('\n'.join(lines))
        print(log_tails(graph.log_dir))
        raise
    finally:
        if person is not None:
            person.stop()
        if harness is not None:
            harness.stop()
            harness.close()
            if person is not None:
                person.read_log()         # the harness's log complete
        graph.stop_all()
    assert not person.errors, person.errors

    beh = out / f'sub-{PARTICIPANT}' / 'ses-1' / 'beh'
    _, rows = read_tsv(beh / f'sub-{PARTICIPANT}_ses-1_task-speed_beh.tsv')
    events = [e for path in sorted(beh.glob('*_events.tsv')) for e in read_tsv(path)[1]]
    assert len(rows) == len(CONDITIONS) * TRIALS and all(r['status'] == 'ok' for r in rows), rows
    identified = sum(int(r['identified']) for r in rows)
    presses = [e for e in events if e['trial_type'] == 'press']
    mine = person.presses
    # the presses recorded are its presses: as many, all from the headset (in its order below)
    assert len(presses) == len(mine) and {p['press_source'] for p in presses} == {'headset'}, (presses, mine)
    assert all(m.stamp is not None for m in mine), mine
    accepted = [(e, m) for e, m in zip(presses, mine) if e['accepted'] == 'True']
    assert len(accepted) == identified == sum(int(r['presses']) for r in rows), (presses, rows)

    # (a) a found event (one event_id, three copies) for each identified target, each after the
    # press that found it and before the next (the harness's clock: its log's receive times and
    # its presses' stamps)
    found = person.events('found')
    assert len(found) == identified and all(m['target'] == 'study' for m in found), found
    for i, ((_, press), flash) in enumerate(zip(accepted, found)):
        assert press.stamp < flash['t'], (press, flash)
        if i + 1 < len(accepted):
            assert flash['t'] < accepted[i + 1][1].stamp, (flash, accepted[i + 1][1])

    # (b) every dummy within the configured field seen from the eye, at the targets' distance
    eye = person.eye
    shown = [e for e in events if e['trial_type'] == 'target_shown']
    assert {round(math.dist(s.position, eye), 3) for s in person.seen} == {TARGET_DISTANCE_M}, person.seen
    sets = dummy_sets(person)
    assert len(sets) >= len(shown), (len(sets), len(shown))       # a new set for every target
    az_max, el_max = field['dummy_azimuth_deg'], field['dummy_elevation_deg']
    for set_number, positions in sets.items():
        assert len(positions) == field['dummies'], (set_number, len(positions))
        for p in positions:
            yaw, pitch = yaw_pitch_deg(direction_to(p, eye))
            assert abs(yaw) <= az_max + ANGLE_TOL_DEG and abs(pitch) <= el_max + ANGLE_TOL_DEG, \
                (set_number, p, yaw, pitch)
            assert math.dist(p, eye) == pytest.approx(TARGET_DISTANCE_M, abs=DISTANCE_TOL_M), (set_number, p)

    # (c) the targets of the events are those the headset showed, in order (one the display
    # showed for a moment at the last target's place, before its new position came, aside)
    seen = [yaw_pitch_deg(direction_to(s.position, eye)) for s in person.seen]
    unmatched = iter(seen)
    for e in shown:
        h, v = number(e['target_h_deg']), number(e['target_v_deg'])
        assert any(abs(a - h) <= ANGLE_TOL_DEG and abs(b - v) <= ANGLE_TOL_DEG for a, b in unmatched), \
            f'target ({h}, {v}) of the events not shown to the headset in its order (it saw {seen})'
    # ... each press stamped where it pressed: the files' steady clock against the monotonic time
    # it sent `confirm`, the intervals between presses against the harness's own stamps
    for e, m in zip(presses, mine):
        assert -STAMP_BEFORE_S <= number(e['steady_s']) - m.sent_s <= STAMP_AFTER_S, (e, m)
        assert 0.0 <= number(e['press_latency_s']) < JUDGED_WITHIN_S, e
    for (e0, m0), (e1, m1) in zip(zip(presses, mine), zip(presses[1:], mine[1:])):
        between = number(e1['steady_s']) - number(e0['steady_s'])
        assert between == pytest.approx(m1.stamp - m0.stamp, abs=MAPPING_MOVE_S), (e0, e1, m0, m1)
    # ... each judged against the target it pressed on, with the error of the direction it
    # looked, as small as its aim; a press refused only when it came in its trial's last half
    # second (the trial over before its gaze sample)
    trials = [(number(r['trial_start_s']), number(r['trial_end_s'])) for r in rows]
    target, k = None, 0
    for e in events:
        if e['trial_type'] == 'target_shown':
            target = (number(e['target_h_deg']), number(e['target_v_deg']))
        elif e['trial_type'] == 'press':
            m, k = mine[k], k + 1
            aimed = yaw_pitch_deg(direction_to(m.target.position, eye))
            assert abs(aimed[0] - target[0]) <= ANGLE_TOL_DEG and abs(aimed[1] - target[1]) <= ANGLE_TOL_DEG, \
                (e, aimed, target)
            if number(e['error_deg']) is not None:
                looked = angle_between_deg(*yaw_pitch_deg(m.direction), *target)
                assert number(e['error_deg']) == pytest.approx(looked, abs=ANGLE_TOL_DEG), (e, looked)
            inside = any(start <= number(e['steady_s']) < end - 0.5 for start, end in trials)
            if e['accepted'] == 'True' or inside:
                assert e['accepted'] == 'True' and number(e['error_deg']) <= MAX_ERROR_DEG, e
    stamps = [number(e['steady_s']) for e, _ in accepted]
    for r in rows:       # a target or more found in every trial; its press_s the last accepted press
        assert int(r['identified']) >= 1 and r['press_source'] == 'headset' and number(r['press_s']) in stamps, r

    # the trial timing as the headset saw it: reported, not asserted (the session's timing has
    # its own tests)
    timing = trial_timing(person, rows, shown, pc_minus_steady)
    (tmp_path / 'timing.json').write_text(json.dumps(timing))
    print('timing [s]', json.dumps({k: summary(v) for k, v in timing.items()}))


def trial_timing(person: HeadsetParticipant, rows: list[dict], shown: list[dict],
                 pc_minus_steady: float) -> dict[str, list[float]]:
    """From the harness's log, the display's send stamps on the steady clock [s]: each trial's
    first target shown minus its trial_start_s; each target shown minus its target_shown event;
    for a trial whose target was still up at its end, the first message with nothing shown after
    the end minus trial_end_s; each row's recorded_utc minus its trial_end_s, and the next
    trial's start minus it."""
    out: dict[str, list[float]] = {'shown_minus_trial_start': [], 'shown_minus_target_shown': [],
                                   'hidden_minus_trial_end': [], 'written_minus_trial_end': [],
                                   'next_start_minus_written': []}
    targets = [(m['stamp'] - pc_minus_steady, m['active']) for m in person.messages('targets')]
    for r in rows:
        start, end = number(r['trial_start_s']), number(r['trial_end_s'])
        first = next((t for t, active in targets if t >= start - 1.0 and active), None)
        if first is not None:
            out['shown_minus_trial_start'].append(first - start)
        # the display as it was at the trial's end (every change is sent at once)
        before = [active for t, active in targets if t <= end]
        hidden = next((t for t, active in targets if t > end and not active), None)
        if before and before[-1] and hidden is not None:
            out['hidden_minus_trial_end'].append(hidden - end)
    for r, following in zip(rows, rows[1:] + [None]):
        written = datetime.fromisoformat(r['recorded_utc']).timestamp() - pc_minus_steady    # to the ms
        out['written_minus_trial_end'].append(written - number(r['trial_end_s']))
        if following is not None:
            out['next_start_minus_written'].append(number(following['trial_start_s']) - written)
    decided = [number(e['steady_s']) for e in shown]
    for s in person.seen:
        t = s.stamp - pc_minus_steady
        before = [d for d in decided if d <= t]
        if before:
            out['shown_minus_target_shown'].append(t - before[-1])
    return out


def summary(values: list[float]) -> dict:
    return {'n': len(values), 'p50': round(statistics.median(values), 3) if values else None,
            'max': round(max(values), 3) if values else None}
