"""The violin plot, the markdown report and the `analyze` command (in process and as a process)."""
from __future__ import annotations

import argparse
from pathlib import Path
import subprocess
import sys

from matplotlib import image
import pandas as pd
import pytest

from fabric_guidance.experiments import analyze
from fabric_guidance.experiments.violin_plots import _groups, _stack, violin_plot
from fabric_guidance.experiments.analysis_report import markdown_report
from fabric_guidance.experiments.stats import analyze_blocks, analyze_trials
from test_stats import PAPER_CSV, paper_table, trials_from, write  # noqa: E402 (test/ is on sys.path)

ROOT = Path(__file__).resolve().parent.parent
PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'


def assert_png(path: Path, min_bytes: int = 10_000) -> None:
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE
    assert len(data) > min_bytes
    pixels = image.imread(path)  # decodes: a whole, valid file
    assert pixels.shape[0] > 300 and pixels.shape[1] > 500
    assert pixels.std() > 0.05  # not a blank canvas


# ------------------------------------------------------------------------ (f) plot and report

def test_violin_plot_of_the_paper_table(tmp_path):
    a = analyze_blocks(paper_table())
    out = violin_plot(a, 'identified target objects', tmp_path / 'targets.png', significance=a)
    assert out == tmp_path / 'targets.png'
    assert_png(out)


def test_violin_plot_takes_a_table_trials_and_a_mapping(tmp_path):
    t = paper_table().astype(float)
    assert_png(violin_plot(t, 'targets', tmp_path / 'table.png'))
    trials = trials_from(t)
    a = analyze_trials(trials, 'targets')
    assert_png(violin_plot(trials, 'targets per trial', tmp_path / 'trials.png', significance=a.pairwise))
    assert_png(violin_plot(t, 'targets', tmp_path / 'map.png',
                           significance={('surface_adjusted', 'speech'): 0.0004, ('surface_fixed', 'speech'): 0.2}))
    with pytest.raises(ValueError, match='measure='):
        violin_plot(trials.assign(other=1.0), 'x', tmp_path / 'no.png')


def test_trials_are_plotted_in_the_paper_order():
    trials = trials_from(paper_table().astype(float))  # shuffled
    names, groups = _groups(trials, 'targets')
    assert names == ['surface_adjusted', 'surface_fixed', 'simple_adjusted', 'speech']
    assert [len(g) for g in groups] == [45] * 4


def test_violin_plot_draws_a_condition_without_spread(tmp_path):
    t = pd.DataFrame({'a': [1.0, 1.0, 1.0], 'b': [1.0, 2.0, 4.0]})  # no KDE for a single value
    assert_png(violin_plot(t, 'x', tmp_path / 'flat.png'), min_bytes=5_000)


def test_brackets_do_not_overlap():
    # (0,1) and (2,3) share a level; (0,3) spans both and goes above; (1,2) fits at level 0.
    placed = {(i, j): level for i, j, _, level in _stack([(0, 3, .01), (0, 1, .01), (2, 3, .01), (1, 2, .01)])}
    assert placed[(0, 1)] == 0 and placed[(2, 3)] == 0
    assert placed[(1, 2)] == 1 and placed[(0, 3)] == 2


def test_markdown_report_has_the_tables_and_the_plot(tmp_path):
    a = analyze_blocks(paper_table())
    (tmp_path / 'figs').mkdir()
    png = violin_plot(a, 'targets', tmp_path / 'figs' / 'targets.png', significance=a)
    text = markdown_report('Speed experiment', {'Identified targets': a}, {'Identified targets': png},
                           notes=['Means per subject over 6 trials.'], relative_to=tmp_path)
    assert text.startswith('# Speed experiment\n')
    assert '- Means per subject over 6 trials.' in text
    assert '## Identified targets' in text
    assert '| condition | mean | SD | median | mean rank | best for |' in text
    assert '| 1 surface, adjusted | 10.71 | 2.37 | 10.70 | 3.533 | 10 |' in text
    assert 'chi-square = 16.837, df = 3, p = 7.64e-04' in text
    assert '| 1 surface, adjusted | 4 speech | +1.900 | +4.031 | 5.57e-05 | 3.34e-04 | *** |' in text
    assert '| 1 surface, adjusted | 2 surface, fixed | +1.133 | +2.404 | 0.0162 | 0.0973 | ns |' in text
    assert '| 2 surface, fixed | 4 | A B (tie) D M |' in text
    assert '![Identified targets](figs/targets.png)' in text
    extra = markdown_report('t', {}, {'loose': png})
    assert '## Figures' in extra and f'![loose]({png.as_posix()})' in extra


