"""Test support for graphs split over network namespaces ("hosts") that the tests build
themselves: test_netns.py (two hosts on one link) and test_lab_network.py (hosts with a lab
link and a second network, a third host on that second network). Needs root (CAP_SYS_ADMIN)
and `ip netns`; why_no_netns() says why not where that is not allowed (containers, CI runners).
"""
import ctypes
import json
import os
from pathlib import Path
import shutil
import subprocess
import threading
import uuid

import socket

from rosgraph import Graph, free_port
from test_graph import SIM_CAL, HoloLensStub, RegisterWatch

CLONE_NEWNET = 0x40000000
#: Two hosts discovering each other by multicast on their one link, UDP only (test_netns.py):
#: shared memory is switched off so that nothing can take a same-machine shortcut between
#: namespaces (its segments in /dev/shm are not per network namespace).
SUBNET_UDP_ENV = {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET', 'FASTDDS_BUILTIN_TRANSPORTS': 'UDPv4'}
#: Environment a process may have inherited that decides its DDS set-up; a NetnsGraph or a
#: participant starts from none of it and sets what it wants.
# Both profile variables: Fast DDS 3's rmw takes an inherited FASTRTPS_DEFAULT_PROFILES_FILE (the
# test process's loopback profile) over a FASTDDS_DEFAULT_PROFILES_FILE set here.
DDS_VARIABLES = ('FASTDDS_DEFAULT_PROFILES_FILE', 'FASTRTPS_DEFAULT_PROFILES_FILE', 'ROS_AUTOMATIC_DISCOVERY_RANGE',
                 'FASTDDS_BUILTIN_TRANSPORTS',
                 'ROS_DISCOVERY_SERVER', 'ROS_SUPER_CLIENT', 'ROS_STATIC_PEERS', 'ROS_LOCALHOST_ONLY')


def ip(*args, check=True):
    return subprocess.run(['ip', *args], capture_output=True, text=True, check=check)


def why_no_netns():
    """None where the tests may create network namespaces, else the reason."""
    if shutil.which('ip') is None:
        return '`ip` (iproute2) is not installed'
    if os.geteuid() != 0:
        return 'network namespaces need root (CAP_SYS_ADMIN); this runs as an ordinary user'
    probe = f'fgprobe{os.getpid()}'
    out = ip('netns', 'add', probe, check=False)
    if out.returncode != 0:
        return f'`ip netns add` is not allowed here: {out.stderr.strip()}'
    ip('netns', 'del', probe, check=False)
    return None


def add_host(ns):
    """A network namespace as a host of its own: loopback up, and its own machine id. Fast DDS
    takes participants with the same /etc/machine-id for one host and then drops the other's
    unicast locators when an interface allowlist leaves out loopback (the lab profile does):
    namespaces sharing the machine's id never discover each other. `ip netns exec` mounts
    /etc/netns/<ns>/machine-id over /etc/machine-id, as two PCs have two ids."""
    ip('netns', 'add', ns)
    ip('-n', ns, 'link', 'set', 'lo', 'up')
    etc = Path('/etc/netns') / ns
    etc.mkdir(parents=True, exist_ok=True)
    (etc / 'machine-id').write_text(uuid.uuid4().hex + '\n')


def delete_host(ns):
    ip('netns', 'del', ns, check=False)   # takes its links with it
    shutil.rmtree(Path('/etc/netns') / ns, ignore_errors=True)


def in_netns(name, fn):
    """Run fn() on a thread that has entered network namespace `name` (setns affects only the
    calling thread); sockets it creates stay in that namespace whoever uses them later."""
    result = {}

    def run():
        libc = ctypes.CDLL(None, use_errno=True)
        fd = os.open(f'/var/run/netns/{name}', os.O_RDONLY)
        try:
            if libc.setns(fd, CLONE_NEWNET) != 0:
                raise OSError(ctypes.get_errno(), f'setns into {name} failed')
        finally:
            os.close(fd)
        try:
            result['value'] = fn()
        except BaseException as exc:  # noqa: BLE001 - handed to the caller
            result['error'] = exc
    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join()
    if 'error' in result:
        raise result['error']
    return result['value']


def dds_env(base: dict, overrides: dict) -> dict:
    """`base` without any inherited DDS set-up, plus `overrides`."""
    env = {k: v for k, v in base.items() if k not in DDS_VARIABLES}
    env.update(overrides)
    return env


class NetnsGraph(Graph):
    """A Graph whose nodes run on the hosts `hosts` names (`ip netns exec`, which execs: the
    Popen's pid is the node's), with `dds` as their DDS set-up (default: multicast on the
    hosts' links, UDP only; the loopback profile of the simulated graph never crosses hosts)."""

    def __init__(self, log_dir, hosts, dds=None):
        super().__init__(log_dir)
        self.hosts = hosts
        self.env = dds_env(self.env, SUBNET_UDP_ENV if dds is None else dds)

    def command_prefix(self, node):
        return ['ip', 'netns', 'exec', self.hosts[node]]


class NetnsRegisterWatch(RegisterWatch):
    """RegisterWatch whose Modbus socket lives on the PLC's host."""

    def __init__(self, port, ns):
        super().__init__(port)
        self.ns = ns

    def read(self):
        return in_netns(self.ns, super().read)


def link_stats(ns: str, dev: str) -> dict:
    """The kernel's counters of `dev` in `ns` (rx/tx packets, bytes...)."""
    return json.loads(ip('-n', ns, '-s', '-j', 'link', 'show', 'dev', dev).stdout)[0]['stats64']


#: The parameter files of every namespace graph.
FILES = ('params/guidance.yaml', 'params/sim.yaml')


def start_graph(graph, a, b, tmp_path):
    """The lab graph of test_graph's end-to-end test on hosts a (gaze side) and b (PLC side); the
    HoloLens stub's socket on a, the register watch's on b."""
    plc_port, gaze_port = free_port(), free_port(socket.SOCK_DGRAM)
    graph.start('mock_plc', FILES, port=plc_port)
    graph.start('plc_output', FILES, plc_port=plc_port)
    graph.start('gaze_bridge', FILES, port=gaze_port)
    graph.start('target_selector', FILES, target_names=['left40'], target_positions=[1.5321, 1.2856, 1.2],
                auto_advance=False)
    graph.start('pressure_controller', FILES, calibration_file=str(SIM_CAL),
                calibration_dir=str(tmp_path / 'cal'), stall_timeout_s=0.0)  # a still stub
    hololens = in_netns(a, lambda: HoloLensStub(gaze_port))   # its socket on host A
    watch = NetnsRegisterWatch(plc_port, b)
    return hololens, watch
