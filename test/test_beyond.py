"""Both Discussion studies on the same wearers (experiments/discussion/studies.py) and the `beyond`
command (experiments/discussion/beyond.py); each study alone: test_study_per_wearer_gain.py,
test_study_moving_targets.py."""
import pandas as pd

from fabric_guidance.experiments.discussion import beyond as beyond_cmd
from fabric_guidance.experiments.discussion.studies import StudySettings, run_studies
from fabric_guidance.experiments.discussion.moving_targets import LAWS

from study_scenes import short


TINY = StudySettings(grid=(0.05, 0.3), tuning_reps=1, evaluation_reps=1, speeds_dps=(20.0,), moving_reps=1,
                     moving_s=4.0)


def test_the_study_is_deterministic_for_any_number_of_workers():
    sc = short(trial_s=8.0)
    a = run_studies(sc, 2, TINY, workers=1)
    b = run_studies(sc, 2, TINY, workers=2)
    pd.testing.assert_frame_equal(a.gain_grid_frame(), b.gain_grid_frame())
    pd.testing.assert_frame_equal(a.moving_frame(), b.moving_frame())
    assert [w.tuned_gain for w in a.wearers] == [w.tuned_gain for w in b.wearers]
    ev = a.gain_trials_frame()
    assert set(ev['condition']) == {'paper', 'own', 'oracle'} and set(ev['phase']) == {'evaluation'}


def test_beyond_quick_writes_the_report_csvs_and_pngs(tmp_path, capsys):
    out = tmp_path / 'beyond'
    assert beyond_cmd.main(['--out', str(out), '--quick']) == 0
    printed = capsys.readouterr().out
    assert 'Per-wearer gain' in printed and 'Moving target' in printed and 'report:' in printed
    report = (out / 'beyond.md').read_text()
    for heading in ('## Summary', '## 1. Per-wearer adjustment gain', '## 2. Moving targets', 'Friedman test',
                    'Dunn-Bonferroni'):
        assert heading in report
    pngs = sorted(p.name for p in out.glob('*.png'))
    assert 'gain_identified.png' in pngs and len(pngs) == 1 + 2 * 2 * 2     # 2 scenarios x 2 speeds x 2 measures
    for name in pngs:
        assert f']({name})' in report and (out / name).read_bytes()[:4] == b'\x89PNG'
    grid = pd.read_csv(out / 'gain_grid.csv')
    assert set(grid['phase']) == {'tuning', 'evaluation'} and grid['subject'].nunique() == 3
    moving = pd.read_csv(out / 'moving_trials.csv')
    assert set(moving['law']) == set(LAWS) and set(moving['scenario']) == {'seen', 'unseen'}
    assert {'find_s', 'tracking_error_deg', 'late_error_deg', 'found'} <= set(moving.columns)
    choice = pd.read_csv(out / 'gain_choice.csv')
    assert len(choice) == 3 and set(choice['tuned_gain']) <= {0.0, 0.05, 0.2, 0.5}
    assert not pd.read_csv(out / 'gain_trials.csv').empty


def test_beyond_refuses_a_non_speed_scene_and_too_few_wearers(tmp_path, capsys):
    assert beyond_cmd.main(['--out', str(tmp_path), '--scene', 'paper-accuracy', '--quick']) == 2
    assert beyond_cmd.main(['--out', str(tmp_path), '--subjects', '1', '--quick']) == 2
    err = capsys.readouterr().err
    assert 'speed scene' in err and '--subjects' in err
