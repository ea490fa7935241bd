"""`fabric-guidance demo` leaves nothing behind in the temporary folder, a failed demo too, and
keeps its logs where --out names a folder."""
import io
import tempfile

from fabric_guidance.commands.demo import run_demo


def test_failed_demo_removes_its_temporary_folder(tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, 'tempdir', str(tmp_path))
    out = io.StringIO()
    # Fails before any process starts (condition 4 needs a scene), after the folder is made.
    assert run_demo(4, stream=out) == 2
    assert 'condition 4 (speech) needs --scene' in out.getvalue()
    assert run_demo(scene='no-such-scene', stream=out) == 2
    assert list(tmp_path.iterdir()) == []


def test_out_folder_is_kept(tmp_path):
    logs = tmp_path / 'logs'
    assert run_demo(4, out_dir=logs, stream=io.StringIO()) == 2
    assert logs.is_dir()
