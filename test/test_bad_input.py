"""Bad input from outside: every file the package reads, given broken, hostile or
extreme content, ends in one line naming the file, the field and the reason, a non-zero exit
(a vent for a running node), nothing written where it should not be, and bounded memory.

The first part holds one regression test per defect of the issue; the second drives every
file reader with hypothesis-generated broken files in-process under tracemalloc. Recorded bags
and their replay are in test_bad_bags.py; the CLI runner, the one-line check and the mutations
both use are in bad_input_support.py.
"""
from __future__ import annotations

import os
from pathlib import Path
import resource
import subprocess
import sys

import pytest
import yaml

from bad_input_support import cli, mutate, one_line_error, PEAK_BYTES, SETTINGS, SIM_CAL
from rosgraph import CONFIG, ROOT

pytestmark = pytest.mark.graph  # starts a process graph with DDS

#: Address-space cap of a CLI under test: far above what it needs (~0.6 GB with matplotlib),
#: far below what an alias bomb expands to.
MEMORY_CAP = 2 * 1024 ** 3


def _cap_memory():
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_CAP, MEMORY_CAP))


def cli_process(*args, cwd=None, timeout=120) -> subprocess.CompletedProcess:
    """fabric-guidance ARGS in a process of bounded memory."""
    env = {**os.environ, 'MPLBACKEND': 'Agg'}
    return subprocess.run([sys.executable, '-m', 'fabric_guidance.commands.cli', *map(str, args)], cwd=cwd or ROOT,
                          env=env, capture_output=True, text=True, timeout=timeout, preexec_fn=_cap_memory)


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
    from fabric_guidance.lab.calibration_report import report_paths
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
    one_line_error(cli_process('calibration-report', cal), str(cal), 'alias')


def test_defect3_every_yaml_reader_refuses_aliases(tmp_path):
    from fabric_guidance.core.calibration import Calibration
    from fabric_guidance.core.channels import ChannelMap
    from fabric_guidance.core.safe_input import InputFileError
    from fabric_guidance.plc.register_map import PlcLayout, RegisterMap
    from fabric_guidance.sim.scene import load_scene
    f = tmp_path / 'bomb.yaml'
    f.write_text(ALIAS_BOMB)
    for reader in (Calibration.load, ChannelMap.load, RegisterMap.load, PlcLayout.load, load_scene):
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
    channel_map = yaml.safe_load((CONFIG / 'hardware/channel_map.yaml').read_text())
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
    guidance = ('params/guidance.yaml',)
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


# ---- defect 6 and 7: calibration-report and analyze

@pytest.mark.parametrize('change', [
    {'p_max_kpa': 1e308},
    {'directions.left.points.pressure_kpa.0': 1e308},
    {'directions.up.points.angle_deg.3': 1e308},
    {'directions.down.points.angle_deg.3': -1e308},
])
def test_defect6_calibration_report_with_extreme_values_is_one_line(tmp_path, change):
    data = calibration_dict()
    (path, value), = change.items()
    *keys, last = path.split('.')
    target = data
    for k in keys:
        target = target[int(k)] if isinstance(target, list) else target[k]
    target[int(last) if isinstance(target, list) else last] = value
    cal = tmp_path / 'cal.yaml'
    cal.write_text(yaml.safe_dump(data))
    one_line_error(cli('calibration-report', cal, '--out', tmp_path / 'out'), str(cal), path.split('.')[0])
    assert not (tmp_path / 'out').exists() or not any((tmp_path / 'out').iterdir())


def test_defect6_analyze_with_extreme_cells_is_one_line(tmp_path):
    table = tmp_path / 'cells.csv'
    table.write_text('subject,C1,C2,C3,C4\n1,1e308,-1e308,3,4\n2,1,2,3,4\n3,4,-1e308,2,1\n')
    one_line_error(cli('analyze', table, '--plot', tmp_path / 'p.png'), str(table), 'C1')


def test_defect7_analyze_refuses_a_table_without_a_header(tmp_path):
    table = tmp_path / 'noheader.csv'
    table.write_text('1,2,3,4,5\n2,1,2,3,4\n3,4,3,2,1\n')
    one_line_error(cli('analyze', table), str(table), 'header')


# ---- defect 5: finite extremes of the gaze wire format

def _datagram(**fields) -> bytes:
    import json
    huge = {k: v for k, v in fields.items() if k in ('extra', 'stamp', 'seq') and isinstance(v, str)}
    fields.update({k: f'@{k}@' for k in huge})
    msg = {'version': 1, 'seq': 7, 'stamp': 12.5, 'gaze_origin': [0.0, 1.6, 0.0],
           'gaze_direction': [0.0, 0.0, 1.0], 'head_position': [0.0, 1.6, 0.0],
           'head_orientation': [0.0, 0.0, 0.0, 1.0], 'eye_tracking_valid': True}
    msg.update(fields)
    text = json.dumps(msg, separators=(',', ':'))
    for k, digits in huge.items():   # an integer json.dumps cannot write (CPython's digit limit)
        text = text.replace(f'"@{k}@"', digits)
    return text.encode()


