"""The lab graph split over two "hosts": two network namespaces joined by a veth pair.

Host A runs gaze_bridge, target_selector and pressure_controller (and the HoloLens stub);
host B runs plc_output and mock_plc. The only thing between them is ROS 2's DDS over UDP on
the veth link (shared memory is switched off with FASTDDS_BUILTIN_TRANSPORTS=UDPv4, so the
commands cannot take a same-machine shortcut), discovered by multicast on that link
(ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET: the namespaces are an isolated network of two, so
this does not reach beyond them). It passes the end-to-end test of test_graph.py unchanged:
guidance reaches the PLC, a stopped gaze vents, SIGKILL of plc_output lets the PLC watchdog
vent. Needs root (CAP_SYS_ADMIN) and `ip netns`; skipped with the reason where that is not
allowed (containers, CI runners).
"""
import os

import pytest

from netns import NetnsGraph, ip as _ip, link_stats, start_graph, why_no_netns as _why_no_netns
from test_graph import end_to_end

pytestmark = pytest.mark.graph  # starts a process graph with DDS

HOST_A = ('gaze_bridge', 'target_selector', 'pressure_controller')
HOST_B = ('plc_output', 'mock_plc')
SUBNET = '10.231.7'


@pytest.fixture
def two_hosts():
    why = _why_no_netns()
    if why:
        pytest.skip(f'cannot split the graph over two network namespaces: {why}')
    a, b = f'fga{os.getpid()}', f'fgb{os.getpid()}'
    try:
        _ip('netns', 'add', a)
        _ip('netns', 'add', b)
        _ip('link', 'add', f'va{os.getpid()}', 'netns', a, 'type', 'veth', 'peer', 'name', f'vb{os.getpid()}',
            'netns', b)
        for ns, dev, host in ((a, f'va{os.getpid()}', 1), (b, f'vb{os.getpid()}', 2)):
            _ip('-n', ns, 'addr', 'add', f'{SUBNET}.{host}/24', 'dev', dev)
            _ip('-n', ns, 'link', 'set', 'lo', 'up')
            _ip('-n', ns, 'link', 'set', dev, 'up')
            # DDS discovery is multicast: it needs a route on the link.
            _ip('-n', ns, 'route', 'add', '224.0.0.0/4', 'dev', dev)
        yield a, b
    finally:
        _ip('netns', 'del', a, check=False)   # takes the veth pair with it
        _ip('netns', 'del', b, check=False)


def test_the_graph_split_over_two_hosts_passes_the_end_to_end_test(two_hosts, tmp_path):
    a, b = two_hosts
    hosts = {**{n: a for n in HOST_A}, **{n: b for n in HOST_B}}
    graph = NetnsGraph(tmp_path / 'logs', hosts)
    hololens = watch = None
    try:
        hololens, watch = start_graph(graph, a, b, tmp_path)
        stale_vent, watchdog_vent = end_to_end(graph, hololens, watch)
        # The commands crossed the veth link: host A sent DDS traffic over it.
        sent = link_stats(a, f'va{os.getpid()}')['tx']['packets']
        assert sent > 100, f'only {sent} packets left host A over the veth link'
        print(f'[netns] hosts {a} (10.231.7.1: {", ".join(HOST_A)}) and {b} (10.231.7.2: {", ".join(HOST_B)}): '
              f'gaze stop vented in {stale_vent:.3f} s, watchdog in {watchdog_vent:.3f} s; {sent} packets A -> B')
    finally:
        if hololens is not None:
            hololens.close()
        graph.stop_all()
        if watch is not None:
            watch.client.close()
