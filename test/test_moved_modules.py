"""The modules that moved into packages keep their old paths for one release, with a warning
(fabric_guidance.MOVED, the one table the import hook and docs/architecture.md's move note use)."""
import importlib
import subprocess
import sys
import warnings

import pytest

import fabric_guidance
from fabric_guidance import MOVED


@pytest.mark.parametrize('old', sorted(MOVED))
def test_an_old_path_imports_the_moved_module_and_warns(old):
    if old.endswith('launch_support'):
        pytest.importorskip('launch.actions', reason='launch_support needs launch (the launch stage runs it)')
    sys.modules.pop(old, None)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        module = importlib.import_module(old)
    assert module is importlib.import_module(MOVED[old])
    assert module.__spec__.name == MOVED[old], 'the moved module keeps its own spec'
    assert any(issubclass(w.category, DeprecationWarning) and MOVED[old] in str(w.message) for w in caught)


def test_from_an_old_path_import_a_name():
    sys.modules.pop('fabric_guidance.process_graph', None)
    with pytest.warns(DeprecationWarning, match='fabric_guidance.graph.process_graph'):
        from fabric_guidance.process_graph import Graph
    from fabric_guidance.graph.process_graph import Graph as new
    assert Graph is new


def test_an_old_python_m_form_runs_the_moved_module_as_main():
    out = subprocess.run([sys.executable, '-W', 'always::DeprecationWarning', '-m', 'fabric_guidance.replay',
                          '--help'], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith('usage: fabric-guidance replay')
    assert 'fabric_guidance.replay moved to fabric_guidance.commands.replay' in out.stderr


def test_every_new_path_exists_and_no_old_file_is_left():
    for old, new in MOVED.items():
        assert importlib.util.find_spec(new) is not None, new
        stale = fabric_guidance.__path__[0] + '/' + old.rpartition('.')[2] + '.py'
        assert not importlib.util.find_spec(new).origin == stale
        assert not __import__('os').path.exists(stale), f'{stale} is still there'


def test_the_move_note_lists_the_table():
    from pathlib import Path
    text = (Path(__file__).resolve().parents[1] / 'docs' / 'architecture.md').read_text()
    missing = [old for old, new in MOVED.items() if f'| `{old}` | `{new}` |' not in text]
    assert not missing, f"docs/architecture.md's move note lacks {missing}"
