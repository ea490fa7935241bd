"""The SROS2 policy generated from the interface table (fabric_guidance/lab/security_policy.py,
docs/security.md): read back, it grants each node exactly what the table says and what every
rclpy node opens, nothing else, under fully qualified names; against sros2's own schema and
permissions transform where sros2 is installed; and enforcement, where the RMW has the DDS
security plugins (the pip wheels here do not: that part is skipped with the middleware's words,
after checking that a node told to enforce security refuses to start rather than run open).
"""
from importlib import util
import json
import os
from pathlib import Path
import re
import subprocess
import sys
import time

import pytest

from fabric_guidance import interface, security_policy as sp
from netns_participant import INTRUDER_KPA
from rosgraph import ROOT, Graph, free_port, wait_until
from test_graph import RESOLUTION_KPA, RegisterWatch

PARTICIPANT = Path(__file__).resolve().parent / 'netns_participant.py'
#: What every node of the package may do besides the table's rows (rclpy's own topics and
#: services; /clock: the table's "nodes with `use_sim_time`").
DEFAULT_PUBLISH = {'/rosout', '/parameter_events'}
DEFAULT_SUBSCRIBE = {'/clock'}
PARAMETER_SERVICES = {'describe_parameters', 'get_parameter_types', 'get_parameters', 'list_parameters',
                      'set_parameters', 'set_parameters_atomically'}


#: rclpy.lifecycle's services and event topic (rcl_lifecycle's names), for interface.MANAGED_NODES.
LIFECYCLE_SERVICES = {'change_state', 'get_state', 'get_available_states', 'get_available_transitions',
                      'get_transition_graph'}


def default_replies(node):
    lifecycle = LIFECYCLE_SERVICES if node in interface.MANAGED_NODES else set()
    return {f'/{node}/{s}' for s in PARAMETER_SERVICES | {'get_type_description'} | lifecycle}


def default_publishes(node):
    return DEFAULT_PUBLISH | ({f'/{node}/transition_event'} if node in interface.MANAGED_NODES else set())


@pytest.fixture(scope='module')
def policy():
    return sp.read_policy(sp.policy_xml(), 'generated policy')


def named(cell: str, node: str) -> bool:
    """The node's name stands in a table cell as a word (an independent reading of the table)."""
    return re.search(rf'(?<![\w/]){re.escape(node)}(?![\w/])', cell) is not None


def fq(name: str) -> str:
    """A name of the tables in the root namespace (a private one as its node's)."""
    return re.sub(r'<[^>]*>', '*', interface.full_name(name))


def test_every_node_gets_exactly_the_tables_topics_and_services(policy):
    for node in sp.NODES:
        g = policy[f'/fabric_guidance/{node}']
        publishes = {fq(t.name) for t in interface.TOPICS if named(t.publishers, node)}
        subscribes = {fq(t.name) for t in interface.TOPICS if named(t.subscribers, node)}
        if node == 'bag_recorder':   # records every topic the table marks recorded
            subscribes |= {fq(t.name) for t in interface.TOPICS if t.recorded}
        replies = {fq(s.name) for s in interface.SERVICES if s.node == node}
        assert g.publish == publishes | default_publishes(node), node
        assert g.subscribe == subscribes | DEFAULT_SUBSCRIBE, node
        assert g.reply == replies | default_replies(node), node
        assert g.request == set(), f'{node} may call services: {g.request}'


def test_what_drives_the_suit_has_one_publisher_each(policy):
    """Spelled out for the safety-relevant rows: only the controller commands pressures, only the
    bridge publishes gaze, only target_selector the target; the services are answered by their
    node alone."""
    def publishers(topic):
        return {path.rsplit('/', 1)[1] for path, g in policy.items() if topic in g.publish}
    assert publishers('/pressure_command') == {'pressure_controller'}
    assert publishers('/gaze') == {'gaze_bridge'}
    assert publishers('/target') == publishers('/active_target') == {'target_selector'}
    assert publishers('/live_targets/*') == {'micromanipulator_sim'}
    readers = {path.rsplit('/', 1)[1] for path, g in policy.items() if '/pressure_command' in g.subscribe}
    assert readers == {'plc_output', 'bag_recorder', 'operator'}
    for s in interface.SERVICES:
        assert {p for p, g in policy.items() if fq(s.name) in g.reply} == {f'/fabric_guidance/{s.node}'}