def test_defect5_finite_extreme_vectors_are_normalised():
    import numpy as np
    from fabric_guidance.core.gaze_wire import parse_datagram
    s = parse_datagram(_datagram(head_orientation=[1e308] * 4))
    assert np.allclose(np.abs(s.head_orientation), 0.5) and np.isclose(np.linalg.norm(s.head_orientation), 1.0)
    s = parse_datagram(_datagram(gaze_direction=[-1.5e308, 1.5e308, 0.0]))
    assert np.isclose(np.linalg.norm(s.gaze_direction), 1.0)
    assert np.allclose(s.gaze_direction, [0.0, 2 ** -0.5, 2 ** -0.5])   # Unity (-x, y) -> REP 103 (-y, z)


def test_defect5_tiny_vectors_are_zero_vector():
    from fabric_guidance.core.gaze_wire import WireFormatError, parse_datagram
    for field, value in (('gaze_direction', [5e-324, 0.0, 0.0]), ('head_orientation', [1e-300, 0, 0, 0])):
        with pytest.raises(WireFormatError) as info:
            parse_datagram(_datagram(**{field: value}))
        assert info.value.reason == 'zero_vector' and field in str(info.value)


def test_defect5_integers_beyond_the_digit_limit_are_numbers_not_json_errors():
    from fabric_guidance.core.gaze_wire import WireFormatError, parse_datagram
    huge = '9' * 5000
    big = 20_000
    sample = parse_datagram(_datagram(extra=huge), max_size=big)     # unknown fields are ignored
    assert sample.seq == 7
    for field, reason in (('stamp', 'non_finite'), ('seq', 'range'), ('gaze_origin', 'non_finite')):
        if field == 'gaze_origin':
            data = _datagram().replace(b'"gaze_origin":[0.0', b'"gaze_origin":[' + huge.encode())
        else:
            data = _datagram(**{field: huge})
        with pytest.raises(WireFormatError) as info:
            parse_datagram(data, max_size=big)
        assert info.value.reason == reason and field in str(info.value), (field, info.value)


def test_defect7_ipv4_mapped_allowed_sender_is_the_ipv4_address():
    from fabric_guidance.nodes.gaze_bridge import GazeBridge
    senders = GazeBridge._parse_senders(['::ffff:192.168.1.20', '10.0.0.1', '::1'])
    # the receive loop strips ::ffff: from what an IPv6 socket reports for an IPv4 sender
    assert senders == {'192.168.1.20', '10.0.0.1', '::1'}


# ---- defect 8: the simulated graph's DDS stays on loopback

def _sockets_of(pids: set[int]) -> list[tuple[str, str, int]]:
    """(netid, local address, pid) of every TCP/UDP socket of these processes (ss -tuanp)."""
    out = subprocess.run(['ss', '-tuanpH'], capture_output=True, text=True, check=True).stdout
    found = []
    for line in out.splitlines():
        fields = line.split()
        for pid in pids:
            if f'pid={pid},' in line:
                found.append((fields[0], fields[4], pid))
    return found


def _local_ip(address: str) -> str:
    host = address.rsplit(':', 1)[0].strip('[]')
    return host.split('%', 1)[0]


@pytest.mark.skipif(not __import__('shutil').which('ss'), reason='ss (iproute2) is not installed')
def test_defect8_nothing_of_the_simulated_graph_listens_beyond_loopback(tmp_path):
    import ipaddress
    import socket
    from std_msgs.msg import String
    from fabric_guidance.commands.demo import NODES
    from fabric_guidance.nodes.qos import LATCHED_QOS
    from rosgraph import Graph, Probe, free_port, wait_until
    plc_port, gaze_port = free_port(), free_port(socket.SOCK_DGRAM)
    overrides = {'mock_plc': dict(port=plc_port), 'plc_output': dict(plc_port=plc_port),
                 'gaze_bridge': dict(port=gaze_port), 'wearer_sim': dict(bridge_port=gaze_port)}
    with Graph(tmp_path) as graph:
        for node in NODES:
            graph.start(node, ('params/guidance.yaml', 'params/sim.yaml'), **overrides.get(node, {}))
        with Probe(graph.domain_id) as probe:
            # the graph is up and discovered: the controller's latched parameters reach the probe
            probe.subscribe(String, 'controller_parameters', LATCHED_QOS)
            wait_until(lambda: probe.latest('controller_parameters'), 60.0, what='controller_parameters')
            pids = {p.pid for p in graph.processes.values()}   # the nodes (not this test process)

            def every_node_has_sockets():
                found = _sockets_of(pids)
                return found if {pid for *_, pid in found} == pids else None
            sockets = wait_until(every_node_has_sockets, 30.0, 0.2, 'a socket of every node in ss')
    beyond = [s for s in sockets if not ipaddress.ip_address(_local_ip(s[1])).is_loopback]
    assert not beyond, f'sockets beyond loopback: {beyond}'


