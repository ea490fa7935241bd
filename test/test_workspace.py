"""The workspace check of the launch stage (make test-launch, after `colcon build`): every
executable of the install tree's lib/fabric_guidance/ starts as `ros2 run` starts it and stops
cleanly, and every command of `fabric-guidance` starts (docs/launch.md, "Dependencies": a module
the package imports and package.xml does not declare fails here). Skipped with one line outside
the launch stage.
"""
import os
import signal
import socket
import subprocess

import pytest

pytestmark = pytest.mark.graph  # starts nodes with DDS

INSTALL = os.environ.get('FABRIC_GUIDANCE_INSTALL')
if not INSTALL:
    pytest.skip('FABRIC_GUIDANCE_INSTALL is not set: run through `make test-launch` (a colcon '
                'build first)', allow_module_level=True)

from fabric_guidance.graph.process_graph import Probe, free_port, fresh_domain_id, wait_until  # noqa: E402

PREFIX = os.path.join(INSTALL, 'fabric_guidance')
SHARE = os.path.join(PREFIX, 'share', 'fabric_guidance')
EXECUTABLES = ('gaze_bridge', 'target_selector', 'pressure_controller', 'plc_output', 'mock_plc',
               'wearer_sim', 'micromanipulator_sim', 'bag_recorder', 'headset_display', 'fabric-guidance')


#: Parameters that keep each node off the ports and folders of a lab (and of other tests).
def _node_arguments(tmp_path):
    plc_port, gaze_port, display_port = free_port(), free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_DGRAM)
    return {
        'gaze_bridge': {'port': gaze_port, 'display_port': display_port},
        'target_selector': {},
        'pressure_controller': {'calibration_dir': str(tmp_path / 'cal')},
        'plc_output': {'plc_port': plc_port},
        'mock_plc': {'port': plc_port, 'records_file': str(tmp_path / 'mock.records.json')},
        'wearer_sim': {'bridge_port': gaze_port},
        'micromanipulator_sim': {},
        'bag_recorder': {'output': str(tmp_path / 'bag')},
        'headset_display': {'display_port': display_port},
    }


def test_every_node_of_the_install_tree_starts_and_stops_cleanly(tmp_path):
    """The workspace check: each node's executable in lib/fabric_guidance (as `ros2 run` starts
    it) with the installed parameter files comes up on the graph and exits 0 on SIGINT, with no
    traceback (a module the package imports and package.xml did not declare fails here)."""
    nodes = [exe for exe in EXECUTABLES if exe != 'fabric-guidance']
    arguments = _node_arguments(tmp_path)
    assert set(arguments) == set(nodes)
    domain_id = fresh_domain_id()
    from fabric_guidance.graph.process_graph import loopback_dds_env
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), PYTHONUNBUFFERED='1', **loopback_dds_env())
    files = [os.path.join(SHARE, 'config', 'params', name) for name in ('guidance.yaml', 'sim.yaml')]
    processes, logs = {}, {}
    try:
        for node in nodes:
            cmd = [os.path.join(PREFIX, 'lib', 'fabric_guidance', node), '--ros-args']
            for f in files + ([os.path.join(SHARE, 'config', 'params', 'micromanipulation.yaml')]
                              if node == 'micromanipulator_sim' else []):
                cmd += ['--params-file', f]
            for key, value in arguments[node].items():
                cmd += ['-p', f'{key}:={value}']
            logs[node] = open(tmp_path / f'{node}.log', 'w+')
            processes[node] = subprocess.Popen(cmd, stdout=logs[node], stderr=subprocess.STDOUT, env=env)
        with Probe(domain_id, 'workspace_check') as probe:
            wait_until(lambda: set(nodes) <= set(probe.node.get_node_names()), 60.0,
                       what=f'every node on the graph: {nodes}')
        for proc in processes.values():
            proc.send_signal(signal.SIGINT)
        codes = {node: proc.wait(20) for node, proc in processes.items()}
    finally:
        for proc in processes.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        for f in logs.values():
            f.close()
    output = {node: (tmp_path / f'{node}.log').read_text() for node in nodes}
    print('\n[workspace] started and stopped: ' + ', '.join(f'{n} (exit {c})' for n, c in codes.items()))
    for node in nodes:
        assert codes[node] == 0 and 'Traceback' not in output[node], \
            f'{node}: exit {codes[node]}\n{output[node][-3000:]}'


def test_every_command_of_the_cli_starts(tmp_path):
    """`fabric-guidance` and each subcommand's --help from the install tree (each subcommand's
    module is imported when it is chosen: replay and recover import rosbags and mcap)."""
    from fabric_guidance.commands.cli import SUBCOMMANDS
    exe = os.path.join(PREFIX, 'lib', 'fabric_guidance', 'fabric-guidance')
    started = []
    for argv in [['--help']] + [[name, '--help'] for name in SUBCOMMANDS]:
        out = subprocess.run([exe, *argv], capture_output=True, text=True, timeout=120, cwd=tmp_path)
        assert out.returncode == 0 and 'usage: fabric-guidance' in out.stdout, f'{argv}: {out.stderr[-2000:]}'
        started.append(' '.join(argv[:1]))
    print(f'\n[workspace] fabric-guidance {", ".join(started)}: each --help exit 0')
