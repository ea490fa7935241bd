"""Bad input from outside (issue 14): every file the package reads, given broken, hostile or
extreme content, ends in one line naming the file, the field and the reason, a non-zero exit
(a vent for a running node), nothing written where it should not be, and bounded memory.

The first part holds one regression test per defect of the issue; the second drives every
file reader with hypothesis-generated broken files in-process under tracemalloc.
"""
from __future__ import annotations

import os
from pathlib import Path
import resource
import subprocess
import sys

import pytest
import yaml

from rosgraph import CONFIG, ROOT

SIM_CAL = CONFIG / 'calibrations' / 'sim-wearer.yaml'
#: Address-space cap of a CLI under test: far above what it needs (~0.6 GB with matplotlib),
#: far below what an alias bomb expands to.
MEMORY_CAP = 2 * 1024 ** 3


def _cap_memory():
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_CAP, MEMORY_CAP))


def cli(*args, cwd=None, timeout=120) -> subprocess.CompletedProcess:
    """fabric-guidance ARGS in a process of bounded memory."""
    env = {**os.environ, 'MPLBACKEND': 'Agg'}
    return subprocess.run([sys.executable, '-m', 'fabric_guidance.cli', *map(str, args)], cwd=cwd or ROOT,
                          env=env, capture_output=True, text=True, timeout=timeout, preexec_fn=_cap_memory)


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


def calibration_dict(**changes) -> dict:
    data = yaml.safe_load(SIM_CAL.read_text())
    data.update(changes)
    return data


def write_calibration(path: Path, **changes) -> Path:
    path.write_text(yaml.safe_dump(calibration_dict(**changes), sort_keys=False))
    return path


ALIAS_BOMB = ('a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]\n'
              'b: &b [*a,*a,*a,*a,*a,*a,*a,*a,*a]\n'
              'c: &c [*b,*b,*b,*b,*b,*b,*b,*b,*b]\n'
              'd: &d [*c,*c,*c,*c,*c,*c,*c,*c,*c]\n'
              'e: &e [*d,*d,*d,*d,*d,*d,*d,*d,*d]\n'
              'f: &f [*e,*e,*e,*e,*e,*e,*e,*e,*e]\n'
              'g: &g [*f,*f,*f,*f,*f,*f,*f,*f,*f]\n'
              'h: &h [*g,*g,*g,*g,*g,*g,*g,*g,*g]\n')


# ---- defect 1: a wearer name is a name

@pytest.mark.parametrize('wearer', ['../../victim', '/tmp/victim', 'a/b', '.hidden', '', 'x' * 65, 'a\nb'])
def test_defect1_calibration_report_refuses_a_wearer_that_is_a_path(tmp_path, wearer):
    victim_dir = tmp_path / 'elsewhere'
    victim_dir.mkdir()
    cal = write_calibration(tmp_path / 'cal.yaml', wearer=wearer.replace('/tmp/victim', str(victim_dir / 'victim')))
    out = tmp_path / 'a' / 'b' / 'out'
    proc = cli('calibration-report', cal, '--out', out)
    one_line_error(proc, str(cal), 'wearer')
    written = [p for p in tmp_path.rglob('*') if p.is_file() and p != cal]
    assert written == []


def test_defect1_calibration_file_with_a_path_wearer_is_refused(tmp_path):
    from fabric_guidance.core.calibration import Calibration, CalibrationFileError
    for wearer in ('../x', '/abs', 'ok/../x', '..'):
        with pytest.raises(CalibrationFileError, match='wearer'):
            Calibration.from_dict(calibration_dict(wearer=wearer), 'cal.yaml')
    assert Calibration.from_dict(calibration_dict(wearer='Alice_2.b-3'), 'cal.yaml').wearer == 'Alice_2.b-3'


def test_defect1_report_paths_refuse_a_path_wearer(tmp_path):
    from fabric_guidance.calibration_report import report_paths
    from fabric_guidance.core.calibration import Calibration
    cal = Calibration.load(SIM_CAL)
    bad = Calibration('../victim', cal.p_max, cal.directions)
    with pytest.raises(ValueError, match='wearer'):
        report_paths(bad, tmp_path)


# ---- defect 3: an alias bomb; values printed whole

def test_defect3_alias_bomb_calibration_report_is_refused_in_bounded_memory(tmp_path):
    cal = tmp_path / 'bomb.yaml'
    cal.write_text(ALIAS_BOMB + 'schema_version: *h\n')
    assert cal.stat().st_size < 600
    one_line_error(cli('calibration-report', cal), str(cal), 'alias')