def test_the_operator_calls_the_services_and_watches_but_publishes_no_topic_of_the_table(policy):
    g = policy['/fabric_guidance/operator']
    assert g.request == ({fq(s.name) for s in interface.SERVICES}
                         | {f'/{n}/{s}' for n in sp.NODES for s in PARAMETER_SERVICES}
                         | {f'/{n}/{s}' for n in interface.MANAGED_NODES for s in LIFECYCLE_SERVICES})
    assert g.subscribe == ({fq(t.name) for t in interface.TOPICS}
                           | {f'/{n}/transition_event' for n in interface.MANAGED_NODES})
    assert g.publish == DEFAULT_PUBLISH
    assert g.reply == {'/*/get_type_description'}   # its node's name is ros2cli's
    assert set(sp.read_policy(sp.policy_xml(operator=False))) == {f'/fabric_guidance/{n}' for n in sp.NODES}


def test_only_the_packages_nodes_have_an_enclave(policy):
    in_table = {n for t in interface.TOPICS for cell in (t.publishers, t.subscribers)
                for n in sp.NODES if named(cell, n)} | {s.node for s in interface.SERVICES}
    assert set(policy) == {f'/fabric_guidance/{n}' for n in in_table | {'operator'}}
    for stranger in ('test_probe', 'intruder', 'ros2cli', 'rviz'):
        assert f'/fabric_guidance/{stranger}' not in policy
        with pytest.raises(ValueError, match=f'{stranger}: no enclave in the policy'):
            sp.node_security(stranger, '/keystore')


def test_names_are_fully_qualified_ros_names_not_dds_topics(policy):
    names = [n for g in policy.values() for rule in (g.publish, g.subscribe, g.reply, g.request) for n in rule]
    assert names
    for n in names:
        assert n.startswith('/') and '~' not in n and '<' not in n, n
        assert not re.match(r'/?r[tqr]/', n), f'{n}: a DDS topic name; sros2 adds rt/, rq/, rr/ itself'


def test_a_table_entry_naming_no_node_stops_the_generator(monkeypatch):
    rogue = interface.Topic('rogue', 'std_msgs/msg/String', interface.EVENT, 'rogue_node', '', 'x')
    monkeypatch.setattr(interface, 'TOPICS', interface.TOPICS + (rogue,))
    with pytest.raises(ValueError, match="topic rogue: publishers: 'rogue_node' is no node of the package"):
        sp.policy_xml()


@pytest.mark.parametrize('old, new, reason', [
    ('publish="ALLOW"', 'publish="DENY"', 'ALLOW'),
    ('<topics publish="ALLOW">', '<actions call="ALLOW"><action>/x</action></actions><topics publish="ALLOW">',
     'only topics and services'),
    ('<policy version="0.2.0">', '<policy version="0.1.0">', 'root is not'),
    ('path="/fabric_guidance/gaze_bridge"', 'path="fabric_guidance/gaze_bridge"', 'absolute path'),
    ('<topic>/gaze</topic>', '<topic></topic>', 'non-empty <topic>'),
])
def test_read_policy_refuses_what_the_generator_never_writes(old, new, reason):
    text = sp.policy_xml()
    assert old in text
    with pytest.raises(ValueError, match=reason):
        sp.read_policy(text.replace(old, new, 1), 'policy.xml')


def test_security_policy_command(tmp_path):
    def cli(*argv):
        return subprocess.run([sys.executable, '-m', 'fabric_guidance.commands.cli', 'security-policy', *argv],
                              capture_output=True, text=True, timeout=60, cwd=ROOT)
    out = cli('--out', str(tmp_path / 'policy.xml'))
    assert out.returncode == 0, out.stderr
    assert (tmp_path / 'policy.xml').read_text() == sp.policy_xml()
    listed = cli('--list-enclaves', '--no-operator').stdout.split()
    assert listed == sorted(f'/fabric_guidance/{n}' for n in sp.NODES)
    refused = cli('--out', str(tmp_path / 'policy.xml' / 'x'))
    assert refused.returncode == 2 and len(refused.stderr.strip().splitlines()) == 1


