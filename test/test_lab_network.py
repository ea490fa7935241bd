"""The lab network set-ups of docs/lab_network.md, each in network namespaces the test builds:
a lab PC with two interfaces (the lab link and another network, as the HoloLens Wi-Fi or the
PLC field network), so that DDS could leak onto the wrong one.

    host A (gaze_bridge, target_selector, pressure_controller)
        lab0 10.231.8.1 ── lab link ── lab0 10.231.8.2  host B (plc_output, mock_plc)
        other0 10.231.9.1 ─┐                 ┌─ other0 10.231.9.2
                           └── br0 host C ───┘  10.231.9.3: a participant nobody configured

1. The Fast DDS profile of `fabric-guidance dds-profile --interface lab0` on every node, with
   multicast discovery on the lab link: the graph works end to end across A and B, and C, an
   unconfigured ROS participant on the other network, neither sees a node of the graph nor
   reaches the PLC by publishing `pressure_command` and `gaze`. The positive control, in the
   same test: C sees an unconfigured participant on host A within a fraction of the deadline
   (the other network does carry DDS discovery), and that participant sees the graph over the
   lab link (the graph is visible to whoever is on the lab network).
2. A discovery server started by `fabric-guidance discovery-server` on host A's lab address,
   every node its client (ROS_DISCOVERY_SERVER), no multicast route on the lab link: the graph
   works end to end, a configured participant (SUPER_CLIENT) on host B sees it, C does not see
   it and does not reach the PLC; C sees the unconfigured participant on A (control).

Also, without namespaces: the profile against the schema of the Fast DDS wheel, the checks on
interface names and profiles, the commands, and a profile naming no interface of the machine
failing closed (its participants hear nobody).

Shared memory is off in both (the profile has none; FASTDDS_BUILTIN_TRANSPORTS=UDPv4 for the
discovery-server graph): its segments are not per network namespace. Needs root and `ip netns`;
skipped with the reason elsewhere.
"""
import json
import os
from pathlib import Path
import signal
import socket
import subprocess
import sys
import time

import pytest

from fabric_guidance.lab import discovery_server, lab_network
from fabric_guidance.lab.discovery_server import client_env
from fabric_guidance.lab.lab_network import process_env, write_profile
from netns import NetnsGraph, add_host, dds_env, delete_host, ip, link_stats, start_graph, why_no_netns
from rosgraph import CONFIG, ROOT, free_port, fresh_domain_id, wait_until
from test_graph import F_LEFT_40, RESOLUTION_KPA, end_to_end

