"""fit-wearer: the paper's targets come from its table, the fit runs end to end and writes scenes
that load, and the shipped fitted speed scene reproduces the paper's four means within the
paper's standard errors (the check that could fail)."""
import math
from pathlib import Path
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from fabric_guidance.experiments import fit_wearer
from fabric_guidance.sim.protocols import run_protocol, summarize
from fabric_guidance.sim.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
TABLE = ROOT / 'test' / 'data' / 'table-identified-targets.csv'


def test_the_targets_are_the_tables_column_means_and_standard_errors():
    mean, se, n = fit_wearer.paper_targets(TABLE)
    table = pd.read_csv(TABLE)
    cols = list(fit_wearer.COLUMNS)
    assert n == len(table) == 15
    np.testing.assert_allclose(mean, table[cols].mean().to_numpy())
    np.testing.assert_allclose(se, table[cols].std(ddof=1).to_numpy() / math.sqrt(15))


def test_a_table_without_a_condition_column_is_one_line_naming_it(tmp_path):
    bad = tmp_path / 'bad.csv'
    bad.write_text('subject,surface_adjusted,surface_fixed,speech\nA,1,2,3\nB,2,3,4\n')
    with pytest.raises(SystemExit, match=r'bad\.csv: column "simple_adjusted" is missing'):
        fit_wearer.paper_targets(bad)
    bad.write_text('subject,surface_adjusted,surface_fixed,simple_adjusted,speech\n'
                   'A,1,2,x,3\nB,2,3,4,5\n')
    with pytest.raises(SystemExit, match=r'bad\.csv: a value is not a number'):
        fit_wearer.paper_targets(bad)


def test_the_free_parameters_map_the_unit_cube_onto_their_bounds():
    for free in fit_wearer.FREE:
        assert free.value(0.0) == pytest.approx(free.lo)
        assert free.value(1.0) == pytest.approx(free.hi)
        assert free.value(free.unit(free.start)) == pytest.approx(free.start)
        assert free.value(-1.0) == pytest.approx(free.lo)     # clipped to the bounds


def test_fit_wearer_runs_end_to_end_and_writes_scenes_that_load(tmp_path):
    proc = subprocess.run([sys.executable, '-m', 'fabric_guidance.experiments.fit_wearer',
                           '--budget', '2', '--subjects', '2', '--workers', '1',
                           '--out', str(tmp_path)],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    evals = [line for line in proc.stdout.splitlines() if line.startswith('eval ')]
    assert len(evals) == 2 and all('objective' in line for line in evals)
    speed = load_scene(tmp_path / 'paper-fitted-speed.yaml')
    accuracy = load_scene(tmp_path / 'paper-fitted-accuracy.yaml')
    assert speed.protocol.kind == 'speed' and accuracy.protocol.kind == 'accuracy'
    for free in fit_wearer.FREE:
        # The same human parameters in both scenes.
        assert speed.effect(free.effect).params_dict[free.param] == \
            accuracy.effect(free.effect).params_dict[free.param]
    for name in fit_wearer.MODEL_EFFECTS:
        assert speed.effect(name) is not None and accuracy.effect(name) is not None
    text = (tmp_path / 'paper-fitted-speed.yaml').read_text()
    assert 'Objective' in text and 'seed 2025' in text


def test_the_fitted_speed_scene_reproduces_each_paper_mean_within_the_papers_se():
    scene = load_scene('paper-fitted-speed')
    summary = summarize(run_protocol(scene, workers=2))
    means = np.array([summary[c]['identified'] for c in (1, 2, 3, 4)])
    target, se, _ = fit_wearer.paper_targets(TABLE)
    assert np.all(np.abs(means - target) <= se), (means, target, se)


def test_the_fitted_accuracy_scene_ends_where_the_paper_does():
    """The paper: every mean error below 30 deg, speech the most accurate. A misreading wearer
    presses where they believe the target is, within the protocol's time (no wearer wanders
    until the timeout: a re-read for a target 'not seen' would make them, as nothing is seen)."""
    summary = summarize(run_protocol(load_scene('paper-fitted-accuracy'), workers=2))
    for c in (1, 2, 3, 4):
        assert summary[c]['h_error_deg'] < 30.0 and summary[c]['v_error_deg'] < 30.0, summary[c]
        assert summary[c]['timed_out'] == 0.0
    for c in (1, 2, 3):
        assert summary[4]['h_error_deg'] < summary[c]['h_error_deg']
        assert summary[4]['v_error_deg'] < summary[c]['v_error_deg']


def test_without_a_table_the_targets_are_the_papers_as_shipped():
    """An installed package has no test/: the default is experiments.paper, the same numbers."""
    from fabric_guidance.experiments import paper
    mean, se, n = fit_wearer.paper_targets()
    csv_mean, csv_se, _ = fit_wearer.paper_targets(TABLE)
    np.testing.assert_allclose(mean, csv_mean)
    np.testing.assert_allclose(se, csv_se)
    assert n == 15 and list(mean) == [paper.speed_means()[c] for c in (1, 2, 3, 4)]
