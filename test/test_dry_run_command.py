"""`fabric-guidance dry-run`: the lab graph against a mock PLC on this PC and no wearer_sim, as
`ros2 launch fabric_guidance guidance.launch.py mock_plc:=true` starts it (test_launch_dry_run.py),
for an installation without `ros2 launch`; the operator's tools join it on the shell's domain."""
from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys

import pytest

from fabric_guidance.commands import dry_run
from fabric_guidance.paths import config_path
from cli_support import Command
from rosgraph import free_port, fresh_domain_id, log_tails, wait_until

#: Marks the command's environment, so its nodes (which inherit it) can be found, and their end seen.
MARK = 'FABRIC_GUIDANCE_TEST_MARK'
#: A cold start of the command and its six nodes on a loaded 2-core machine.
STARTED_S = 90.0
#: Discovery, a published status, a restart 2 s after a death and the new process's start.
SEEN_S = 60.0
SIM_CALIBRATION = str(config_path('calibrations/sim-wearer.yaml'))


#: Asks pressure_controller to arm, as `ros2 service call .../enable` does, from a process with
#: the ROS defaults (no loopback profile): what the operator's tools on the PC are.
OPERATOR = '''
import sys
import rclpy
from std_srvs.srv import SetBool
rclpy.init()
node = rclpy.create_node('operator_tool')
client = node.create_client(SetBool, sys.argv[1])
if not client.wait_for_service(timeout_sec=float(sys.argv[2])):
    sys.exit('no service ' + sys.argv[1])
rclpy.spin_until_future_complete(node, client.call_async(SetBool.Request(data=True)), timeout_sec=5.0)
'''


def _operator_env(domain_id: int) -> dict:
    from fabric_guidance.lab.lab_network import PROFILE_VARIABLES
    env = {k: v for k, v in os.environ.items() if k not in (*PROFILE_VARIABLES, 'ROS_AUTOMATIC_DISCOVERY_RANGE')}
    return {**env, 'ROS_DOMAIN_ID': str(domain_id)}


def _controller_status(probe_diagnostics: list, after: dict | None = None) -> dict | None:
    """The latest status values pressure_controller published (from another process than `after`'s)."""
    for msg in reversed(list(probe_diagnostics)):
        for st in msg.status:
            if st.name.startswith('pressure_controller:'):
                values = {kv.key: kv.value for kv in st.values}
                if after is None or values['started'] != after['started']:
                    return values
    return None


def _node_pid(mark: str, node: str) -> int:
    from fabric_guidance.graph.process_graph import processes_with
    found = [line for line in processes_with(MARK, mark) if f'fabric_guidance.nodes.{node} ' in line]
    assert len(found) == 1, found
    return int(found[0].split(':')[0].split()[1])


