"""The `fabric-guidance` command line: one table of subcommands, each module imported only when
its subcommand runs (so `bench` works without scikit-posthocs, `example` without pandas)."""
from __future__ import annotations

import argparse
from importlib import import_module
import json
import subprocess
import sys

import pytest

from fabric_guidance.commands.cli import SUBCOMMANDS

#: Imported by the statistics and plotting subcommands only.
HEAVY = ('pandas', 'scikit_posthocs', 'matplotlib')

PROBE = '''
import json, sys
from fabric_guidance.commands.cli import main
try:
    main(sys.argv[1:])
except SystemExit:
    pass
print(json.dumps({"heavy": sorted(m for m in %r if m in sys.modules),
                  "modules": sorted(m for m in sys.modules if m.startswith("fabric_guidance"))}))
''' % (HEAVY,)


def probe(*argv: str) -> dict:
    """Run `fabric-guidance ARGV` in a fresh interpreter; what it had imported at the end."""
    out = subprocess.run([sys.executable, '-c', PROBE, *argv], capture_output=True, text=True,
                         timeout=120, check=True)
    return out.stdout, json.loads(out.stdout.strip().splitlines()[-1])


def test_help_lists_every_subcommand_without_importing_one():
    stdout, loaded = probe('--help')
    for name, (_, help_text) in SUBCOMMANDS.items():
        assert name in stdout
        assert ' '.join(help_text.split()[:3]) in ' '.join(stdout.split())
    assert loaded['heavy'] == []
    subcommand_modules = {module for module, _ in SUBCOMMANDS.values()}
    assert subcommand_modules.isdisjoint(loaded['modules'])


@pytest.mark.parametrize('name', ['example', 'bench', 'replay', 'demo', 'dry-run'])
def test_a_light_subcommand_imports_only_its_own_module(name):
    stdout, loaded = probe(name, '--help')
    assert f'usage: fabric-guidance {name}' in stdout
    assert loaded['heavy'] == []
    others = {module for other, (module, _) in SUBCOMMANDS.items() if other != name}
    assert SUBCOMMANDS[name][0] in loaded['modules']
    assert others.isdisjoint(loaded['modules'])


def test_every_module_lists_itself_with_the_tables_help():
    """The table's one line is what the module's own add_parser says (no drift between them)."""
    for name, (module, help_text) in SUBCOMMANDS.items():
        sub = argparse.ArgumentParser().add_subparsers()
        import_module(module).add_parser(sub)
        listed = {action.dest: action.help for action in sub._choices_actions}
        assert listed == {name: help_text}


def test_an_unknown_subcommand_is_argparses_one_line_error(capsys):
    from fabric_guidance.commands.cli import main
    with pytest.raises(SystemExit) as exc:
        main(['no-such-command'])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith('fabric-guidance: error: argument command: invalid choice')


def test_a_mistyped_option_prints_the_subcommands_usage(tmp_path, capsys):
    from fabric_guidance.commands.cli import main
    table = tmp_path / 't.csv'
    table.write_text('subject,1,2\nS01,1,2\n')
    with pytest.raises(SystemExit) as exc:
        main(['analyze', str(table), '--plto', 'x.png'])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith('usage: fabric-guidance analyze')
    assert err.strip().splitlines()[-1] == 'fabric-guidance analyze: error: unrecognized arguments: --plto x.png'


def test_sigterm_ends_a_command_as_ctrl_c_does_so_its_clean_up_runs():
    """soak, chaos, demo and bench stop their graph in `finally`; a SIGTERM that killed the
    process outright left the nodes running (seen with a soak run)."""
    import os
    import signal

    from fabric_guidance import subcommand
    before = signal.getsignal(signal.SIGTERM)
    cleaned = []
    try:
        subcommand.stop_on_sigterm()
        with pytest.raises(KeyboardInterrupt):
            try:
                os.kill(os.getpid(), signal.SIGTERM)   # its handler runs before kill returns here
            finally:
                cleaned.append(True)
    finally:
        signal.signal(signal.SIGTERM, before)
    assert cleaned == [True]


def test_a_reader_that_goes_away_ends_a_command_quietly_as_a_unix_filter():
    """`fabric-guidance example | head -1`: the pipe closes under the command's next line. It
    stops with the shell's SIGPIPE status (141) and nothing on stderr (it printed a traceback)."""
    from fabric_guidance.subcommand import BROKEN_PIPE
    proc = subprocess.Popen([sys.executable, '-m', 'fabric_guidance.commands.cli', 'example'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = proc.stdout.readline()
    proc.stdout.close()                     # what head does after its line
    err = proc.stderr.read()
    assert proc.wait(timeout=120) == BROKEN_PIPE, err
    assert first.startswith('fabric_guidance worked example') and err == '', err


@pytest.mark.parametrize('option', ['--record', '--out'])
def test_a_demo_folder_it_cannot_write_is_refused_before_any_graph_starts(tmp_path, capsys, option):
    """`demo --record /proc/nope` started the graph, waited 45 s for a recorder that could not
    write, and ended in a traceback."""
    from fabric_guidance.commands.cli import main
    not_a_folder = tmp_path / 'a-file'
    not_a_folder.write_text('')
    for folder in ('/proc/nope', str(not_a_folder)):
        assert main(['demo', option, folder]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f'fabric-guidance demo: error: {option}: cannot write into {folder}')


@pytest.mark.parametrize('options, line', [
    (['--trial-s', '-5'], '--trial-s: must be > 0 s, got -5.0'),
    (['--participants', '0'], "--participants: 1..15 (the scene's wearers), got 0"),
    (['--trials', '0'], '--trials: must be >= 1 trials, got 0'),
    (['--protocol', 'accuracy', '--trial-s', '5'], '--trial-s: only the speed protocol has timed trials'),
])
def test_a_study_option_out_of_range_is_refused_before_the_folder_is_made(tmp_path, capsys, options, line):
    """The folder used to be made first: the corrected command was then refused as 'started with
    another scene or other options', and the message named the scene file's field."""
    from fabric_guidance.commands.cli import main
    out = tmp_path / 'study'
    assert main(['study', '--simulated', '--out', str(out), *options]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [f'fabric-guidance study: error: {line}']
    assert not out.exists()


def test_a_long_study_says_how_long_before_it_starts():
    """`study --simulated --out DIR` alone is the paper's whole study (about 1.5 h): said first."""
    from fabric_guidance.live_study.session_graph import duration_line
    from fabric_guidance.study.plan import StudyDesign
    line = duration_line(StudyDesign('speed'), 5)
    assert line.startswith('study: at least 86 min: 5 participants x 4 conditions x 6 trials x (40 s + 3 s rest)')
    assert 'at most about 60 min: 200 trials of up to 15 s' in duration_line(StudyDesign('accuracy'), 5)


def test_a_misspelt_scene_name_lists_the_valid_ones_in_one_line(capsys):
    from fabric_guidance.commands.cli import main
    from fabric_guidance.sim.scene import scene_names
    assert main(['demo', '--scene', 'paper-sped']) == 2
    lines = [line for line in capsys.readouterr().out.splitlines() if line.strip()]
    # nothing ran: no "(the logs above were ...)" line after it
    assert len(lines) == 1 and "no scene named 'paper-sped' (did you mean paper-speed?)" in lines[0], lines
    assert all(name in lines[0] for name in scene_names()) and 'paper-fitted-speed' in scene_names()