def test_defect3_every_yaml_reader_refuses_aliases(tmp_path):
    from fabric_guidance.core.calibration import Calibration
    from fabric_guidance.core.channels import ChannelMap
    from fabric_guidance.core.safe_input import InputFileError
    from fabric_guidance.plc.register_map import RegisterMap
    from fabric_guidance.sim.scene import load_scene
    f = tmp_path / 'bomb.yaml'
    f.write_text(ALIAS_BOMB)
    for reader in (Calibration.load, ChannelMap.load, RegisterMap.load, load_scene):
        with pytest.raises((InputFileError, ValueError)) as info:
            reader(f)
        msg = str(info.value)
        assert str(f) in msg and 'alias' in msg and '\n' not in msg and len(msg) < 300


def test_defect3_a_big_value_is_printed_as_an_excerpt(tmp_path):
    from fabric_guidance.core.calibration import Calibration, CalibrationFileError
    huge = list(range(100_000))
    for field in ('schema_version', 'units', 'p_max_kpa', 'adjustment_gain'):
        with pytest.raises(CalibrationFileError) as info:
            Calibration.from_dict(calibration_dict(**{field: huge}), 'cal.yaml')
        assert field in str(info.value) and len(str(info.value)) < 300


# ---- defect 7 (part): a binary YAML names its file

def test_defect7_binary_yaml_names_the_file(tmp_path):
    f = tmp_path / 'binary.yaml'
    f.write_bytes(bytes(range(256)) * 4)
    one_line_error(cli('calibration-report', f), str(f), 'UTF-8')


# ---- defects 2, 6 (nodes), 1 (node), 3 (node): refused at start-up, one line, no traceback

NODE_EXIT_DEADLINE_S = 60.0   # every case starting at once on a loaded 2-core machine


def test_nodes_refuse_bad_files_and_parameters_at_start_up_in_one_line(tmp_path):
    from rosgraph import Graph, free_port
    channel_map = yaml.safe_load((CONFIG / 'channel_map.yaml').read_text())
    no_suit = {'channels': channel_map['channels'], 'layouts': {'arm': channel_map['layouts']['arm']}}
    files = {
        'no_suit.yaml': yaml.safe_dump(no_suit),
        'bomb.yaml': ALIAS_BOMB,
        'list.yaml': '- a\n- b\n',
        'broken.yaml': 'a: [\n',
        'binary.yaml': bytes(range(256)).decode('latin-1'),
    }
    for name, text in files.items():
        (tmp_path / name).write_text(text, encoding='latin-1' if name == 'binary.yaml' else 'utf-8')
    f = {name: str(tmp_path / name) for name in files}
    guidance = ('guidance.yaml',)
    # (case, node, parameter files, overrides, what the one line must name)
    cases = [
        ('defect 2: channel map without the suit layout', 'pressure_controller', guidance,
         {'channel_map_file': f['no_suit.yaml'], 'condition': 1}, ['no_suit.yaml', '"layouts"', 'suit']),
        ('defect 1: wearer is a path', 'pressure_controller', guidance, {'wearer': '../../victim'},
         ['"wearer"', 'file name']),
        ('defect 3: alias bomb channel map', 'pressure_controller', guidance,
         {'channel_map_file': f['bomb.yaml']}, ['bomb.yaml', 'alias']),
        ('defect 7: binary calibration file', 'pressure_controller', guidance,
         {'calibration_file': f['binary.yaml']}, ['binary.yaml', 'UTF-8']),
        ('defect 6: list-shaped params file', 'target_selector', (f['list.yaml'],), {},
         ['parameters file', 'list.yaml', 'node names']),
        ('defect 6: unparsable params file', 'gaze_bridge', (f['broken.yaml'],), {'port': free_port()},
         ['parameters file', 'broken.yaml', 'YAML']),
        ('defect 6: missing params file', 'plc_output', (str(tmp_path / 'missing.yaml'),), {},
         ['parameters file', 'missing.yaml']),
    ]
    running = []
    for i, (case, node, params_files, overrides, needles) in enumerate(cases):
        graph = Graph(tmp_path / f'case{i}')
        running.append((case, node, graph, graph.start(node, params_files, **overrides), needles))
    failures = []
    try:
        for case, node, graph, proc, needles in running:
            try:
                code = proc.wait(NODE_EXIT_DEADLINE_S)
            except subprocess.TimeoutExpired:
                code = None
            log = graph.log(node)
            lines = [line for line in log.splitlines() if line.strip()]
            if (code != 1 or 'Traceback' in log or len(lines) != 1 or 'cannot start' not in lines[0]
                    or not all(n in lines[0] for n in needles)):
                failures.append(f'{case} ({node}): exit {code}, expected 1 and one "cannot start" line '
                                f'with {needles}; log:\n{log[-3000:]}')
    finally:
        for _, _, graph, _, _ in running:
            graph.stop_all(check=False)
    assert not failures, '\n\n'.join(failures)
    assert not (tmp_path.parent / 'victim.yaml').exists()
