"""`analyze STUDY_DIR` counts only trials that ended: a block cut off and not yet run again is
left out (named), a participant without every condition is left out (named), one participant
is reported, each value is within its column's range, each error names its file and line, and
each measure knows its direction."""
from __future__ import annotations

from pathlib import Path

import pytest

from fabric_guidance.experiments import analyze
from fabric_guidance.study.store import read_tsv
from test_study_store import DESIGN, run_participant  # noqa: E402 (test/ is on sys.path)


def trials_path(root: Path, pid: str) -> Path:
    return next((root / f'sub-{pid}').rglob(f'sub-{pid}_*_task-speed_beh.tsv'))


def whole(root: Path, *pids: str) -> None:
    for pid in pids:
        run_participant(root, pid)


def edit(path: Path, line: int, column: str, value: str) -> None:
    """Set one cell of a TSV (line: 1-based, the header is line 1)."""
    lines = path.read_text().split('\n')
    header = lines[0].split('\t')
    cells = lines[line - 1].split('\t')
    cells[header.index(column)] = value
    lines[line - 1] = '\t'.join(cells)
    path.write_text('\n'.join(lines))


def run(capsys, *args) -> tuple[int, str, str]:
    code = analyze.main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_a_block_cut_off_and_not_rerun_is_never_counted(tmp_path, capsys):
    root = tmp_path / 's'
    whole(root, 'P1', 'P2', 'P3')
    # P4: three blocks done, the fourth cut after its first trial (not yet run again): every
    # condition has an 'ok' row, but the last one's block did not end.
    run_participant(root, 'P4', stop_after=3 * DESIGN.trials + 1)
    rows = read_tsv(trials_path(root, 'P4'))[1]
    cut = rows[3 * DESIGN.trials]
    assert cut['status'] == 'ok'
    frame, _ = analyze.study_frame(root)
    assert cut['block'] not in set(frame.loc[frame['wearer'] == 'P4', 'block'])
    code, out, err = run(capsys, root, '--table', tmp_path / 't.csv')
    assert code == 0, err
    assert f'block {cut["block"]} did not finish: its 1 trial(s) are left out until it is run again' in out
    assert 'participant P4 is left out of identified: no finished trial in' in out
    assert '3 subjects (blocks) x 4 conditions' in out
    assert [ln.split(',')[0] for ln in (tmp_path / 't.csv').read_text().splitlines()[1:]] == ['P1', 'P2', 'P3']


def test_a_participant_without_every_condition_is_left_out_and_named(tmp_path, capsys):
    root = tmp_path / 's'
    whole(root, 'P1', 'P2', 'P3')
    run_participant(root, 'P4', stop_after=3)          # one block done, the second stopped
    code, out, err = run(capsys, root)
    assert code == 0, err
    assert 'participant P4 is left out of identified: no finished trial in' in out
    assert '3 subjects (blocks) x 4 conditions' in out


def test_one_participant_is_reported_and_its_table_written(tmp_path, capsys):
    root = tmp_path / 's'
    whole(root, 'P1')
    code, out, err = run(capsys, root, '--table', tmp_path / 't.csv')
    assert code == 0, err
    assert '1 participant: the Friedman test needs at least 2' in out
    table = (tmp_path / 't.csv').read_text().splitlines()
    assert table[0] == 'subject,surface_adjusted,surface_fixed,simple_adjusted,speech'
    assert table[1].startswith('P1,')


@pytest.mark.parametrize('column, value, why', [
    ('identified', '99', "identified '99' is more than presented"),
    ('identified', '-3', "identified '-3' is not a count"),
    ('presented', '2.5', "presented '2.5' is not a count"),
    ('mean_find_s', '-1.0', "mean_find_s '-1.0' is not within the trial (0 to 5 s)"),
    ('h_error_deg', '200.0', "h_error_deg '200.0' is not an error within the field"),
    ('condition', '7', "condition '7' is not a condition of the study"),
    ('identified', 'many', "identified 'many' is not a number"),
])
def test_a_value_out_of_its_range_is_one_line_naming_file_and_line(tmp_path, capsys, column, value, why):
    root = tmp_path / 's'
    whole(root, 'P1', 'P2')
    path = trials_path(root, 'P2')
    edit(path, 4, column, value)
    code, out, err = run(capsys, root)
    assert code == 2
    assert f'{path}: line 4: {why}' in err and err.count('\n') == 1, err


def test_a_cut_off_last_row_is_an_error_naming_it(tmp_path, capsys):
    root = tmp_path / 's'
    whole(root, 'P1', 'P2')
    path = trials_path(root, 'P1')
    text = path.read_text()
    path.write_text(text[:-40])                         # the last row lost its tail
    last = len(text.splitlines())
    code, out, err = run(capsys, root)
    assert code == 2
    assert f'{path}: line {last} is cut off' in err and err.count('\n') == 1, err


def test_a_folder_with_only_headers_says_so(tmp_path, capsys):
    root = tmp_path / 's'
    run_participant(root, 'P1', stop_after=0)
    path = trials_path(root, 'P1')
    path.write_text(path.read_text().split('\n')[0] + '\n')
    code, out, err = run(capsys, root)
    assert code == 2
    assert 'no trials recorded yet (every trials file holds only its header)' in err, err


def test_each_measure_knows_its_direction(tmp_path, capsys):
    root = tmp_path / 's'
    whole(root, 'P1', 'P2')
    code, out, err = run(capsys, root, '--measure', 'mean_find_s')
    assert code == 0, err
    assert '2 subjects (blocks) x 4 conditions; lower is better' in out
    code, out, err = run(capsys, root)
    assert '; higher is better' in out


def test_study_trials_counts_only_blocks_that_ended(tmp_path):
    from fabric_guidance.study.store import study_trials
    root = tmp_path / 's'
    run_participant(root, 'P1', stop_after=3)          # block 1 done, block 2 cut after one trial
    assert [r['block'] for r in study_trials(root)] == [r['block'] for r in read_tsv(trials_path(root, 'P1'))[1][:2]]