@pytest.mark.graph
def test_dry_run_runs_the_lab_graph_on_a_mock_plc_disarmed_and_stops_it_vented(tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray
    from std_msgs.msg import Float64MultiArray

    from fabric_guidance import interface
    from fabric_guidance.core import ChannelMap
    from fabric_guidance.graph.process_graph import Probe, processes_with
    from fabric_guidance.nodes import qos
    from fabric_guidance.plc import PlcClient, PlcLinkError, RegisterMap
    from fabric_guidance.plc.records import load_records

    domain_id, plc_port = fresh_domain_id(), free_port()
    gaze_port, display_port = free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_DGRAM)
    mark, logs = f'dry-run-{os.getpid()}-{domain_id}', tmp_path / 'logs'
    operator_env = _operator_env(domain_id)
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), PYTHONUNBUFFERED='1', **{MARK: mark})
    cmd = Command(['dry-run', '--headset-address', '127.0.0.2', '--bind-address', '127.0.0.1', '--study', 'speed',
                   '--plc-port', str(plc_port), '--gaze-port', str(gaze_port), '--display-port', str(display_port),
                   '--calibration-file', SIM_CALIBRATION, '--wearer', 'sim-wearer', '--condition', '2',
                   '--logs', str(logs)], env, new_session=True)
    regmap = RegisterMap.load(config_path('hardware/plc_register_map.yaml'),
                              expected_channels=ChannelMap.load(config_path('hardware/channel_map.yaml')).channels)
    try:
        wait_until(lambda: 'Ctrl-C stops every node' in cmd.text() or cmd.proc.poll() is not None, STARTED_S,
                   what='the dry run to say it runs')
        out = cmd.text()
        assert cmd.proc.poll() is None, out
        assert f'ROS_DOMAIN_ID {domain_id} (from the shell)' in out, out
        assert f'mock PLC 127.0.0.1:{plc_port}' in out and f'UDP 127.0.0.1:{gaze_port}' in out, out
        assert f'display to 127.0.0.2:{display_port}' in out and f'logs in {logs}' in out, out
        assert '/pressure_controller/enable std_srvs/srv/SetBool "{data: true}"' in out, out
        with Probe(domain_id) as probe, PlcClient(regmap, '127.0.0.1', plc_port, timeout_s=1.0) as client:
            diagnostics = probe.subscribe(DiagnosticArray, interface.DIAGNOSTICS, 10)
            commands = probe.subscribe(Float64MultiArray, interface.PRESSURE_COMMAND, qos.COMMAND_QOS)
            # plc_output holds the mock's write claim: its link is up, at the port the command named.

            def claim_holder() -> str:
                try:
                    return client.read_claim_holder()
                except PlcLinkError:
                    # Not answered within the client's timeout (a mock PLC just started on a
                    # loaded machine can leave its first read over 1 s): not yet.
                    return ''

            def registers_now():
                # On a connection of its own: the mock PLC closes one silent for IDLE_S, as the PLC
                # program reaps its sockets, and a wait between two reads may last longer on a loaded
                # machine (and a read left unanswered above may still be answered on the old one).
                client.close()
                return client.read_commands_kpa()
            wait_until(claim_holder, SEEN_S, what="plc_output's link to the mock PLC")
            wait_until(lambda: len(commands) >= 10, SEEN_S, what='pressure commands')
            assert all(max(m.data) == 0.0 for m in commands)
            assert not registers_now().any()
            first = wait_until(lambda: _controller_status(diagnostics), SEEN_S, what="the controller's status")
            # Disarmed, with the options' wearer, calibration and condition over the files'.
            assert (first['enabled'], first['wearer'], first['calibration'], first['condition']) == \
                ('False', 'sim-wearer', 'sim-wearer', '2'), first
            names = wait_until(lambda: {'mock_plc', *dry_run.LAB_NODES} <= set(probe.node.get_node_names())
                               and probe.node.get_node_names(), SEEN_S, what='the six nodes on the domain')
            assert 'wearer_sim' not in names
            running = processes_with(MARK, mark)
            assert not [line for line in running if 'wearer_sim' in line], running
            assert len([line for line in running if 'fabric_guidance.nodes.' in line]) == 6, running

            # The operator arms from a process with the ROS defaults, on the shell's domain.
            subprocess.run([sys.executable, '-c', OPERATOR, interface.full_name(interface.ENABLE), str(SEEN_S)],
                           env=operator_env, check=True, timeout=SEEN_S + 30)
            wait_until(lambda: (_controller_status(diagnostics) or {}).get('enabled') == 'True', SEEN_S,
                       what="the operator's enable")
            # The controller's death: started again, disarmed; another node's: said, and left down.
            armed = _controller_status(diagnostics)
            os.kill(_node_pid(mark, 'pressure_controller'), signal.SIGKILL)
            wait_until(lambda: 'pressure_controller ended (exit code -9) and was started again, disarmed' in
                       cmd.text(), SEEN_S, what='the restart said')
            again = wait_until(lambda: _controller_status(diagnostics, after=armed), SEEN_S,
                               what="the restarted controller's status")
            assert again['enabled'] == 'False', again
            os.kill(_node_pid(mark, 'target_selector'), signal.SIGKILL)
            wait_until(lambda: 'target_selector ended (exit code -9) and stays down' in cmd.text(), SEEN_S,
                       what='the ended node said')
            assert not registers_now().any()
        code = cmd.stop(signal.SIGINT)
    except AssertionError as exc:
        raise AssertionError(f'{exc}\n{cmd.text()}\n{log_tails(logs)}') from None
    finally:
        cmd.close()
    out = cmd.text()
    assert 'Traceback' not in out, out
    assert code == 130, out
    assert cmd.lines[-1] == ('fabric-guidance dry-run: stopped (Ctrl-C): the dry run is stopped (each node vented '
                             'on its way out)'), out
    assert processes_with(MARK, mark) == [], 'processes of the dry run left running'
    # What the mock PLC was written, through to plc_output's vent on its way out: never more than 0.
    records = load_records(logs / 'mock_plc-0.records.json')
    assert records['writes'] > 0 and not any(records['max_written_counts'].values()), records
    assert records['over_limit_count'] == 0