# ---- every file reader on generated broken files (hypothesis): one line, bounded memory

from hypothesis import given, strategies as st  # noqa: E402

_extreme = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True), st.integers(min_value=-10 ** 30, max_value=10 ** 30),
    st.sampled_from([1e308, -1e308, 5e-324, 10 ** 400, '', 'x' * 5000, None, True, [], {}]),
    st.text(max_size=30), st.lists(st.integers(), max_size=5))
_yaml_value = st.recursive(_extreme, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=8), inner, max_size=4)), max_leaves=20)


def _readers():
    from fabric_guidance.core.calibration import Calibration
    from fabric_guidance.core.channels import ChannelMap
    from fabric_guidance.experiments.stats import load_table
    from fabric_guidance.nodes.parameters import check_params_files
    from fabric_guidance.plc.register_map import PlcLayout, RegisterMap
    from fabric_guidance.sim.scene import load_scene
    return {
        'calibration': (Calibration.load, SIM_CAL),
        'channel map': (ChannelMap.load, CONFIG / 'hardware/channel_map.yaml'),
        'register map': (RegisterMap.load, CONFIG / 'hardware/plc_register_map.yaml'),
        # What plc_output reads (one PLC or several).
        'plc layout': (PlcLayout.load, CONFIG / 'hardware/plc_register_map.yaml'),
        'scene': (load_scene, CONFIG / 'scenes' / 'paper-accuracy.yaml'),
        'parameters file': (lambda p: check_params_files(['--params-file', str(p)]), CONFIG / 'params/guidance.yaml'),
        'analyze table': (load_table, ROOT / 'test' / 'data' / 'table-identified-targets.csv'),
    }


READERS = _readers()


def _refuses_in_one_line(reader, path: Path) -> None:
    """The reader accepts the file or raises a ValueError of one short line naming the file;
    anything else (another exception, a traceback's worth of text, a memory spike) fails."""
    import tracemalloc
    tracemalloc.start()
    try:
        reader(path)
    except ValueError as exc:
        msg = str(exc)
        assert '\n' not in msg and len(msg) < 600, msg[:2000]
        assert path.name in msg, msg
    finally:
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    assert peak < PEAK_BYTES, f'{peak / 1e6:.0f} MB'


@pytest.mark.parametrize('name', sorted(READERS))
@SETTINGS
@given(data=st.data())
def test_every_file_reader_refuses_mutated_files_in_one_line(tmp_path, name, data):
    reader, original = READERS[name]
    path = tmp_path / f'broken{original.suffix}'
    path.write_bytes(mutate(original.read_bytes(), data))
    _refuses_in_one_line(reader, path)


@pytest.mark.parametrize('name', sorted(set(READERS) - {'analyze table'}))
@SETTINGS
@given(data=st.data())
def test_every_yaml_reader_refuses_wrong_values_in_one_line(tmp_path, name, data):
    """The real file with a generated value in one of its fields (or as the whole document)."""
    reader, original = READERS[name]
    doc = yaml.safe_load(original.read_text())
    value = data.draw(_yaml_value)
    target = doc
    while isinstance(target, dict) and target and data.draw(st.booleans()):
        key = data.draw(st.sampled_from(sorted(target, key=str)))
        if not isinstance(target[key], dict):
            break
        target = target[key]
    if isinstance(target, dict) and target:
        target[data.draw(st.sampled_from(sorted(target, key=str)))] = value
    else:
        doc = value
    path = tmp_path / 'broken.yaml'
    path.write_text(yaml.safe_dump(doc, sort_keys=False, allow_unicode=True))
    _refuses_in_one_line(reader, path)


def test_a_missing_field_is_named_missing_not_got_none(tmp_path):
    from fabric_guidance.core.calibration import Calibration, CalibrationFileError
    from fabric_guidance.paths import config_path
    data = yaml.safe_load(config_path('calibrations/sim-wearer.yaml').read_text())
    for field in ('p_max_kpa', 'wearer', 'units', 'directions', 'schema_version'):
        broken = {k: v for k, v in data.items() if k != field}
        with pytest.raises(CalibrationFileError) as exc:
            Calibration.from_dict(broken, source='alice.yaml')
        assert f'field "{field}"' in str(exc.value) and 'the field is missing' in str(exc.value)
        assert 'None' not in str(exc.value)
    # A null written in the file is still reported as what it is.
    with pytest.raises(CalibrationFileError, match='got None'):
        Calibration.from_dict(dict(data, p_max_kpa=None), source='alice.yaml')
