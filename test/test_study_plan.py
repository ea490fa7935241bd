"""The study's plan: participant ids, condition orders (random as the headless experiment's,
balanced Latin square), trials and their targets (the headless experiment's, common random
numbers), and that the study's modules load no ROS."""
from __future__ import annotations

import itertools
import subprocess
import sys

import pytest

from fabric_guidance.sim import protocols
from fabric_guidance.sim.scene import load_scene
from fabric_guidance.study.plan import (StudyDesign, balanced_latin_square, check_participant, condition_order,
                                        order_counts, participant_blocks, target_stream)


def test_the_study_modules_load_no_ros():
    code = ('import sys\n'
            'import fabric_guidance.study, fabric_guidance.study.plan, fabric_guidance.study.session, '
            'fabric_guidance.study.store, fabric_guidance.study.trial_columns, fabric_guidance.experiments.analyze\n'
            'bad = sorted(m for m in sys.modules if m.split(".")[0] in ("rclpy", "rosidl_runtime_py"))\n'
            'print(bad)\n'
            'sys.exit(1 if bad else 0)\n')
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr


@pytest.mark.parametrize('pid', ['01', 'P7', 'alice', 'A' * 64])
def test_participant_ids_that_are_file_names_and_bids_labels(pid):
    assert check_participant(pid) == pid


@pytest.mark.parametrize('pid, why', [('', 'letters'), ('a_b', 'BIDS'), ('sub-01', 'BIDS'), ('a.b', 'BIDS'),
                                      ('../x', 'letters'), ('A' * 65, 'letters'), (7, 'letters'), ('a b', 'letters')])
def test_participant_ids_refused_in_one_line(pid, why):
    with pytest.raises(ValueError, match=why) as info:
        check_participant(pid, 'participant')
    assert '\n' not in str(info.value) and str(info.value).startswith('participant ')


def test_the_paper_defaults_and_bad_designs():
    assert StudyDesign('speed').trials == 6 and StudyDesign('speed').trial_s == 40.0
    assert StudyDesign('speed').acceptance_deg == 5.0
    assert StudyDesign('accuracy').trials == 10
    for kwargs, msg in [(dict(protocol='walk'), 'protocol'), (dict(protocol='speed', trials=0), 'trials'),
                        (dict(protocol='speed', trial_s=0), 'trial_s'), (dict(protocol='speed', conditions=(1, 1)),
                                                                         'distinct'),
                        (dict(protocol='speed', conditions=(1, 5)), 'condition'),
                        (dict(protocol='speed', order='latin', conditions=(1, 2, 3)), 'even'),
                        (dict(protocol='speed', seed=-1), 'seed'), (dict(protocol='speed', rest_s=float('nan')),
                                                                    'rest_s')]:
        with pytest.raises(ValueError, match=msg):
            StudyDesign(**kwargs)
    d = StudyDesign('accuracy', seed=4, order='latin')
    assert StudyDesign.from_dict(d.as_dict()) == d
    with pytest.raises(ValueError, match='unknown parameter'):
        StudyDesign.from_dict({**d.as_dict(), 'colour': 1}, 'x.json')


@pytest.mark.parametrize('n', [2, 4, 6])
def test_the_latin_square_is_balanced(n):
    square = balanced_latin_square(n)
    assert len(square) == n
    for pos in range(n):
        assert sorted(row[pos] for row in square) == list(range(n))       # each once per position
    follows = [(row[i], row[i + 1]) for row in square for i in range(n - 1)]
    assert sorted(follows) == sorted(itertools.permutations(range(n), 2))  # each pair once


def test_latin_orders_over_participants_are_balanced():
    d = StudyDesign('speed', order='latin')
    orders = [condition_order(d, i) for i in range(8)]
    assert (order_counts(orders) == 2).all()
    assert orders[0] == (1, 2, 4, 3) and orders[4] == orders[0]


def test_the_random_order_is_the_headless_experiments_for_the_same_seed():
    scene = load_scene('paper-speed')
    d = StudyDesign('speed', seed=scene.seed, conditions=scene.conditions)
    orders = [condition_order(d, i) for i in range(12)]
    assert orders == [protocols.condition_order(scene, i) for i in range(12)]
    assert len(set(orders)) > 3                                            # it does vary per participant
    assert condition_order(StudyDesign('speed', seed=scene.seed + 1), 0) != orders[0] or \
        condition_order(StudyDesign('speed', seed=scene.seed + 1), 1) != orders[1]


def test_the_targets_are_the_headless_experiments_and_the_same_in_every_condition():
    scene = load_scene('paper-accuracy')
    d = StudyDesign('accuracy', seed=scene.seed)
    blocks = participant_blocks(d, 'P3', 3)
    for rep in range(d.trials):
        headless = protocols.draw_target(protocols.target_stream(scene, 3, rep), scene.protocol)
        assert {b.trials[rep].target for b in blocks} == {headless}
    every = [t for b in blocks for t in (s.target for s in b.trials)]
    assert all(abs(h) <= 60 and abs(v) <= 30 for h, v in every)
    assert len({t for t in every}) == d.trials                             # new per repetition
    speed = load_scene('paper-speed')
    stream = target_stream(StudyDesign('speed', seed=speed.seed), 2, 4)
    rng = protocols.target_stream(speed, 2, 4)
    assert [next(stream) for _ in range(5)] == [protocols.draw_target(rng, speed.protocol) for _ in range(5)]


def test_blocks_are_the_participants_conditions_in_order():
    d = StudyDesign('speed', seed=9, trials=3)
    blocks = participant_blocks(d, 'P1', 5, session=2)
    assert tuple(b.condition for b in blocks) == condition_order(d, 5)
    assert [b.order for b in blocks] == [1, 2, 3, 4] and all(b.session == 2 for b in blocks)
    assert all([s.repetition for s in b.trials] == [0, 1, 2] and b.trials[0].target is None for b in blocks)
    assert len({b.key for b in blocks}) == 4
    with pytest.raises(ValueError, match='participant'):
        participant_blocks(d, 'P_1', 0)


def test_press_sources_parse_and_round_trip_through_the_sidecars_dict():
    from fabric_guidance.study.plan import PRESS_SOURCES, parse_press_sources
    assert parse_press_sources('all') == () and parse_press_sources('') == ()
    assert parse_press_sources('keyboard, headset,keyboard') == ('headset', 'keyboard')
    with pytest.raises(ValueError, match="unknown press source 'clicker': one of " + ', '.join(PRESS_SOURCES)):
        parse_press_sources('keyboard,clicker')
    d = StudyDesign('speed', press_sources=('keyboard',))
    assert d.as_dict()['press_sources'] == ['keyboard'] and StudyDesign.from_dict(d.as_dict()) == d
    assert StudyDesign.from_dict({k: v for k, v in d.as_dict().items() if k != 'press_sources'}).press_sources == ()
    assert d.judges('keyboard') and not d.judges('headset') and not d.judges('ros')
    for bad in ('keyboard', ['clicker'], [3]):
        with pytest.raises(ValueError, match='press'):
            StudyDesign.from_dict({'protocol': 'speed', 'press_sources': bad}, 'side.json')
