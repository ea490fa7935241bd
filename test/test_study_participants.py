"""participants.tsv as researchers use it: their columns are kept through every registration,
the index is the package's alone (a hand-edited one is refused in one line naming the file and
line, never used), duplicates are refused, a spreadsheet's byte order mark is read."""
from __future__ import annotations

from pathlib import Path

import pytest

from fabric_guidance.study.store import Study, StudyError, read_tsv
from test_study_store import DESIGN, run_participant  # noqa: E402 (test/ is on sys.path)


def lines(root: Path) -> list[list[str]]:
    return [ln.split('\t') for ln in (root / 'participants.tsv').read_text(encoding='utf-8-sig').splitlines()]


def write(root: Path, rows: list[list[str]], bom: bool = False) -> None:
    text = '\n'.join('\t'.join(r) for r in rows) + '\n'
    (root / 'participants.tsv').write_text(('\ufeff' if bom else '') + text, encoding='utf-8')


def one_line_error(call) -> str:
    with pytest.raises(StudyError) as info:
        call()
    text = str(info.value)
    assert '\n' not in text and 'Traceback' not in text
    return text


def test_a_researchers_columns_are_kept_in_order_through_every_registration(tmp_path):
    root = tmp_path / 's'
    study = Study.open(root)
    study.add_participant('P1')
    (pid, index, utc), (p1, i1, u1) = lines(root)
    # the researcher adds age (before index), handedness and notes (after), and fills P1's
    write(root, [[pid, 'age', index, utc, 'handedness', 'notes'], [p1, '34', i1, u1, 'left', 'wore glasses']])
    study.add_participant('P2')
    run_participant(root, 'P3')                         # a session registers too
    header, rows = read_tsv(root / 'participants.tsv')
    assert header == ['participant_id', 'age', 'index', 'registered_utc', 'handedness', 'notes']
    assert rows[0] == {'participant_id': 'sub-P1', 'age': '34', 'index': '0', 'registered_utc': u1,
                       'handedness': 'left', 'notes': 'wore glasses'}
    assert [(r['participant_id'], r['index'], r['age'], r['notes']) for r in rows[1:]] == \
        [('sub-P2', '1', 'n/a', 'n/a'), ('sub-P3', '2', 'n/a', 'n/a')]
    assert [p.index for p in Study.open(root).participants()] == [0, 1, 2]


def test_a_swapped_index_is_refused_naming_file_and_line(tmp_path):
    root = tmp_path / 's'
    run_participant(root, 'P1', stop_after=1)
    run_participant(root, 'P2', stop_after=1)
    (h, a, b) = lines(root)
    a[1], b[1] = b[1], a[1]
    write(root, [h, a, b])
    text = one_line_error(lambda: Study.open(root).participants())
    assert f"{root / 'participants.tsv'}: line 2: index '1' of sub-P1 is not its registration order (0)" in text
    # the session path refuses it as well, and never runs P2 on P1's order and targets
    one_line_error(lambda: run_participant(root, 'P2'))
    one_line_error(lambda: Study.open(root).add_participant('P3'))


def test_rows_and_indices_swapped_together_are_refused_by_the_sidecar(tmp_path):
    root = tmp_path / 's'
    run_participant(root, 'P1', stop_after=1)
    run_participant(root, 'P2', stop_after=1)
    (h, a, b) = lines(root)
    a[0], b[0] = b[0], a[0]                             # P2 now reads as registered first
    write(root, [h, a, b])
    text = one_line_error(lambda: Study.open(root).session('P1', 1, DESIGN))
    assert 'participant index 0 recorded, participants.tsv gives 1' in text and 'sub-P1_ses-1' in text


def test_duplicates_are_refused(tmp_path):
    root = tmp_path / 's'
    study = Study.open(root)
    study.add_participant('P1')
    study.add_participant('P2')
    (h, a, b) = lines(root)
    write(root, [h, a, [a[0], b[1], b[2]]])
    text = one_line_error(lambda: Study.open(root).participants())
    assert 'line 3: sub-P1 is registered twice (also line 2)' in text


def test_a_byte_order_mark_is_read(tmp_path):
    root = tmp_path / 's'
    study = Study.open(root)
    study.add_participant('P1')
    write(root, lines(root), bom=True)
    assert [p.participant_id for p in Study.open(root).participants()] == ['P1']
    assert Study.open(root).add_participant('P2').index == 1


def test_a_file_without_the_packages_columns_is_refused(tmp_path):
    root = tmp_path / 's'
    Study.open(root).add_participant('P1')
    write(root, [['participant_id', 'age'], ['sub-P1', '30']])
    text = one_line_error(lambda: Study.open(root).participants())
    assert 'participants.tsv: line 1: no column index' in text


def test_study_simulated_refuses_a_swapped_index_in_one_line(tmp_path, capsys):
    from fabric_guidance.live_study.study_command import main as study_main
    root = tmp_path / 's'
    study = Study.open(root)
    study.add_participant('01')
    study.add_participant('02')
    (h, a, b) = lines(root)
    a[1], b[1] = b[1], a[1]
    write(root, [h, a, b])
    code = study_main(['--simulated', '--participants', '2', '--trials', '1', '--trial-s', '2', '--out', str(root)])
    err = capsys.readouterr().err
    assert code == 1 and 'Traceback' not in err and err.count('\n') == 1, err
    assert "participants.tsv: line 2: index '1' of sub-01 is not its registration order (0)" in err
    assert not (root / 'sourcedata').exists()          # refused before any graph started
