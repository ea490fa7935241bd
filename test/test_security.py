"""What the package exposes by default: the gaze port on loopback for localhost senders only,
the PLC written only at mapped registers, DDS discovery on this machine for every simulated
and test graph. (Running checks: test_node_gaze_bridge.py binds and filters, every Graph's
stop_all holds the mock PLC to the register map, test_faults_process.py reads the running
nodes' environment.)"""
import ast
import ipaddress
from pathlib import Path


from fabric_guidance.nodes import gaze_bridge
from fabric_guidance.plc import RegisterMap
from fabric_guidance.paths import node_parameters
from rosgraph import CONFIG, ROOT, Graph


def _declared_default(module_file: Path, name: str):
    """The default of declare(self, '<name>', default, ...) in a node's source."""
    for node in ast.walk(ast.parse(module_file.read_text())):
        if isinstance(node, ast.Call) and getattr(node.func, 'id', '') == 'declare' and len(node.args) >= 3 \
                and isinstance(node.args[1], ast.Constant) and node.args[1].value == name:
            return ast.literal_eval(node.args[2])
    raise AssertionError(f'{name} is not declared in {module_file}')


def test_the_bridge_listens_on_loopback_for_loopback_senders_by_default():
    source = Path(gaze_bridge.__file__)
    assert _declared_default(source, 'bind_address') == '127.0.0.1'
    assert _declared_default(source, 'allowed_senders') == ['127.0.0.1']
    params = node_parameters('params/guidance.yaml', 'gaze_bridge')
    assert ipaddress.ip_address(params['bind_address']).is_loopback
    assert all(ipaddress.ip_address(a).is_loopback for a in params['allowed_senders'])


def test_the_package_writes_only_mapped_registers():
    """The register map names every holding register the client may write; the mock PLC
    records anything else, and every test graph fails on such a record (process_graph)."""
    m = RegisterMap.load(CONFIG / 'hardware/plc_register_map.yaml')
    writable = set(m.command_registers) | {m.heartbeat_register, m.sequence_register, m.vent_register}
    assert m.vent_register is not None
    assert all(m.is_mapped_holding(a) for a in writable)
    assert not any(m.is_mapped_holding(a) for a in set(range(65536)) - writable)


def test_simulated_and_test_graphs_keep_dds_discovery_on_localhost(tmp_path):
    env = Graph(tmp_path).env   # the loopback profile decides alone (test_bad_input checks with ss)
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SYSTEM_DEFAULT'
    from fabric_guidance.lab.lab_network import profile_variable
    assert env[profile_variable()] == str(CONFIG / 'fastdds_loopback.xml')   # the distribution's Fast DDS name
    launch = (ROOT / 'launch' / 'sim.launch.py').read_text()
    # The simulated launch sets the same profile (LOCALHOST discovery if the file were missing).
    assert 'loopback_dds_actions(' in launch
    support = (ROOT / 'fabric_guidance' / 'graph' / 'launch_support.py').read_text()
    assert "'fastdds_loopback.xml'" in support and "'LOCALHOST'" in support
    assert 'ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST' in (ROOT / 'Makefile').read_text()
    assert ipaddress.ip_address(node_parameters('params/sim.yaml', 'mock_plc')['host']).is_loopback
