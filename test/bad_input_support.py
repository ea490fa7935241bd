"""What the bad-input tests share (test_bad_input.py: files, node start-up, the gaze wire, the
graph's sockets; test_bad_bags.py: recorded bags and their replay): the command line run in this
process with the one-line error it must end in, and hypothesis's mutations of a file's bytes."""
from __future__ import annotations

import subprocess

from hypothesis import HealthCheck, settings, strategies as st

from rosgraph import CONFIG

SIM_CAL = CONFIG / 'calibrations' / 'sim-wearer.yaml'


def cli(*args) -> subprocess.CompletedProcess:
    """fabric-guidance ARGS in this process (the imports are paid once): its exit code and
    output; an exception that escapes is reported as the traceback a user would see."""
    import contextlib
    import io
    import traceback
    from fabric_guidance.commands.cli import main
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            if args[0] == 'replay':   # replay.run binds sys.stdout at import: hand it the stream
                import argparse
                from fabric_guidance.commands import replay
                parser = argparse.ArgumentParser(prog='fabric-guidance')
                replay.add_parser(parser.add_subparsers(dest='command', required=True))
                code = replay.run(parser.parse_args([str(a) for a in args]), stream=out)
            else:
                code = main([str(a) for a in args])
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else 1
        except Exception:  # noqa: BLE001 - what the user would get
            traceback.print_exc(file=err)
            code = 1
    return subprocess.CompletedProcess(args, code, out.getvalue(), err.getvalue())


def one_line_error(proc: subprocess.CompletedProcess, *words: str) -> str:
    """The process failed with exactly one line on stderr/stdout naming each of `words`."""
    out = (proc.stderr + proc.stdout).strip()
    assert proc.returncode != 0, out[-2000:]
    assert 'Traceback' not in out, out[-2000:]
    lines = [line for line in out.splitlines() if line.strip()]
    assert len(lines) == 1, out[-2000:]
    for w in words:
        assert w in lines[0], lines[0]
    assert len(lines[0]) < 400, lines[0]
    return lines[0]


#: A reader of a few-kB file stays far below this, whatever the file holds.
PEAK_BYTES = 64 * 1024 ** 2
SETTINGS = settings(derandomize=True, max_examples=30, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


def mutate(original: bytes, data) -> bytes:
    kind = data.draw(st.sampled_from(['truncate', 'flip', 'splice', 'random']))
    if kind == 'truncate':
        return original[:data.draw(st.integers(0, len(original)))]
    if kind == 'flip':
        out = bytearray(original)
        for _ in range(data.draw(st.integers(1, 8))):
            i = data.draw(st.integers(0, len(out) - 1))
            out[i] = data.draw(st.integers(0, 255))
        return bytes(out)
    if kind == 'splice':
        i = data.draw(st.integers(0, len(original)))
        return original[:i] + data.draw(st.binary(max_size=64)) + original[i:]
    return data.draw(st.binary(max_size=2048))
