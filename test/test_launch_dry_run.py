"""guidance.launch.py mock_plc:=true: the lab graph against a mock PLC on this PC and no
wearer_sim, a lab's dry run with the real headset and a person but no suit (docs/launch.md).
Run by `make test`'s launch stage with test_launch.py (whose launch helpers it shares)."""
import os
import socket

import pytest

pytestmark = pytest.mark.graph

launch_pytest = pytest.importorskip('launch_pytest', reason='launch_pytest is not installed here: `make test` runs '
                                    'the launch tests in .venv-launch when ../shared/ros-tooling/ is present')
if not os.environ.get('FABRIC_GUIDANCE_INSTALL'):
    pytest.skip('FABRIC_GUIDANCE_INSTALL is not set: run through `make test-launch`', allow_module_level=True)

from std_msgs.msg import Float64MultiArray  # noqa: E402

from fabric_guidance import interface  # noqa: E402
from fabric_guidance.core import ChannelMap  # noqa: E402
from fabric_guidance.graph.process_graph import Probe, free_port, fresh_domain_id, wait_until  # noqa: E402
from fabric_guidance.nodes import qos  # noqa: E402
from fabric_guidance.plc import PlcClient, RegisterMap  # noqa: E402
from test_launch import LINK_UP, SHARE, Watch, _graph, _include  # noqa: E402


@pytest.fixture
def dry_run_arguments():
    return {'mock_plc': 'true', 'plc_port': free_port(),
            'calibration_file': os.path.join(SHARE, 'config', 'calibrations', 'sim-wearer.yaml'),
            'bind_address': '127.0.0.1', 'gaze_port': free_port(socket.SOCK_DGRAM),
            'allowed_senders': "['127.0.0.2']", 'headset_address': '127.0.0.2',
            'display_port': free_port(socket.SOCK_DGRAM)}


@launch_pytest.fixture
def dry_run(dry_run_arguments):
    watch, domain_id = Watch(), fresh_domain_id()
    return _graph(watch, domain_id, _include('guidance.launch.py', **dry_run_arguments)), watch, domain_id


@pytest.mark.launch(fixture=dry_run)
def test_mock_plc_true_runs_the_lab_graph_against_a_mock_plc_without_a_simulated_wearer(dry_run, dry_run_arguments):
    _, watch, domain_id = dry_run
    wait_until(lambda: LINK_UP.search(watch.log('plc_output')), 60.0, what='plc_output connected to the mock PLC')
    assert watch.name('mock_plc') is not None and watch.name('wearer_sim') is None
    channels = ChannelMap.load(os.path.join(SHARE, 'config', 'hardware', 'channel_map.yaml')).channels
    regmap = RegisterMap.load(os.path.join(SHARE, 'config', 'hardware', 'plc_register_map.yaml'),
                              expected_channels=channels)
    # The mock listens where the launch pointed plc_output (its plc_port), and holds every channel
    # at 0: the lab launch's controller starts disarmed (respawn, the default) until the operator's enable.
    with Probe(domain_id) as probe, PlcClient(regmap, '127.0.0.1', dry_run_arguments['plc_port'],
                                              timeout_s=1.0) as client:
        commands = probe.subscribe(Float64MultiArray, interface.PRESSURE_COMMAND, qos.COMMAND_QOS)
        wait_until(lambda: len(commands) >= 10, 30.0, what='pressure commands')
        assert all(max(m.data) == 0.0 for m in commands)
        assert not client.read_commands_kpa().any()