def _run(argv: list[str]) -> int:
    # Free ports unless the case names one: guidance.yaml's may be taken on a busy machine.
    ports = ['--plc-port', str(free_port()), '--gaze-port', str(free_port(socket.SOCK_DGRAM))]
    return dry_run.run(dry_run.configure(argparse.ArgumentParser()).parse_args([*ports, *argv]))


@pytest.fixture
def listening():
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        s.listen()
        yield s.getsockname()[1]


@pytest.mark.parametrize('options, line', [
    (['--plc-port', 'abc'], "--plc-port 'abc': not a port 1-65535"),
    (['--gaze-port', '70000'], "--gaze-port '70000': not a port 1-65535"),
    (['--headset-address', '192.168.1.20'], '--bind-address 127.0.0.1: a headset at 192.168.1.20 cannot reach a '
     "loopback address; give this PC's address on the headset's network"),
    (['--headset-address', 'hololens'], "--headset-address 'hololens': not an IP address"),
    (['--study', 'sped'], "--study sped: 'sped' is not one of speed, accuracy"),
    (['--condition', '5'], "--condition '5': one of 1, 2, 3, 4"),
    (['--calibration-file', SIM_CALIBRATION, '--wearer', 'P07'],
     f"--calibration-file {SIM_CALIBRATION}: its wearer is 'sim-wearer', --wearer is 'P07'"),
    (['--calibration-file', 'no-such.yaml'], '--calibration-file no-such.yaml: no such file'),
])
def test_a_bad_option_value_is_one_line_naming_it_and_nothing_starts(tmp_path, capsys, monkeypatch, options, line):
    from fabric_guidance.graph.process_graph import Graph
    started = []
    monkeypatch.setattr(Graph, 'start', lambda self, node, *a, **k: started.append(node))
    logs = tmp_path / 'logs'
    assert _run(['--headset-address', '127.0.0.2', '--logs', str(logs), *options]) == 2
    assert capsys.readouterr().err.splitlines() == [f'fabric-guidance dry-run: error: {line}']
    assert started == [] and not logs.exists()


def test_a_taken_port_or_a_bad_domain_is_refused_before_anything_starts(tmp_path, capsys, monkeypatch, listening):
    from fabric_guidance.graph.process_graph import Graph
    started = []
    monkeypatch.setattr(Graph, 'start', lambda self, node, *a, **k: started.append(node))
    base = ['--headset-address', '127.0.0.2', '--logs', str(tmp_path / 'logs')]
    assert _run([*base, '--plc-port', str(listening)]) == 2
    assert capsys.readouterr().err.splitlines() == [
        f'fabric-guidance dry-run: error: --plc-port {listening}: the mock PLC cannot listen on '
        f'127.0.0.1:{listening} (Address already in use)']
    monkeypatch.setenv('ROS_DOMAIN_ID', '300')
    assert _run(base) == 2
    assert capsys.readouterr().err.splitlines() == [
        "fabric-guidance dry-run: error: ROS_DOMAIN_ID='300' (the environment): not a domain id 0-232"]
    assert started == [] and not (tmp_path / 'logs').exists()