def test_launch_arguments_of_a_node_with_and_without_a_keystore():
    assert sp.node_security('plc_output', '') == {}
    assert sp.node_security('plc_output', '/lab/keystore') == {
        'ros_arguments': ['--enclave', '/fabric_guidance/plc_output'],
        'additional_env': {'ROS_SECURITY_KEYSTORE': '/lab/keystore', 'ROS_SECURITY_ENABLE': 'true',
                           'ROS_SECURITY_STRATEGY': 'Enforce'}}


def _sros2_dir():
    spec = util.find_spec('sros2')
    if spec is None or not spec.submodule_search_locations:
        pytest.skip('sros2 is not installed (it comes with a ROS 2 installation, not on the package index): '
                    "the policy is checked against this module's reading of sros2's policy.xsd only")
    return Path(list(spec.submodule_search_locations)[0])


def test_the_policy_is_valid_for_sros2s_schema(tmp_path):
    xmlschema = pytest.importorskip('xmlschema', reason='xmlschema is not installed (requirements/test.txt)')
    schema = xmlschema.XMLSchema(str(_sros2_dir() / 'policy' / 'schemas' / 'policy.xsd'))
    schema.validate(sp.policy_xml())
    assert not schema.is_valid(sp.policy_xml().replace('publish="ALLOW"', 'publish="YES"', 1))


def test_sros2_turns_the_policy_into_dds_permissions_that_keep_the_commands_to_the_controller(tmp_path):
    _sros2_dir()
    pytest.importorskip('lxml', reason='lxml is not installed (sros2 needs it; python3-lxml)')
    from lxml import etree
    from sros2.api import _policy
    from sros2.policy import get_transport_schema, get_transport_template, load_policy
    path = sp.write_policy(tmp_path / 'policy.xml')
    tree = load_policy(path)   # sros2's own reading: XInclude and policy.xsd
    transform = etree.XSLT(etree.parse(str(get_transport_template('dds', 'permissions.xsl'))))
    schema = etree.XMLSchema(etree.parse(str(get_transport_schema('dds', 'permissions.xsd'))))
    commanders = set()
    for enclave in sp.read_policy(path.read_text()):
        permissions = transform(_policy.get_policy_from_tree(enclave, tree))
        schema.assertValid(permissions)
        published = {t.text for t in permissions.iterfind('.//allow_rule/publish/topics/topic')}
        if 'rt/pressure_command' in published:
            commanders.add(enclave)
    assert commanders == {'/fabric_guidance/pressure_controller'}


# ---- enforcement

def _security_env(keystore, enclave):
    return {'ROS_SECURITY_KEYSTORE': str(keystore), 'ROS_SECURITY_ENABLE': 'true', 'ROS_SECURITY_STRATEGY': 'Enforce',
            'ROS_SECURITY_ENCLAVE_OVERRIDE': enclave}


def test_a_node_told_to_enforce_security_refuses_to_start_where_the_rmw_cannot(tmp_path):
    """Where the middleware lacks the DDS security plugins, plc_output with a keystore set exits
    with the middleware's reason instead of running unauthenticated. Where it has them, the
    enforcement test below runs instead."""
    (tmp_path / 'keystore' / 'enclaves' / 'fabric_guidance' / 'plc_output').mkdir(parents=True)
    env = dict(os.environ, **_security_env(tmp_path / 'keystore', '/fabric_guidance/plc_output'))
    out = subprocess.run([sys.executable, '-m', 'fabric_guidance.nodes.plc_output'], env=env, capture_output=True,
                         text=True, timeout=60)
    text = out.stdout + out.stderr
    if "doesn't have the security libraries" not in text:
        pytest.skip('the RMW has the security libraries (an empty enclave folder gave: '
                    f'{text.strip().splitlines()[-1] if text.strip() else out.returncode}); see the enforcement test')
    assert out.returncode != 0 and 'cannot start: error creating node' in text, text