# ------------------------------------------------------------------------ the command in process

def test_add_parser_and_run(tmp_path, capsys):
    parser = argparse.ArgumentParser(prog='fabric-guidance')
    sub = parser.add_subparsers(dest='command', required=True)
    analyze.add_parser(sub)
    csv = write(tmp_path, PAPER_CSV)
    args = parser.parse_args(['analyze', str(csv), '--plot', str(tmp_path / 'v.png'),
                              '--report', str(tmp_path / 'r.md'), '--label', 'identified targets'])
    assert args.command == 'analyze'
    assert analyze.run(args) == 0
    out = capsys.readouterr().out
    assert 'Friedman chi-square = 16.837' in out and f'plot: {tmp_path / "v.png"}' in out
    assert_png(tmp_path / 'v.png')
    report = (tmp_path / 'r.md').read_text()
    assert '![identified targets](v.png)' in report and '| 4 speech | 8.38 |' in report


def test_lower_is_better_flag(tmp_path, capsys):
    assert analyze.main([str(write(tmp_path, PAPER_CSV)), '--lower-is-better']) == 0
    out = capsys.readouterr().out
    assert 'lower is better' in out and 'smallest value' in out


def test_unwritable_plot_is_exit_1(tmp_path, capsys):
    assert analyze.main([str(write(tmp_path, PAPER_CSV)), '--plot', str(tmp_path / 'no' / 'v.png')]) == 1
    assert 'cannot write' in capsys.readouterr().err


# ------------------------------------------------------------------------ (g) the command as a process

def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', 'fabric_guidance.experiments.analyze', *args],
                          capture_output=True, text=True, cwd=ROOT, timeout=120)


def test_analyze_end_to_end_on_the_paper_table(tmp_path):
    csv = write(tmp_path, PAPER_CSV, 'table-identified-targets.csv')
    res = run_cli(str(csv), '--plot', str(tmp_path / 'targets.png'))
    assert res.returncode == 0, res.stderr
    assert res.stderr == ''
    out = res.stdout
    assert '15 subjects (blocks) x 4 conditions; higher is better' in out
    assert 'Friedman chi-square = 16.837, df = 3, p = 7.64e-04' in out
    assert "Kendall's W = 0.374" in out
    for needle in ('+2.404    0.0162        0.0973       ns', '+2.333    0.0196        0.1177       ns',
                   '+4.031  5.57e-05      3.34e-04      ***'):
        assert needle in out
    assert '1 surface, adjusted       10  B(tie) C E F H I J K L O' in out
    assert '2 surface, fixed           4  A B(tie) D M' in out
    assert_png(tmp_path / 'targets.png')


@pytest.mark.parametrize('text, message', [
    ('subject,a,b\ns1,1,\ns2,3,4\n', 'missing value at subject s1, condition b'),
    ('subject,a\ns1,1\ns2,2\n', 'at least 2 condition columns'),
    ('subject,a,b\ns1,x,2\ns2,3,4\n', "non-numeric value at subject s1, condition a ('x')"),
])
def test_analyze_bad_table_is_one_line_and_exit_2(tmp_path, text, message):
    res = run_cli(str(write(tmp_path, text)))
    assert res.returncode == 2
    assert res.stdout == ''
    lines = res.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith('fabric-guidance analyze: error: ') and message in lines[0]


def test_analyze_missing_file_is_exit_2(tmp_path):
    res = run_cli(str(tmp_path / 'nope.csv'))
    assert res.returncode == 2 and 'No such file' in res.stderr and len(res.stderr.splitlines()) == 1
