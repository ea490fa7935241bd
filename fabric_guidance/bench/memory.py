"""Resident memory of every lab node beside a bare rclpy node, in the same environment and the
same ROS domain: what each node costs on top of rclpy itself.

Every node is started idle (no gaze, no PLC answering: plc_output keeps retrying its link),
as it sits at the start of a session; its RSS is read from /proc once it has been steady for a
second (all of them on the same ticks). The bare node is `rclpy.create_node` spun by a
SingleThreadedExecutor, nothing else.
"""
from __future__ import annotations

from pathlib import Path
import socket
import subprocess
import sys
import time
from typing import Callable

from ..graph.process_graph import Graph, free_port
from .graphs import FILES, SIM_CALIBRATION, rss_mb

#: The lab nodes (the simulators stand in for hardware and are left out).
LAB_NODES = ('gaze_bridge', 'target_selector', 'pressure_controller', 'plc_output', 'headset_display',
             'bag_recorder')
BARE = 'bare rclpy node'
#: Nodes that may load scipy: the one that fits Algorithm 1 (and only when it does).
FITS = ('pressure_controller',)

BARE_NODE = '''
import signal, threading, rclpy
from rclpy.executors import SingleThreadedExecutor
rclpy.init()
node = rclpy.create_node('bare_node')
stop = threading.Event()
signal.signal(signal.SIGINT, lambda *a: stop.set())
signal.signal(signal.SIGTERM, lambda *a: stop.set())
executor = SingleThreadedExecutor()
executor.add_node(node)
print('bare node spinning', flush=True)
while not stop.is_set():
    executor.spin_once(timeout_sec=0.05)
node.destroy_node()
rclpy.shutdown()
'''


def _steady_rss(pids: dict[str, int], timeout_s: float = 30.0) -> dict[str, float | None]:
    """{name: RSS} of each process once two of its readings a second apart differ by less than
    0.5 MB (start-up done). All are read on the same one-second ticks: the processes run side by
    side, so waiting for one after the other would only add seconds."""
    deadline = time.monotonic() + timeout_s
    last = {name: rss_mb(pid) for name, pid in pids.items()}
    steady: dict[str, float | None] = {}
    while len(steady) < len(pids) and time.monotonic() < deadline:
        time.sleep(1.0)
        for name, pid in pids.items():
            if name in steady:
                continue
            now = rss_mb(pid)
            if now is None or (last[name] is not None and abs(now - last[name]) < 0.5):
                steady[name] = now
            last[name] = now
    return {name: steady.get(name, last[name]) for name in pids}


def node_rss(work: Path, say: Callable[[str], None], nodes: tuple[str, ...] = LAB_NODES) -> dict[str, float | None]:
    """{name: MB} for the bare node and every lab node of `nodes`, started together and idle."""
    graph = Graph(Path(work) / 'memory_logs')
    bare = None
    overrides = {
        'gaze_bridge': lambda: {'port': free_port(socket.SOCK_DGRAM)},
        'target_selector': dict,
        'pressure_controller': lambda: {'calibration_file': str(SIM_CALIBRATION),
                                        'calibration_dir': str(Path(work) / 'calibrations')},
        'plc_output': lambda: {'plc_port': free_port()},      # nobody listens: it retries
        'headset_display': lambda: {'display_port': free_port(socket.SOCK_DGRAM)},
        'bag_recorder': lambda: {'output': str(Path(work) / 'memory_bag')},
    }
    try:
        bare = subprocess.Popen([sys.executable, '-c', BARE_NODE], env=graph.env, stdout=subprocess.DEVNULL,
                                stderr=subprocess.STDOUT)
        for name in nodes:
            graph.start(name, FILES, **overrides[name]())
        say(f'  resident memory of {len(nodes)} idle lab nodes and a bare rclpy node ...')
        alive = {name: graph.processes[name].pid for name in nodes if graph.processes[name].poll() is None}
        steady = _steady_rss({BARE: bare.pid, **alive})
        return {BARE: steady[BARE], **{name: steady.get(name) for name in nodes}}
    finally:
        if bare is not None:
            bare.terminate()
            try:
                bare.wait(10)
            except subprocess.TimeoutExpired:
                bare.kill()
        graph.stop_all(check=False)
