"""A namespaced suit names its own PLC (graph/suit_plc.py): the rule the launch files and the
process graph share, tested without launch (the launch stage runs the launch files themselves)."""
import pytest

from fabric_guidance.graph.suit_plc import require_own_plc
from rosgraph import ROOT, Graph


@pytest.mark.parametrize('namespace, given', [
    ('', {'plc_host': '', 'plc_port': ''}),                 # the root suit: the parameter files' PLC
    ('/', {'plc_host': '', 'plc_port': ''}),
    ('suit_b', {'plc_host': '192.168.1.12', 'plc_port': ''}),
    ('suit_b', {'plc_host': '', 'plc_port': '1602'}),
    ('suit_b', {'plc_port': 1602}),
])
def test_a_suit_with_its_own_plc_address_starts(namespace, given):
    require_own_plc(namespace, given)


@pytest.mark.parametrize('namespace, given, named', [
    ('suit_b', {'plc_host': '', 'plc_port': ''}, 'plc_host:=... or plc_port:=...'),
    ('/suit_b/', {'plc_port': ''}, 'plc_port:=...'),
    ('lab/suit_b', {'plc_host': None, 'plc_port': None}, 'plc_host:=... or plc_port:=...'),
])
def test_a_namespaced_suit_without_its_own_plc_address_is_refused_naming_the_argument(namespace, given, named):
    with pytest.raises(ValueError) as exc:
        require_own_plc(namespace, given)
    message = str(exc.value)
    assert message.startswith(f'launch argument namespace:={namespace}: ') and f'give {named}' in message
    assert '\n' not in message


def test_a_namespaced_graph_refuses_a_plc_output_without_its_own_plc(tmp_path):
    graph = Graph(tmp_path, namespace='suit_b')
    with pytest.raises(ValueError, match=r'Graph.start\(plc_output\) in namespace:=suit_b: .* give plc_host:=\.\.\. '
                                         r'or plc_port:=\.\.\.'):
        graph.start('plc_output', ('params/guidance.yaml',))
    assert 'plc_output' not in graph.processes


@pytest.mark.parametrize('launch_file, arguments', [
    ('guidance.launch.py', "('plc_host', 'plc_port')"),
    ('sim.launch.py', "{'plc_port': plc_port}"),
    ('micromanipulation.launch.py', "('plc_port',) if simulated_wearer else ('plc_host', 'plc_port')"),
])
def test_every_launch_file_applies_the_rule(launch_file, arguments):
    text = (ROOT / 'launch' / launch_file).read_text()
    assert 'require_own_plc(' in text and arguments in text
