"""ament's flake8 check over the package, its tests and launch files, as `colcon test` runs it in
a ROS workspace (ament_flake8 from the package index here). The rules are setup.cfg's [flake8]
section: pycodestyle and pyflakes at 120 columns (why 120: the comment there)."""
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
main_with_errors = pytest.importorskip('ament_flake8.main', reason='ament_flake8 is not installed '
                                       '(requirements/test.txt has it; rosdep: ament_flake8)').main_with_errors


@pytest.mark.flake8
@pytest.mark.linter
def test_flake8():
    paths = [str(ROOT / p) for p in ('fabric_guidance', 'test', 'launch', 'setup.py')]
    rc, errors = main_with_errors(argv=['--config', str(ROOT / 'setup.cfg'), *paths])
    assert rc == 0, f'{len(errors)} flake8 finding(s):\n' + '\n'.join(errors)