def _rmw_has_security(tmp_path) -> str | None:
    """None where the RMW enforces DDS security, else its reason (the message it fails with)."""
    (tmp_path / 'probe' / 'enclaves' / 'probe').mkdir(parents=True)
    env = dict(os.environ, **_security_env(tmp_path / 'probe', '/probe'))
    out = subprocess.run([sys.executable, '-c', 'import rclpy; rclpy.init(); rclpy.create_node("probe")'],
                         env=env, capture_output=True, text=True, timeout=60)
    text = out.stdout + out.stderr
    match = re.search(r"This Fast DDS version doesn't have the security libraries[^,\n]*", text)
    return match.group(0) if match else None


@pytest.mark.graph  # starts mock_plc and plc_output with DDS security
def test_enforced_only_the_controllers_enclave_reaches_the_plc(tmp_path):
    """With a keystore generated from the policy (sros2's generate_artifacts) and security
    enforced: a participant in headset_display's enclave cannot publish pressure_command (the
    middleware refuses the writer, or nothing it sends arrives), one in pressure_controller's
    can, and plc_output writes what it sent."""
    reason = _rmw_has_security(tmp_path)
    if reason:
        pytest.skip(f'the RMW of these wheels cannot enforce SROS2: "{reason}" '
                    '(rmw_fastrtps, Fast DDS built without -DSECURITY=ON); the policy tests above still run')
    _sros2_dir()
    from sros2.api._artifact_generation import generate_artifacts
    graph = Graph(tmp_path / 'logs')
    os.environ['ROS_DOMAIN_ID'] = str(graph.domain_id)   # sros2 writes the domain into the permissions
    try:
        generate_artifacts(tmp_path / 'keystore', [], [sp.write_policy(tmp_path / 'policy.xml')])
    finally:
        os.environ.pop('ROS_DOMAIN_ID')
    plc_port = free_port()
    files = ('params/guidance.yaml', 'params/sim.yaml')
    watch = None
    try:
        for node, params in (('mock_plc', {'port': plc_port}), ('plc_output', {'plc_port': plc_port})):
            graph.env.update(_security_env(tmp_path / 'keystore', sp.enclave_path(node)))
            graph.start(node, files, **params)
        watch = RegisterWatch(plc_port)

        def participant(enclave, name):
            env = dict(graph.env, **_security_env(tmp_path / 'keystore', sp.enclave_path(enclave)))
            log = tmp_path / f'{name}.jsonl'
            with open(log, 'w') as out:
                proc = subprocess.Popen([sys.executable, str(PARTICIPANT), '--name', name, '--seconds', '30',
                                         '--publish', 'pressure_command'], env=env, stdout=out,
                                        stderr=subprocess.STDOUT)
            return proc, log

        def reports(log):
            return [json.loads(line) for line in log.read_text().splitlines() if line.startswith('{')]

        wait_until(lambda: watch.matches({}), 30.0, what='plc_output up and vented')
        denied, denied_log = participant('headset_display', 'denied')
        try:
            t0 = time.monotonic()
            while time.monotonic() - t0 < 10.0 and denied.poll() is None:
                assert watch.read()['F1'] <= RESOLUTION_KPA, "headset_display's enclave reached the PLC"
                time.sleep(0.05)
        finally:
            denied.terminate()
            denied.wait(10)
        assert any('refused' in r for r in reports(denied_log)) or not any(
            any(r['subscribers'].values()) for r in reports(denied_log)), denied_log.read_text()
        allowed, allowed_log = participant('pressure_controller', 'allowed')
        try:   # the control: the controller's enclave reaches the PLC through plc_output
            wait_until(lambda: abs(watch.read()['F1'] - INTRUDER_KPA) <= RESOLUTION_KPA, 30.0,
                       what="the controller's enclave commanding F1 through plc_output")
        finally:
            allowed.terminate()
            allowed.wait(10)
        assert not any('refused' in r for r in reports(allowed_log)), allowed_log.read_text()
    finally:
        if watch is not None:
            watch.client.close()
        graph.stop_all()


def test_the_lab_network_modules_import_no_rclpy():
    """The generators and their commands run without ROS (a lab PC writing a profile, CI)."""
    code = ('import sys, fabric_guidance.lab.security_policy, fabric_guidance.lab.lab_network, '
            'fabric_guidance.lab.discovery_server; sys.exit(any(m.split(".")[0] == "rclpy" for m in sys.modules))')
    assert subprocess.run([sys.executable, '-c', code], timeout=60).returncode == 0
