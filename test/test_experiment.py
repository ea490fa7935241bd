"""`fabric-guidance experiment`: a protocol run end to end writes its CSV, statistics, plots
and report, and refuses bad arguments with a clear message."""
import pandas as pd

from fabric_guidance.commands.cli import main


def test_speed_experiment_writes_everything(tmp_path, capsys):
    assert main(['experiment', '--protocol', 'speed', '--subjects', '3', '--out', str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert '[ 3/3]' in out                                          # progress
    assert out.startswith('scene paper-fitted-speed:')              # the README's population
    trials = pd.read_csv(tmp_path / 'trials.csv')
    assert len(trials) == 3 * 4 * 6                                 # wearers x conditions x repetitions
    assert set(trials['condition']) == {'surface_adjusted', 'surface_fixed', 'simple_adjusted', 'speech'}
    assert (trials['identified'] >= 0).all()
    stats = (tmp_path / 'statistics.txt').read_text()
    assert 'Friedman chi-square' in stats and 'Bonferroni' in stats
    assert (tmp_path / 'identified.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    report = (tmp_path / 'report.md').read_text()
    assert 'identified.png' in report and 'Friedman' in report
    # `analyze` reads the trials table the experiment wrote, to the same statistics.
    assert main(['analyze', str(tmp_path / 'trials.csv')]) == 0
    friedman = [line for line in stats.splitlines() if line.startswith('Friedman chi-square')]
    assert friedman and friedman[0] in capsys.readouterr().out


def test_accuracy_experiment_analyses_both_errors(tmp_path, capsys):
    assert main(['experiment', '--protocol', 'accuracy', '--subjects', '3', '--out', str(tmp_path)]) == 0
    stats = (tmp_path / 'statistics.txt').read_text()
    assert 'horizontal error' in stats and 'vertical error' in stats
    assert (tmp_path / 'h_error_deg.png').exists() and (tmp_path / 'v_error_deg.png').exists()
    capsys.readouterr()
    assert main(['analyze', str(tmp_path / 'trials.csv')]) == 0
    out = capsys.readouterr().out
    friedman = [line for line in stats.splitlines() if line.startswith('Friedman chi-square')]
    assert len(friedman) == 2 and all(line in out for line in friedman)
    assert 'accuracy: h_error_deg' in out and 'accuracy: v_error_deg' in out


def test_bad_arguments_are_refused(tmp_path, capsys):
    assert main(['experiment', '--out', str(tmp_path)]) == 2
    assert 'exactly one of --protocol or --scene' in capsys.readouterr().err
    assert main(['experiment', '--scene', 'no-such-scene', '--out', str(tmp_path)]) == 2
    assert main(['experiment', '--protocol', 'speed', '--subjects', '99', '--out', str(tmp_path)]) == 2
    assert "population" in capsys.readouterr().err


def test_an_out_folder_with_another_runs_files_is_refused_unless_overwrite(tmp_path, capsys):
    """experiment wrote over a results folder in silence, mixing the files of two runs."""
    (tmp_path / 'trials.csv').write_text('an earlier run\n')
    assert main(['experiment', '--protocol', 'speed', '--subjects', '1', '--out', str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f'fabric-guidance experiment: error: --out {tmp_path} already holds 1 file(s) (trials.csv): '
                   "another run's results would mix with this one's; give a new --out, or --overwrite to write "
                   'over them']
    assert (tmp_path / 'trials.csv').read_text() == 'an earlier run\n'
    # --overwrite passes the folder check: the next check (the population) is what refuses here.
    assert main(['experiment', '--protocol', 'speed', '--subjects', '99', '--out', str(tmp_path), '--overwrite']) == 2
    assert 'already holds' not in (err := capsys.readouterr().err) and 'population' in err