HOST_A = ('gaze_bridge', 'target_selector', 'pressure_controller')
HOST_B = ('plc_output', 'mock_plc')
GRAPH_NODES = set(HOST_A + HOST_B)
LAB, OTHER = '10.231.8', '10.231.9'
PARTICIPANT = Path(__file__).resolve().parent / 'netns_participant.py'
#: ROS 2's defaults: what a participant nobody configured for the lab runs with.
UNCONFIGURED = {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET'}
#: The positive control (C seeing an unconfigured participant on host A) has this long; seen on
#: this machine within 0.1 s (simple discovery announces at once, then every 3 s).
CONTROL_S = 5.0
#: How long C must see nothing of the graph and move no register, from the start of both
#: participants: at least three times the control's deadline, so that a negative means more
#: than "too early".
NEGATIVE_S = 3 * CONTROL_S
GUIDED = {'L1': F_LEFT_40, 'L2': F_LEFT_40}


def fastdds_schema():
    """The fastdds_profiles.xsd of the installed ros-fastdds wheel (found through its file list)."""
    xmlschema = pytest.importorskip('xmlschema', reason='xmlschema is not installed (requirements/test.txt)')
    from importlib import metadata
    try:
        dist = metadata.distribution('ros-fastdds')
    except metadata.PackageNotFoundError:
        pytest.skip('the ros-fastdds wheel is not installed: no fastdds_profiles.xsd to check against')
    xsd = [f for f in dist.files or [] if f.name == 'fastdds_profiles.xsd']
    assert xsd, 'the ros-fastdds wheel lists no fastdds_profiles.xsd'
    return xmlschema.XMLSchema(str(dist.locate_file(xsd[0])))


@pytest.mark.parametrize('interface', ['enp3s0', 'lab0', '192.168.1.10', 'wlp0s20f3.100'])
def test_the_profile_is_valid_fast_dds_xml_and_pins_exactly_that_interface(tmp_path, interface):
    path = write_profile(tmp_path / 'lab.xml', interface)
    fastdds_schema().validate(str(path))
    assert lab_network.validate_profile(path.read_text(), str(path)) == interface
    assert process_env(path) == {lab_network.profile_variable(): str(path),
                                 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SYSTEM_DEFAULT'}


FAST_DDS_CASES = [('jazzy', 'FASTRTPS_DEFAULT_PROFILES_FILE'), ('humble', 'FASTRTPS_DEFAULT_PROFILES_FILE'),
                  ('kilted', 'FASTDDS_DEFAULT_PROFILES_FILE'), ('', 'FASTDDS_DEFAULT_PROFILES_FILE')]


@pytest.mark.parametrize('distro, variable', FAST_DDS_CASES)
def test_every_profile_setting_names_the_variable_of_the_distributions_fast_dds(tmp_path, monkeypatch, distro,
                                                                                variable):
    """Fast DDS 2.x (Jazzy) reads only FASTRTPS_DEFAULT_PROFILES_FILE, Fast DDS 3 (Kilted)
    FASTDDS_DEFAULT_PROFILES_FILE: with the other one alone, the distribution silently drops the
    profile, and a simulated graph's DDS reaches the network (SYSTEM_DEFAULT range). With both,
    Kilted prefers the old name and warns in every process: the one of ROS_DISTRO is set."""
    from fabric_guidance.graph.process_graph import Graph, loopback_dds_env
    monkeypatch.setenv('ROS_DISTRO', distro)
    monkeypatch.setenv('FASTRTPS_DEFAULT_PROFILES_FILE' if variable.startswith('FASTDDS') else
                       'FASTDDS_DEFAULT_PROFILES_FILE', '/an/inherited/profile.xml')
    other = next(v for v in lab_network.PROFILE_VARIABLES if v != variable)
    loopback = str(CONFIG / 'fastdds_loopback.xml')
    for where, env, profile in (('lab_network.process_env', process_env(tmp_path / 'p.xml'), str(tmp_path / 'p.xml')),
                                ('process_graph.loopback_dds_env', loopback_dds_env(), loopback),
                                ('process_graph.Graph.env', Graph(tmp_path / 'g').env, loopback)):
        assert env.get(variable) == profile, f'{where}: {variable}'
        assert other not in env, f'{where}: {other}'
        assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SYSTEM_DEFAULT', where
    # The launch files set the profile through launch_support.loopback_dds_actions only (run under
    # the real launch system by test_launch.py), never one variable by hand.
    for launch_file in sorted((ROOT / 'launch').glob('*.launch.py')):
        text = launch_file.read_text()
        assert 'FASTDDS_DEFAULT_PROFILES_FILE' not in text and 'FASTRTPS' not in text, launch_file.name
    assert 'lab_network.profile_env(profile)' in (ROOT / 'fabric_guidance' / 'graph' / 'launch_support.py').read_text()


def test_the_loopback_profile_of_the_demo_passes_the_same_check():
    """The check reads any profile of this shape: the simulated graph's pins 127.0.0.1."""
    fastdds_schema().validate(str(CONFIG / 'fastdds_loopback.xml'))
    assert lab_network.validate_profile((CONFIG / 'fastdds_loopback.xml').read_text()) == '127.0.0.1'


#: A participant that says 'ready' once it exists and lives until its stdin closes.
READY_PARTICIPANT = ("import sys, rclpy; rclpy.init(); node = rclpy.create_node('tls_probe'); "
                     "print('ready', flush=True); sys.stdin.read()")


def _thread_names(profile: Path | None) -> list[str]:
    env = dict(os.environ, ROS_DOMAIN_ID=str(fresh_domain_id()))
    for name in lab_network.PROFILE_VARIABLES:
        env.pop(name, None)
    if profile is not None:
        env.update(process_env(profile))
    proc = subprocess.Popen([sys.executable, '-c', READY_PARTICIPANT], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            text=True, env=env)
    try:
        assert proc.stdout.readline() == 'ready\n'
        task = Path('/proc') / str(proc.pid) / 'task'
        return sorted((task / t / 'comm').read_text().strip() for t in os.listdir(task))
    finally:
        proc.stdin.close()
        proc.wait(60)


@pytest.mark.graph
def test_no_participant_of_the_packages_profiles_runs_the_type_lookup_service(tmp_path):
    """Fast DDS 3.2's type lookup reply thread killed plc_output at discovery in CI: SIGSEGV in
    TypeLookupManager::notify_callbacks (the kernel log named the thread, dds.tls.replies), and the
    node's log stayed empty. Both profiles turn the service off (fastdds.type_propagation disabled):
    a participant made with either has no dds.tls thread. Control: with no profile it has them."""
    assert any(name.startswith('dds.tls.') for name in _thread_names(None))
    for profile in (CONFIG / 'fastdds_loopback.xml', write_profile(tmp_path / 'lab.xml', 'lo')):
        names = _thread_names(profile)
        assert any(name.startswith('dds.udp.') for name in names), (profile, names)   # Fast DDS is there
        assert not any(name.startswith('dds.tls.') for name in names), (profile, names)


@pytest.mark.parametrize('bad, reason', [
    ('', 'neither an IPv4 address nor a network device name'),
    ('a-name-of-16-chr', 'neither an IPv4 address nor'),
    ('eth0/1', 'neither'), ('eth 0', 'neither'), ('eth0"', 'neither'), ('en:1', 'neither'),
    ('fe80::1', 'an IPv6 address'), ('239.255.0.1', 'multicast or 0.0.0.0'), ('0.0.0.0', 'multicast or 0.0.0.0'),
])
def test_an_unusable_interface_is_refused_naming_it(bad, reason):
    with pytest.raises(ValueError, match=reason) as exc:
        lab_network.interface_profile(bad)
    assert repr(bad) in str(exc.value) and '\n' not in str(exc.value)


def _edit(text, old, new):
    assert old in text
    return text.replace(old, new)


@pytest.mark.parametrize('old, new, field', [
    ('<interface name="lab0"/>', '<interface name="lab0"/><interface name="wlan0"/>', 'allowlist: 2 interfaces'),
    ('<allowlist>', '<allowlist></allowlist><blocklist><interface name="wlan0"/></blocklist><allowlist>', 'blocklist'),
    ('<useBuiltinTransports>false', '<useBuiltinTransports>true', 'useBuiltinTransports is not false'),
    ('is_default_profile="true"', 'is_default_profile="false"', '0 with is_default_profile'),
    ('<type>UDPv4</type>', '<type>TCPv4</type>', 'type is not UDPv4'),
    ('<userTransports>', '<userTransports><transport_id>shm</transport_id>', 'userTransports'),
    ('<dds xmlns="http://www.eprosima.com">', '<dds>', 'root element'),
    ('</dds>', '', 'not XML'),
])
def test_a_profile_that_does_not_pin_one_interface_is_refused_naming_the_field(old, new, field):
    text = _edit(lab_network.interface_profile('lab0'), old, new)
    with pytest.raises(ValueError, match=field) as exc:
        lab_network.validate_profile(text, 'lab.xml')
    assert str(exc.value).startswith('lab.xml: ')


def test_dds_profile_command_writes_checks_and_refuses(tmp_path):
    def cli(*argv):
        return subprocess.run([sys.executable, '-m', 'fabric_guidance.commands.cli', 'dds-profile', *argv],
                              capture_output=True, text=True, timeout=60, cwd=ROOT)
    out = cli('--interface', 'lo', '--out', str(tmp_path / 'p.xml'))
    assert out.returncode == 0, out.stderr
    # The variable of the distribution it runs on (ROS_DISTRO; Kilted's without it), the other not.
    assert f'export {lab_network.profile_variable()}={tmp_path / "p.xml"}' in out.stdout
    assert sum(f'export {v}=' in out.stdout for v in lab_network.PROFILE_VARIABLES) == 1
    assert 'export ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT' in out.stdout
    assert 'no interface named' not in out.stderr     # lo exists everywhere
    checked = cli('--check', str(tmp_path / 'p.xml'))
    assert checked.returncode == 0 and 'DDS pinned to interface lo' in checked.stdout
    refused = cli('--interface', 'fe80::1', '--out', str(tmp_path / 'q.xml'))
    assert refused.returncode == 2 and not (tmp_path / 'q.xml').exists()
    assert refused.stderr.strip().splitlines() == [
        "fabric-guidance dds-profile: error: interface 'fe80::1': an IPv6 address; the profile pins the UDPv4 "
        'transport, give the IPv4 address or the device name']
    (tmp_path / 'two.xml').write_text(lab_network.interface_profile('lo').replace(
        '<interface name="lo"/>', '<interface name="lo"/><interface name="eth0"/>'))
    bad = cli('--check', str(tmp_path / 'two.xml'))
    assert bad.returncode == 2 and f'{tmp_path / "two.xml"}: interfaces/allowlist: 2 interfaces' in bad.stderr


@pytest.mark.parametrize('text, expected', [('192.168.1.10', ('192.168.1.10', 11811)),
                                            ('10.0.0.2:11888', ('10.0.0.2', 11888))])
def test_discovery_server_addresses(text, expected):
    assert discovery_server.parse_locator(text) == expected


@pytest.mark.parametrize('bad, reason', [('lab-pc', 'not an IPv4 address'), ('10.0.0.1:0', 'port'),
                                         ('10.0.0.1:x', 'port'), ('0.0.0.0', 'one interface'),
                                         ('fe80::1', 'not an IPv4 address')])
def test_a_bad_discovery_server_address_is_refused_naming_it(bad, reason):
    with pytest.raises(ValueError, match=reason) as exc:
        discovery_server.client_env(bad)
    assert repr(bad) in str(exc.value)


def test_clients_list_every_server():
    assert discovery_server.client_env(['10.0.0.1', '10.0.0.2:11900']) == {
        'ROS_DISCOVERY_SERVER': '10.0.0.1:11811;10.0.0.2:11900'}


def test_the_discovery_server_is_found_in_the_wheels_and_runs(tmp_path):
    """The server is found by code (the wheel's file list), with its libraries and command index;
    `fabric-guidance discovery-server` execs it, and it stops on SIGINT. (Its clients: the
    discovery-server graph test below.)"""
    tool = discovery_server.find_server()
    assert Path(tool.prefix[0]).name == 'fast-discovery-server' and os.access(tool.prefix[0], os.X_OK)
    printed = subprocess.run([sys.executable, '-m', 'fabric_guidance.commands.cli', 'discovery-server', '--listen',
                              '127.0.0.1:0', '--print'], capture_output=True, text=True, timeout=60)
    assert printed.returncode == 2 and "port '0' is not 1-65535" in printed.stderr
    port = free_port(socket.SOCK_DGRAM)
    log = open(tmp_path / 'server.log', 'w')
    server = subprocess.Popen([sys.executable, '-m', 'fabric_guidance.commands.cli', 'discovery-server', '--listen',
                               f'127.0.0.1:{port}'], stdout=log, stderr=subprocess.STDOUT)
    try:
        wait_until(lambda: f'UDPv4:[127.0.0.1]:{port}' in (tmp_path / 'server.log').read_text(), 30.0,
                   what='the server running')
        server.send_signal(signal.SIGINT)
        assert server.wait(10) == 0
    finally:
        if server.poll() is None:
            server.kill()
            server.wait()
        log.close()


@pytest.mark.graph
def test_a_profile_naming_no_interface_of_the_machine_fails_closed(tmp_path):
    """A typo in the interface name: Fast DDS finds nothing to allow and its participants hear
    nobody (not: every interface). Control: the same two participants with the loopback profile
    of the demo see each other."""
    typo = write_profile(tmp_path / 'typo.xml', 'nosuchif0')
    loopback = CONFIG / 'fastdds_loopback.xml'
    pairs = {}
    for name, profile in (('loopback', loopback), ('typo', typo)):   # both pairs at once, a domain each
        env = dds_env(dict(os.environ, ROS_DOMAIN_ID=str(fresh_domain_id())), process_env(profile))
        pairs[name] = [subprocess.Popen([sys.executable, str(PARTICIPANT), '--name', f'{name}_{i}', '--seconds', '6'],
                                        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
                       for i in (1, 2)]
    seen = {}
    for name, pair in pairs.items():
        outs = [p.communicate(timeout=60)[0] for p in pair]
        seen[name] = [{n for line in outs[i].splitlines() if line.startswith('{') for n in json.loads(line)['nodes']}
                      for i in (0, 1)]
        if name == 'typo':
            assert 'All whitelist interfaces were filtered out' in outs[0] + outs[1]
    assert seen['loopback'] == [{'loopback_2'}, {'loopback_1'}], seen
    assert seen['typo'] == [set(), set()], seen


@pytest.fixture
def lab_hosts():
    why = why_no_netns()
    if why:
        pytest.skip(f'cannot build the lab network in network namespaces: {why}')
    pid = os.getpid()
    a, b, c = f'fla{pid}', f'flb{pid}', f'flc{pid}'
    try:
        for ns in (a, b, c):
            add_host(ns)
            # No IPv6 (router solicitations, MLD): a link's counters then show IPv4 traffic alone.
            subprocess.run(['ip', 'netns', 'exec', ns, 'sysctl', '-q', '-w', 'net.ipv6.conf.all.disable_ipv6=1',
                            'net.ipv6.conf.default.disable_ipv6=1'], check=True)
        # The lab link, named lab0 on both hosts: one profile naming the device serves both.
        ip('link', 'add', f'la{pid}', 'netns', a, 'type', 'veth', 'peer', 'name', f'lb{pid}', 'netns', b)
        ip('-n', a, 'link', 'set', f'la{pid}', 'name', 'lab0')
        ip('-n', b, 'link', 'set', f'lb{pid}', 'name', 'lab0')
        # The other network: a bridge on host C, with host A and host B on it as other0.
        ip('-n', c, 'link', 'add', 'br0', 'type', 'bridge')
        for ns, veth, peer in ((a, f'oa{pid}', f'ca{pid}'), (b, f'ob{pid}', f'cb{pid}')):
            ip('link', 'add', veth, 'netns', ns, 'type', 'veth', 'peer', 'name', peer, 'netns', c)
            ip('-n', ns, 'link', 'set', veth, 'name', 'other0')
            ip('-n', c, 'link', 'set', peer, 'master', 'br0')
            ip('-n', c, 'link', 'set', peer, 'up')
        for ns, dev, address in ((a, 'lab0', f'{LAB}.1'), (b, 'lab0', f'{LAB}.2'), (a, 'other0', f'{OTHER}.1'),
                                 (b, 'other0', f'{OTHER}.2'), (c, 'br0', f'{OTHER}.3')):
            ip('-n', ns, 'addr', 'add', f'{address}/24', 'dev', dev)
            ip('-n', ns, 'link', 'set', dev, 'up')
        # A veth's carrier comes up after `link set up` returns (the kernel's link watch, up to a
        # second on some machines); Fast DDS leaves out an interface that is not up yet when a
        # participant starts, and a profile allowing that interface alone then has no transport.
        links = ((a, 'lab0'), (b, 'lab0'), (a, 'other0'), (b, 'other0'), (c, 'br0'))
        wait_until(lambda: all(operstate(ns, dev) == 'UP' for ns, dev in links), 10.0,
                   what='every link of the lab network up')
        yield a, b, c
    finally:
        for ns in (a, b, c):
            delete_host(ns)


def operstate(ns, dev) -> str:
    """The link's operational state in namespace ns (UP once it has a carrier)."""
    return json.loads(ip('-n', ns, '-j', 'link', 'show', 'dev', dev).stdout)[0].get('operstate', '')


def multicast_route(ns, dev):
    """Multicast (simple discovery) leaves `ns` by `dev`; without a route it leaves nowhere."""
    ip('-n', ns, 'route', 'add', '224.0.0.0/4', 'dev', dev)


class Participant:
    """netns_participant.py on a host, its reports in a file."""

    def __init__(self, ns, name, env, log_dir, seconds, intrude=False):
        publish = ['--publish', 'pressure_command', '--publish', 'gaze'] if intrude else []
        self.name = name
        self.path = Path(log_dir) / f'{name}.jsonl'
        self.log = open(self.path, 'w')
        self.proc = subprocess.Popen(
            ['ip', 'netns', 'exec', ns, sys.executable, str(PARTICIPANT), '--name', name, '--seconds', str(seconds),
             *publish], stdout=self.log, stderr=subprocess.STDOUT, env=env)

    def reports(self) -> list[dict]:
        out = []
        for line in self.path.read_text().splitlines():
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:   # a log line of rclpy, or one being written
                pass
        return out

    def nodes_seen(self) -> set:
        return {n for r in self.reports() for n in r['nodes']}

    def matched(self) -> dict:
        """The most remote subscriptions ever matched per topic it publishes."""
        best = {}
        for r in self.reports():
            for topic, count in r['subscribers'].items():
                best[topic] = max(best.get(topic, 0), count)
        return best

    def close(self):
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.log.close()


def stop_everything(participants, hololens, graph, watch):
    """The end of a namespace test: the extra participants, the HoloLens stub, the graph, the
    register watch."""
    for p in participants:
        p.close()
    if hololens is not None:
        hololens.close()
    graph.stop_all()
    if watch is not None:
        watch.client.close()


def intruder_sees_and_moves_nothing(intruder, control, watch):
    """From the moment both participants are up until NEGATIVE_S later: the intruder sees no
    node of the graph, matches no subscription, and no register leaves the guided values (F1,
    which only the intruder commands, stays 0); and it sees the control within CONTROL_S.
    Returns how long the control took to be seen, and the number of register reads."""
    wait_until(lambda: intruder.reports() and control.reports(), 30.0, what='both participants up')
    t_up = max(intruder.reports()[0]['m'], control.reports()[0]['m'])
    reads, t_control = 0, None
    while time.monotonic() - t_up < NEGATIVE_S:
        now = watch.read()
        reads += 1
        assert now['F1'] <= RESOLUTION_KPA, f'the intruder reached the PLC: F1 at {now["F1"]:.1f} kPa'
        assert abs(now['L1'] - F_LEFT_40) <= RESOLUTION_KPA, f'guidance disturbed: L1 at {now["L1"]:.1f} kPa'
        if t_control is None:
            t_control = next((r['m'] - t_up for r in intruder.reports() if control.name in r['nodes']), None)
        time.sleep(0.05)
    assert t_control is not None and t_control <= CONTROL_S, (
        f'the control failed: {intruder.name} on host C did not see {control.name} on host A within '
        f'{CONTROL_S:.0f} s (seen after {t_control} s): the negative below would mean nothing')
    assert intruder.proc.poll() is None, f'{intruder.name} ended early: {intruder.path.read_text()[-2000:]}'
    seen = intruder.nodes_seen() & GRAPH_NODES
    assert not seen, f'{intruder.name} on the other network saw nodes of the graph: {sorted(seen)}'
    assert not any(intruder.matched().values()), f'{intruder.name} matched subscriptions: {intruder.matched()}'
    return t_control, reads


@pytest.mark.graph
@pytest.mark.serial   # guidance unbroken for NEGATIVE_S: a loaded machine's stale-gaze vent would read as a disturbance
def test_pinned_to_the_lab_interface_the_graph_works_and_the_other_network_neither_sees_nor_drives_it(
        lab_hosts, tmp_path):
    a, b, c = lab_hosts
    # The multicast route of both lab hosts points at the other network, as on a PC whose
    # default route is the Wi-Fi: without the profile, discovery would go there.
    for ns, dev in ((a, 'other0'), (b, 'other0'), (c, 'br0')):
        multicast_route(ns, dev)
    profile = write_profile(tmp_path / 'fastdds_lab.xml', 'lab0')
    hosts = {**{n: a for n in HOST_A}, **{n: b for n in HOST_B}}
    graph = NetnsGraph(tmp_path / 'logs', hosts, dds=process_env(profile))
    hololens = watch = None
    others = []
    try:
        hololens, watch = start_graph(graph, a, b, tmp_path)
        t0 = time.monotonic()
        wait_until(lambda: watch.matches(GUIDED), 30.0, what='guidance at the PLC across the lab link')
        t_guided = time.monotonic() - t0
        quiet = {ns: link_stats(ns, 'other0')['tx']['packets'] for ns in (a, b)}

        unconfigured = dds_env(dict(os.environ, ROS_DOMAIN_ID=str(graph.domain_id)), UNCONFIGURED)
        seconds = NEGATIVE_S + 40   # start-up under load, and the rest of the test
        intruder = Participant(c, 'intruder', unconfigured, tmp_path, seconds, intrude=True)
        others.append(intruder)
        control = Participant(a, 'other_net_control', unconfigured, tmp_path, seconds)
        others.append(control)
        t_control, reads = intruder_sees_and_moves_nothing(intruder, control, watch)
        # The unconfigured participant on host A also reaches the lab link: it sees the graph.
        wait_until(lambda: GRAPH_NODES <= control.nodes_seen(), 5.0, what='the control seeing the graph on lab0')

        # Before C and the control started, the graph had sent nothing on the other network.
        assert quiet == {a: 0, b: 0}, f'packets sent on other0 by the pinned graph: {quiet}'
        stale_vent, watchdog_vent = end_to_end(graph, hololens, watch)
        print(f'\n[lab network, pinned to lab0] guided in {t_guided:.1f} s; control seen after {t_control:.2f} s '
              f'(deadline {CONTROL_S:.0f} s); graph unseen and {reads} register reads unmoved for {NEGATIVE_S:.0f} s; '
              f'vents {stale_vent:.3f} s, {watchdog_vent:.3f} s')
    finally:
        stop_everything(others, hololens, graph, watch)


@pytest.mark.graph
@pytest.mark.serial   # guidance unbroken for NEGATIVE_S: a loaded machine's stale-gaze vent would read as a disturbance
def test_with_a_discovery_server_and_no_multicast_the_graph_works_and_an_unconfigured_participant_sees_nothing(
        lab_hosts, tmp_path):
    a, b, c = lab_hosts
    # Multicast nowhere on the lab link. On the other network it works (host A's other0, host C):
    # the control discovers C that way.
    multicast_route(a, 'other0')
    multicast_route(c, 'br0')
    server_address = f'{LAB}.1:11811'
    server_log = open(tmp_path / 'discovery_server.log', 'w')
    server = subprocess.Popen(['ip', 'netns', 'exec', a, sys.executable, '-m', 'fabric_guidance.commands.cli',
                               'discovery-server', '--listen', server_address],
                              stdout=server_log, stderr=subprocess.STDOUT)
    hosts = {**{n: a for n in HOST_A}, **{n: b for n in HOST_B}}
    # Every node a discovery client; UDP only (no shared memory between the namespaces).
    graph = NetnsGraph(tmp_path / 'logs', hosts,
                       dds={**client_env(server_address), 'FASTDDS_BUILTIN_TRANSPORTS': 'UDPv4'})
    hololens = watch = None
    others = []
    try:
        wait_until(lambda: 'Server started' in (tmp_path / 'discovery_server.log').read_text(), 30.0,
                   what=f'the discovery server on {server_address}')
        hololens, watch = start_graph(graph, a, b, tmp_path)
        t0 = time.monotonic()
        wait_until(lambda: watch.matches(GUIDED), 30.0, what='guidance at the PLC, discovered through the server')
        t_guided = time.monotonic() - t0

        domain = {'ROS_DOMAIN_ID': str(graph.domain_id)}
        unconfigured = dds_env({**os.environ, **domain}, UNCONFIGURED)
        seconds = NEGATIVE_S + 40
        intruder = Participant(c, 'intruder', unconfigured, tmp_path, seconds, intrude=True)
        others.append(intruder)
        control = Participant(a, 'other_net_control', unconfigured, tmp_path, seconds)
        others.append(control)
        # A participant given the server (as `ros2` tools are: a super client) sees the graph.
        configured = dds_env({**os.environ, **domain}, {**client_env(server_address), 'ROS_SUPER_CLIENT': 'TRUE'})
        observer = Participant(b, 'configured_observer', configured, tmp_path, seconds)
        others.append(observer)
        t_control, reads = intruder_sees_and_moves_nothing(intruder, control, watch)
        assert GRAPH_NODES <= observer.nodes_seen(), f'the configured observer saw only {sorted(observer.nodes_seen())}'
        assert not GRAPH_NODES & control.nodes_seen(), 'the unconfigured participant on host A saw the graph'

        stale_vent, watchdog_vent = end_to_end(graph, hololens, watch)
        print(f'\n[lab network, discovery server {server_address}] guided in {t_guided:.1f} s; control seen after '
              f'{t_control:.2f} s (deadline {CONTROL_S:.0f} s); graph unseen and {reads} register reads unmoved for '
              f'{NEGATIVE_S:.0f} s; vents {stale_vent:.3f} s, {watchdog_vent:.3f} s')
    finally:
        stop_everything(others, hololens, graph, watch)
        server.send_signal(signal.SIGINT)
        try:
            server.wait(10)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()
        server_log.close()
