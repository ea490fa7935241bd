"""Bad parameter values and bad calibration or register-map files are refused at start-up.

Each case starts one node as a process (the way a launch file does) with one bad value or
file; it must exit 1 with one line `cannot start: ...` that names the field and the reason,
and a bad calibration file must be left exactly as it was. All cases start at once and are
then waited for (one process each, on its own domain), to keep the wall time down. The
bridge's own bad parameters (address, sender, port in use) are in test_node_gaze_bridge.py;
the register map's and the calibration file's every field in test_plc_register_map.py and
test_calibration.py: here they go through the nodes.
"""
import pytest
import yaml

from rosgraph import CONFIG, Graph, free_port

pytestmark = pytest.mark.graph  # starts a process graph with DDS

FILES = ('params/guidance.yaml', 'params/sim.yaml')
EXIT_DEADLINE_S = 60.0   # every case starting at once on a loaded 2-core machine
SIM_CAL = yaml.safe_load((CONFIG / 'calibrations' / 'sim-wearer.yaml').read_text())
REG_MAP = yaml.safe_load((CONFIG / 'hardware/plc_register_map.yaml').read_text())


def _calibration(**changes):
    data = yaml.safe_load(yaml.safe_dump(SIM_CAL))
    for path, value in changes.items():
        *keys, last = path.split('.')
        target = data
        for k in keys:
            target = target[k]
        if value is ...:
            del target[last]
        else:
            target[last] = value
    return data


def _register_map(**changes):
    data = dict(REG_MAP)
    for k, v in changes.items():
        if v is ...:
            del data[k]
        else:
            data[k] = v
    return data


# (id, node, parameters, {parameter: YAML content of a file written for it}, what the message must say)
CASES = [
    ('gain negative', 'pressure_controller', {'gain': -1.0}, {}, ['gain', 'out of range']),
    ('p_max NaN', 'pressure_controller', {'p_max_kpa': '.nan'}, {}, ['p_max_kpa', 'out of range']),
    ('calibration: units missing', 'pressure_controller', {},
     {'calibration_file': _calibration(units=...)}, ['field "units"']),
    ('calibration: b out of range', 'pressure_controller', {},
     {'calibration_file': _calibration(**{'directions.left.b': 99.0})},
     ['"directions.left"', 'exponent b', 'within [0.001, 20.0]']),
    ('calibration: a not a number', 'pressure_controller', {},
     {'calibration_file': _calibration(**{'directions.up.a': 'strong'})},
     ['"directions.up"', 'coefficient a', 'finite']),
    # (A calibration file that does not exist is no error: a first-time participant has none, and
    # the controller starts without one and offers start_calibration; test_controller_latch.py.)
    ('register map: p_max over 16 bit', 'plc_output', {},
     {'register_map_file': _register_map(p_max_kpa=7000.0)}, ['field "p_max_kpa"', '16-bit']),
    ('register map: sequence register misplaced', 'plc_output', {},
     {'register_map_file': _register_map(sequence_register=30)}, ['field "sequence_register"', 'right after']),
    ('register map: unknown field', 'mock_plc', {},
     {'register_map_file': _register_map(heartbeat=5)}, ['field "heartbeat"', 'not a known field']),
    ('reconnect backoff reversed', 'plc_output', {'reconnect_min_s': 10.0, 'reconnect_max_s': 1.0}, {},
     ['"reconnect_min_s"', 'must not exceed']),
    ('gain not a number', 'pressure_controller', {'gain': 'abc'}, {}, ["'gain'", 'expecting type']),
    ('datagram limit too small', 'gaze_bridge', {'max_datagram_bytes': 10}, {}, ['max_datagram_bytes', 'out of range']),
    ('target positions short', 'target_selector', {'target_positions': [1.0, 2.0]}, {},
     ["'target_positions'", 'needs 3 values']),
]


def test_bad_parameters_and_files_are_refused_naming_the_field_and_the_reason(tmp_path):
    running = []
    for i, (case, node, params, files, needles) in enumerate(CASES):
        folder = tmp_path / f'case{i}'
        folder.mkdir()
        params = dict(params)
        for param, content in files.items():
            path = folder / f'{param}.yaml'
            path.write_text(yaml.safe_dump(content, sort_keys=False))
            params[param] = str(path)
        # Free ports where a node would otherwise fight over the configured ones.
        params.setdefault({'plc_output': 'plc_port', 'mock_plc': 'port', 'gaze_bridge': 'port'}.get(node, '_'),
                          free_port())
        params.pop('_', None)
        graph = Graph(folder / 'logs')
        before = {p: (folder / f'{p}.yaml').read_bytes() for p in files}
        running.append((case, node, graph, graph.start(node, FILES, **params), needles, before, folder))
    failures = []
    try:
        for case, node, graph, proc, needles, before, folder in running:
            code = proc.wait(EXIT_DEADLINE_S)
            log = graph.log(node)
            lines = [line for line in log.splitlines() if 'cannot start' in line]
            if code != 1 or len(lines) != 1 or not all(n in lines[0] for n in needles):
                failures.append(f'{case} ({node}): exit {code}, expected 1 and one "cannot start" line with '
                                f'{needles}; log:\n{log}')
                continue
            print(f'\n[start-up] {case}: {lines[0].split("cannot start: ", 1)[1]}')
            for param, content in before.items():
                assert (folder / f'{param}.yaml').read_bytes() == content, f'{case}: {param} was changed'
    finally:
        for _, _, graph, *_ in running:
            graph.stop_all()
    assert not failures, '\n\n'.join(failures)
