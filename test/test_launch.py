"""The launch files under the real launch system, run from a `colcon build` install tree, as a
lab runs them: under ROS 2 Kilted's launch 3.7.1 / launch_ros 0.28.0 and under Jazzy's launch
3.4.3 / launch_ros 0.26.6 (FABRIC_GUIDANCE_LAUNCH_DISTRO names which; rclpy and Fast DDS are the
Kilted wheels' in both: Jazzy's are not on the package index).

`make test` runs this module twice, in .venv-launch and .venv-launch-jazzy (pytest 7.4.4, the
wheels of ../shared/ros-tooling/ and ../shared/ros-tooling/jazzy/, colcon), each after building
the package with colcon into build-launch/ or build-launch-jazzy/; see docs/launch.md (the
workspace check beside it: test_workspace.py). Everywhere else it is skipped with one line.
"""
import glob
import os
import re
import signal
import socket
import sys
import tempfile
import threading

import pytest

pytestmark = pytest.mark.graph  # starts a process graph with DDS

launch_pytest = pytest.importorskip(
    'launch_pytest',
    reason='launch_pytest is not installed here: `make test` runs the launch tests in '
           '.venv-launch when ../shared/ros-tooling/ is present (docs/launch.md)')
INSTALL = os.environ.get('FABRIC_GUIDANCE_INSTALL')
if not INSTALL:
    pytest.skip('FABRIC_GUIDANCE_INSTALL is not set: run through `make test-launch` (a colcon '
                'build first)', allow_module_level=True)

import launch  # noqa: E402
from launch.actions import GroupAction, IncludeLaunchDescription  # noqa: E402
from launch.actions import RegisterEventHandler, SetEnvironmentVariable  # noqa: E402
from launch.event_handlers import OnProcessExit, OnProcessIO, OnProcessStart  # noqa: E402
from launch.launch_description_sources import PythonLaunchDescriptionSource  # noqa: E402
from launch_ros.actions import SetParameter  # noqa: E402
from rcl_interfaces.srv import GetParameters  # noqa: E402
from std_msgs.msg import Float64MultiArray  # noqa: E402

from fabric_guidance.core import ChannelMap  # noqa: E402
from fabric_guidance import interface  # noqa: E402
from fabric_guidance.nodes import qos  # noqa: E402
from fabric_guidance.plc import MockPlcServer, RegisterMap  # noqa: E402
from fabric_guidance.graph.process_graph import (Probe, free_port, fresh_domain_id,  # noqa: E402
                                                 wait_until)

PREFIX = os.path.join(INSTALL, 'fabric_guidance')
SHARE = os.path.join(PREFIX, 'share', 'fabric_guidance')
EXECUTABLES = ('gaze_bridge', 'target_selector', 'pressure_controller', 'plc_output', 'mock_plc',
               'wearer_sim', 'micromanipulator_sim', 'bag_recorder', 'headset_display', 'fabric-guidance')
P_MAX = 375.0
#: Seven processes' start-up plus four guided turns of a few seconds each on a loaded machine.
SESSION_DEADLINE_S = 90.0
VENTED = re.compile(r'vented all \d+ channels (of PLC \S+ )?on shutdown')
LINK_UP = re.compile(r'connected to the PLC|PLC \S+ at \S+ up')
FOUND = re.compile(r"target found: '(\w+)'")


class Watch:
    """Every process of a launch: pid, output and return code, by process name (node-1...)."""

    def __init__(self):
        self.lock = threading.RLock()
        self.pids, self.output, self.returncodes = {}, {}, {}

    def actions(self):
        return [RegisterEventHandler(OnProcessStart(on_start=self._started)),
                RegisterEventHandler(OnProcessIO(on_stdout=self._io, on_stderr=self._io)),
                RegisterEventHandler(OnProcessExit(on_exit=self._exited))]

    def _started(self, event, context):
        with self.lock:
            self.pids[event.process_name] = event.pid

    def _io(self, event):
        with self.lock:
            self.output[event.process_name] = (self.output.get(event.process_name, '')
                                               + event.text.decode(errors='replace'))

    def _exited(self, event, context):
        with self.lock:
            self.returncodes[event.process_name] = event.returncode

    def name(self, node):
        with self.lock:
            return next((n for n in self.pids if n.rsplit('-', 1)[0] == node), None)

    def log(self, node):
        with self.lock:
            return ''.join(text for n, text in self.output.items() if n.rsplit('-', 1)[0] == node)

    def found(self):
        """The targets target_selector logged as found, in order (its log, not DDS: a probe that
        discovers the graph late on a loaded machine would miss the first events)."""
        return FOUND.findall(self.log('target_selector'))

    def exited(self, node):
        with self.lock:
            return self.name(node) in self.returncodes


def _include(name, **arguments):
    return IncludeLaunchDescription(
        PythonLaunchDescriptionSource(os.path.join(SHARE, 'launch', name)),
        launch_arguments={k: str(v) for k, v in arguments.items()}.items())


def _graph(watch, domain_id, *entities):
    return launch.LaunchDescription([
        SetEnvironmentVariable('ROS_DOMAIN_ID', str(domain_id)),
        SetEnvironmentVariable('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST'),
        *watch.actions(), *entities, launch_pytest.actions.ReadyToTest()])


def _fabric_guidance_temp_files():
    return set(glob.glob(os.path.join(tempfile.gettempdir(), 'fabric_guidance_*')))


#: launch and launch_ros releases of each distribution the stage runs under (their wheels).
LAUNCH_VERSIONS = {'kilted': ('3.7.', '0.28.'), 'jazzy': ('3.4.', '0.26.')}


def test_the_stage_runs_under_the_distributions_launch_and_launch_ros():
    """A venv with the other distribution's wheels would pass for this one unseen."""
    from importlib.metadata import version
    distro = os.environ.get('FABRIC_GUIDANCE_LAUNCH_DISTRO', 'kilted')
    launch_version, launch_ros_version = version('launch'), version('launch_ros')
    print(f'\n[{distro}] launch {launch_version}, launch_ros {launch_ros_version}, '
          f'launch_pytest {version("launch_pytest")}')
    assert launch_version.startswith(LAUNCH_VERSIONS[distro][0]), launch_version
    assert launch_ros_version.startswith(LAUNCH_VERSIONS[distro][1]), launch_ros_version
    assert os.path.dirname(launch.__file__).startswith(sys.prefix), launch.__file__


def test_colcon_build_installed_the_package():
    """colcon build's install tree: the ament index marker, share/ and every executable; this
    process imports the package from there."""
    import fabric_guidance
    assert os.path.isfile(os.path.join(PREFIX, 'share', 'ament_index', 'resource_index',
                                       'packages', 'fabric_guidance'))
    assert os.path.isfile(os.path.join(SHARE, 'package.xml'))
    assert sorted(os.listdir(os.path.join(SHARE, 'launch'))) == [
        'guidance.launch.py', 'micromanipulation.launch.py', 'sim.launch.py']
    for name in ('params/guidance.yaml', 'params/sim.yaml', 'params/micromanipulation.yaml',
                 'hardware/channel_map.yaml', 'hardware/plc_register_map.yaml', 'calibrations/sim-wearer.yaml'):
        assert os.path.isfile(os.path.join(SHARE, 'config', name)), name
    for exe in EXECUTABLES:
        assert os.access(os.path.join(PREFIX, 'lib', 'fabric_guidance', exe), os.X_OK), exe
    assert fabric_guidance.__file__.startswith(PREFIX)


# ------------------------------------------------------------------------------- sim.launch.py
@pytest.fixture
def sim_ports():
    return {'plc_port': free_port(), 'gaze_port': free_port(socket.SOCK_DGRAM),
            'display_port': free_port(socket.SOCK_DGRAM)}


#: The simulated graph runs in a namespace, as a second suit on the domain would: its parameter
#: files (keyed /**/<node>) and its launch arguments must still reach every node.
SIM_NAMESPACE = 'suit_a'


@launch_pytest.fixture
def sim_graph(sim_ports):
    watch, domain_id = Watch(), fresh_domain_id()
    return _graph(watch, domain_id, _include('sim.launch.py', namespace=SIM_NAMESPACE, **sim_ports)), \
        watch, domain_id


def _parameters(probe, node, names):
    response = probe.call(GetParameters, interface.full_name('~/get_parameters', SIM_NAMESPACE, node),
                          GetParameters.Request(names=names), attempts=3)
    return [{1: v.bool_value, 2: v.integer_value, 3: v.double_value, 4: v.string_value,
             9: list(v.string_array_value)}.get(v.type) for v in response.values]


@pytest.mark.launch(fixture=sim_graph)
def test_sim_launch_in_a_namespace_keeps_its_configuration_guides_and_vents_on_sigint(sim_graph, sim_ports):
    from fabric_guidance.paths import node_parameters
    _, watch, domain_id = sim_graph
    wait_until(lambda: len(watch.found()) >= 4, SESSION_DEADLINE_S, what='four targets found')
    assert watch.found() == ['front_left', 'up_right', 'down_left', 'down_right']
    with Probe(domain_id, namespace=SIM_NAMESPACE) as probe:
        # The largest pressure the mock PLC was ever written, per channel (published at 10 Hz).
        written = probe.subscribe(Float64MultiArray, interface.MAX_WRITTEN, qos.COMMAND_QOS)
        wait_until(lambda: written, 30.0, what="the mock PLC's largest writes")
        assert max(written[-1].data) <= P_MAX
        assert max(written[-1].data) > 50.0  # guided, not found by luck
        # From the files (sim.yaml over guidance.yaml, keyed /**/<node>) and the arguments (a file
        # keyed by the node's full name): a namespace loses neither.
        sim = os.path.join(SHARE, 'config', 'params', 'sim.yaml')
        assert _parameters(probe, 'target_selector', ['return_to_front']) == \
            [node_parameters(sim, 'target_selector')['return_to_front']]
        assert _parameters(probe, 'wearer_sim', ['tau_s', 'bridge_port']) == \
            [node_parameters(sim, 'wearer_sim')['tau_s'], sim_ports['gaze_port']]
        assert _parameters(probe, 'gaze_bridge', ['port', 'headset_address']) == [sim_ports['gaze_port'], '127.0.0.1']
        assert _parameters(probe, 'mock_plc', ['port']) == [sim_ports['plc_port']]
        # Discovery of a probe that joined late takes its time: wait for the names, then check.

        def services():
            return {name for name, _ in probe.node.get_service_names_and_types()}
        wanted = {interface.full_name(s.name, SIM_NAMESPACE) for s in interface.SERVICES}
        wait_until(lambda: wanted <= services(), 30.0,
                   what=f'every service in {SIM_NAMESPACE}: {sorted(wanted)}')
        assert not services() & set(interface.OLD_NAMES)
    # The distribution's Fast DDS variable (FASTRTPS_ on Jazzy, FASTDDS_ on Kilted) names the
    # loopback profile, and the other name is not there to win over it.
    from fabric_guidance.lab.lab_network import PROFILE_VARIABLES, profile_variable
    env = _environ(watch.pids[watch.name('plc_output')])
    profile = os.path.join(SHARE, 'config', 'fastdds_loopback.xml')
    assert env.get(profile_variable()) == profile
    assert not any(v in env for v in PROFILE_VARIABLES if v != profile_variable())
    # Ctrl-C at its worst: the mock PLC gets SIGINT first and the others only later (a terminal
    # signals the whole group at once; any order must vent). The mock must still be there.
    os.kill(watch.pids[watch.name('mock_plc')], signal.SIGINT)
    try:
        wait_until(lambda: watch.exited('mock_plc'), 1.0)
    except AssertionError:
        pass  # still up, waiting for plc_output's vent: as it should
    for name, pid in list(watch.pids.items()):
        if not name.startswith('mock_plc'):
            os.kill(pid, signal.SIGINT)
    wait_until(lambda: len(watch.returncodes) == len(watch.pids), 20.0,
               what='every process exited')
    plc_output = watch.log('plc_output')
    assert VENTED.search(plc_output), plc_output[-2000:]
    assert 'could not vent' not in plc_output
    assert 'stopping with' not in watch.log('mock_plc')
    assert all(code == 0 for code in watch.returncodes.values()), watch.returncodes


# -------------------------------------------------------------------------- guidance.launch.py
@pytest.fixture
def plc():
    channels = ChannelMap.load(os.path.join(SHARE, 'config', 'hardware/channel_map.yaml')).channels
    regmap = RegisterMap.load(os.path.join(SHARE, 'config', 'hardware/plc_register_map.yaml'),
                              expected_channels=channels)
    with MockPlcServer(regmap, '127.0.0.1', 0) as server:
        yield server


@pytest.fixture
def lab_arguments(plc, tmp_path):
    return {'plc_host': '127.0.0.1', 'plc_port': plc.port,
            'calibration_file': os.path.join(SHARE, 'config', 'calibrations', 'sim-wearer.yaml'),
            'condition': 3, 'bind_address': '127.0.0.1', 'gaze_port': free_port(socket.SOCK_DGRAM),
            'allowed_senders': "['127.0.0.2', '127.0.0.3']", 'use_sim_time': 'false',
            'headset_address': '127.0.0.2', 'display_port': free_port(socket.SOCK_DGRAM)}


@launch_pytest.fixture
def lab_graph(lab_arguments):
    watch, domain_id = Watch(), fresh_domain_id()
    # A global parameter, as a lab's bringup sets: with the arguments as a `/**` file (the old
    # launch file) rcl applied guidance.yaml's node sections after it and ignored them all.
    lab = GroupAction([SetParameter(name='use_sim_time', value=False),
                       _include('guidance.launch.py', **lab_arguments)])
    return _graph(watch, domain_id, lab), watch, domain_id


@pytest.mark.launch(fixture=lab_graph)
def test_lab_launch_comes_up_vented_and_honours_every_argument(lab_graph, lab_arguments, plc):
    _, watch, domain_id = lab_graph
    expected = {
        'plc_output': {'plc_host': '127.0.0.1', 'plc_port': lab_arguments['plc_port']},
        'pressure_controller': {'calibration_file': lab_arguments['calibration_file'],
                                'condition': 3},
        'gaze_bridge': {'bind_address': '127.0.0.1', 'port': lab_arguments['gaze_port'],
                        'allowed_senders': ['127.0.0.2', '127.0.0.3'], 'headset_address': '127.0.0.2',
                        'display_port': lab_arguments['display_port']},
        'headset_display': {'headset_address': '127.0.0.2', 'display_port': lab_arguments['display_port']},
        'target_selector': {'use_sim_time': False},
    }
    with Probe(domain_id) as probe:
        commands = probe.subscribe(Float64MultiArray, interface.PRESSURE_COMMAND, qos.COMMAND_QOS)
        for node, parameters in expected.items():
            names = list(parameters)
            response = probe.call(GetParameters, f'/{node}/get_parameters',
                                  GetParameters.Request(names=names), attempts=3)
            got = {}
            for name, value in zip(names, response.values):
                got[name] = {1: value.bool_value, 2: value.integer_value, 4: value.string_value,
                             9: list(value.string_array_value)}[value.type]
            assert got == parameters, node
        # Up and vented: plc_output on the given port, writing zeros; no command above 0.
        wait_until(lambda: plc.client_count >= 1, 20.0, what='plc_output connected to plc_port')
        wait_until(lambda: len(commands) >= 10, 20.0, what='pressure commands')
        # autostart (the default): the launch's lifecycle events configured and activated both.
        for node in MANAGED:
            wait_until(lambda: _state(probe, node) == 'active', 20.0, what=f'{node} active')
        assert all(max(m.data) == 0.0 for m in commands)
        assert not plc.commands_kpa().any()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s, pytest.raises(OSError):
        s.bind(('127.0.0.1', lab_arguments['gaze_port']))  # the bridge listens there


# ------------------------------------------------------------- the lifecycle nodes, by hand
MANAGED = ('pressure_controller', 'plc_output')


# ---------------------------------------------------------------------------- respawn:=true
#: SIGKILL -> the new process active: respawn_delay, a cold start on a loaded machine, discovery.
RESPAWN_DEADLINE_S = 45.0


@launch_pytest.fixture
def respawning_lab(lab_arguments):
    watch, domain_id = Watch(), fresh_domain_id()
    return _graph(watch, domain_id, _include('guidance.launch.py', respawn_delay='0.5', **lab_arguments)), \
        watch, domain_id


def _guidance_status(diagnostics, since: int):
    """The controller's latest guidance status among diagnostics[since:], as (message, values)."""
    for msg in reversed(diagnostics[since:]):
        for st in msg.status:
            if st.name == 'pressure_controller: guidance':
                return st.message, {kv.key: kv.value for kv in st.values}
    return None


def _active_status(diagnostics, since: int):
    status = _guidance_status(diagnostics, since)
    return status if status and status[1].get('lifecycle state') == 'active' else None


@pytest.mark.launch(fixture=respawning_lab)
def test_lab_launch_respawns_a_killed_controller_vented_and_disabled_until_enable(respawning_lab, plc):
    from diagnostic_msgs.msg import DiagnosticArray
    from std_srvs.srv import SetBool
    _, watch, domain_id = respawning_lab
    with Probe(domain_id) as probe:
        diagnostics = probe.subscribe(DiagnosticArray, interface.DIAGNOSTICS, 10)
        wait_until(lambda: _state(probe, 'pressure_controller') == 'active', 30.0, what='the controller active')
        name = watch.name('pressure_controller')
        first = watch.pids[name]
        os.kill(first, signal.SIGKILL)
        wait_until(lambda: watch.returncodes.get(name) == -signal.SIGKILL, 10.0, what='the controller killed')
        wait_until(lambda: watch.pids[name] != first, RESPAWN_DEADLINE_S, what='the controller respawned')
        since = len(diagnostics)
        # Activated again by the launch's lifecycle events, and disabled: vented until enable.
        wait_until(lambda: _state(probe, 'pressure_controller') == 'active', RESPAWN_DEADLINE_S,
                   what='the respawned controller active')
        status = wait_until(lambda: _active_status(diagnostics, since), 10.0, what='its diagnostics, active')
        assert status[1]['enabled'] == 'False' and status[0].startswith("vented: the operator's arm is off"), status
        assert probe.call(SetBool, interface.ENABLE, SetBool.Request(data=True)).success
        since = len(diagnostics)
        wait_until(lambda: (_guidance_status(diagnostics, since) or ('', {}))[1].get('enabled') == 'True', 10.0,
                   what='enabled by the operator')
    assert not any(plc.max_written_kpa().values())


def _state(probe, node):
    from lifecycle_msgs.srv import GetState
    return probe.call(GetState, f'/{node}/get_state', GetState.Request(), attempts=3).current_state.label


def _transition(probe, node, transition_id):
    """Ask for a transition as `ros2 lifecycle set` does; the seconds to the answer."""
    import time
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState
    t0 = time.monotonic()
    response = probe.call(ChangeState, f'/{node}/change_state',
                          ChangeState.Request(transition=Transition(id=transition_id)))
    assert response.success, f'{node}: transition {transition_id} refused'
    return time.monotonic() - t0


@launch_pytest.fixture
def operator_graph(lab_arguments):
    watch, domain_id = Watch(), fresh_domain_id()
    return _graph(watch, domain_id, _include('guidance.launch.py', autostart='false', **lab_arguments)), \
        watch, domain_id


@pytest.mark.launch(fixture=operator_graph)
def test_lab_launch_with_autostart_false_leaves_the_lifecycle_nodes_to_the_operator(operator_graph, plc):
    import time
    import numpy as np
    from lifecycle_msgs.msg import Transition
    _, watch, domain_id = operator_graph
    n = len(plc.commands_kpa())
    command = [10.0 + 20.0 * i for i in range(n)]
    with Probe(domain_id) as probe:
        commands = probe.subscribe(Float64MultiArray, interface.PRESSURE_COMMAND, qos.COMMAND_QOS)
        for node in MANAGED:
            assert _state(probe, node) == 'unconfigured', node
        time.sleep(1.0)     # watched for a second: nothing commands, nothing connects
        assert not commands and plc.client_count == 0
        times = {}
        for node in MANAGED:
            times[f'{node} configure'] = _transition(probe, node, Transition.TRANSITION_CONFIGURE)
        wait_until(lambda: plc.client_count >= 1, 20.0, what='plc_output connected once configured')
        for node in MANAGED:
            times[f'{node} activate'] = _transition(probe, node, Transition.TRANSITION_ACTIVATE)
        wait_until(lambda: len(commands) >= 10, 20.0, what='pressure commands once active')
        assert all(max(m.data) == 0.0 for m in commands)   # no gaze: vented
        # The operator's own command through the active plc_output, then deactivate: the vent.
        times['pressure_controller deactivate'] = _transition(probe, 'pressure_controller',
                                                              Transition.TRANSITION_DEACTIVATE)
        # plc_output writes only the commands of the node named pressure_controller, labelled with
        # its channel order: the operator's test command comes from a node of that name.
        from fabric_guidance.nodes.array_layout import named_layout
        from fabric_guidance.paths import config_path
        layout = named_layout(ChannelMap.load(config_path('hardware/channel_map.yaml')).channels)
        operator = Probe(domain_id, 'pressure_controller')
        pub = operator.node.create_publisher(Float64MultiArray, interface.PRESSURE_COMMAND, qos.COMMAND_QOS)
        timer = operator.node.create_timer(0.05, lambda: pub.publish(Float64MultiArray(layout=layout,
                                                                                       data=command)))
        wait_until(lambda: np.allclose(plc.commands_kpa(), command, atol=0.1), 20.0,
                   what='the operator command in the PLC registers')
        t0 = time.monotonic()
        times['plc_output deactivate'] = _transition(probe, 'plc_output', Transition.TRANSITION_DEACTIVATE)
        wait_until(lambda: not plc.commands_kpa().any(), 2.0, interval=0.005,
                   what='registers vented on deactivate')
        times['plc_output deactivate -> registers vented'] = time.monotonic() - t0
        time.sleep(0.5)
        assert not plc.commands_kpa().any(), 'inactive: the commands still published are not written'
        assert _state(probe, 'plc_output') == 'inactive' and plc.client_count >= 1   # the link held
        timer.cancel()
        operator.close()
        for node in MANAGED:
            times[f'{node} shutdown'] = _transition(probe, node, Transition.TRANSITION_INACTIVE_SHUTDOWN)
            assert _state(probe, node) == 'finalized'
        print('\n[lifecycle under launch] ' + ', '.join(f'{k} {1e3 * v:.0f} ms' for k, v in times.items()))


# ------------------------------------------------------------------ micromanipulation.launch.py
OBJECTS = ('holding_pipette', 'microbead', 'injection_pipette')


@launch_pytest.fixture
def micromanipulation_graph(sim_ports):
    watch, domain_id = Watch(), fresh_domain_id()
    topics = {f'{name}_topic': f'/stack/{name}/pose' for name in OBJECTS}
    graph = _include('micromanipulation.launch.py', micromanipulator_sim='true', wearer_sim='true',
                     **sim_ports, **topics)
    # Before the launch starts (this function only describes it): what is in /tmp already.
    before = _fabric_guidance_temp_files()
    return _graph(watch, domain_id, graph), watch, domain_id, before


@pytest.mark.launch(fixture=micromanipulation_graph)
def test_micromanipulation_launch_follows_the_stack_and_finds_every_object(
        micromanipulation_graph):
    import numpy as np
    from geometry_msgs.msg import PointStamped, PoseStamped
    _, watch, domain_id, before = micromanipulation_graph
    from fabric_guidance.paths import node_parameters
    path = os.path.join(SHARE, 'config', 'params/micromanipulation.yaml')
    selector, stack = node_parameters(path, 'target_selector'), node_parameters(path, 'micromanipulator_sim')
    micro = {n: np.array(stack['object_positions'][3 * i:3 * i + 3])
             for i, n in enumerate(stack['object_names'])}
    scale, offset, drift = selector['live_scale'], np.array(selector['live_offset']), \
        stack['drift_amplitude_m']
    with Probe(domain_id) as probe:
        poses = {n: probe.subscribe(PoseStamped, f'/stack/{n}/pose', qos.SENSOR_QOS)
                 for n in OBJECTS}
        targets = probe.subscribe(PointStamped, interface.TARGET, qos.LATCHED_QOS)
        wait_until(lambda: len(watch.found()) >= 3, SESSION_DEADLINE_S, what='three objects found')
        assert watch.found() == list(OBJECTS)
        for name in OBJECTS:  # the selector listens on the stack's topics, not its defaults
            topic = f'/stack/{name}/pose'
            wait_until(lambda: probe.node.count_subscribers(topic) >= 1
                       and probe.node.count_publishers(topic) >= 1 and poses[name], 30.0,
                       what=topic)
            assert probe.node.count_subscribers(f'/live_targets/{name}') == 0
        wait_until(lambda: targets, 30.0, what='a target from target_selector')
        # The stack speaks in the microscope frame at micro scale, drifting by at most its
        # amplitude; every target the selector published is one of them mapped x1000 + offset.
        for name in OBJECTS:
            assert {m.header.frame_id for m in poses[name]} == {'microscope'}
            xyz = np.array([[m.pose.position.x, m.pose.position.y, m.pose.position.z]
                            for m in poses[name]])
            assert np.max(np.linalg.norm(xyz - micro[name], axis=1)) <= drift * 1.0001
        for m in targets:
            assert m.header.frame_id == interface.IMMERSIVE_FRAME
            p = np.array([m.point.x, m.point.y, m.point.z])
            assert min(np.linalg.norm(p - (q * scale + offset)) for q in micro.values()) \
                <= drift * scale * 1.0001 + 1e-9
    # plc_output started after the mock PLC listened: its first connection went through.
    plc_output = watch.log('plc_output')
    assert LINK_UP.search(plc_output), plc_output
    assert '[ERROR]' not in plc_output, plc_output
    yield
    # After shutdown: the per-launch files are gone.
    assert _fabric_guidance_temp_files() <= before


# ---------------------------------------------------------------- keystore:= and discovery_server:=
LAB_NODES = ('gaze_bridge', 'target_selector', 'pressure_controller', 'plc_output', 'headset_display')


def _environ(pid):
    with open(f'/proc/{pid}/environ', 'rb') as f:
        return dict(item.split('=', 1) for item in f.read().decode(errors='replace').split('\0') if '=' in item)


@pytest.fixture
def keystore(tmp_path):
    """A keystore with the lab nodes' enclave folders, empty: rcl finds each node's enclave, the
    middleware then has no certificates (or, as the pip wheels, no security at all)."""
    for node in LAB_NODES:
        os.makedirs(os.path.join(tmp_path, 'keystore', 'enclaves', 'fabric_guidance', node))
    return os.path.join(tmp_path, 'keystore')


@launch_pytest.fixture
def secured_lab(lab_arguments, keystore):
    watch, domain_id = Watch(), fresh_domain_id()
    return _graph(watch, domain_id, _include('guidance.launch.py', keystore=keystore, **lab_arguments)), watch


@pytest.mark.launch(fixture=secured_lab)
def test_with_a_keystore_each_node_starts_in_its_enclave_or_not_at_all(secured_lab, keystore, plc):
    _, watch = secured_lab
    wait_until(lambda: all(watch.exited(n) for n in LAB_NODES), 60.0, what='every node refusing to run open')
    for node in LAB_NODES:
        log = watch.log(node)
        assert f'Found security directory: {keystore}/enclaves/fabric_guidance/{node}' in log, log
        assert 'cannot start' in log and watch.returncodes[watch.name(node)] != 0, log
    assert plc.client_count == 0 and not plc.commands_kpa().any()


@launch_pytest.fixture
def lab_with_discovery_server(lab_arguments):
    watch, domain_id = Watch(), fresh_domain_id()
    server = f'127.0.0.1:{free_port(socket.SOCK_DGRAM)}'
    lab = _include('guidance.launch.py', discovery_server=server, start_discovery_server='true', **lab_arguments)
    return _graph(watch, domain_id, lab), watch, server


@pytest.mark.launch(fixture=lab_with_discovery_server)
def test_discovery_server_started_by_the_launch_and_every_node_its_client(lab_with_discovery_server, plc):
    _, watch, server = lab_with_discovery_server
    wait_until(lambda: f'UDPv4:[127.0.0.1]:{server.rsplit(":", 1)[1]}' in watch.log('discovery_server'), 30.0,
               what=f'the discovery server on {server}')
    wait_until(lambda: all(watch.name(n) for n in LAB_NODES), 30.0, what='every node started')
    for node in LAB_NODES:
        env = _environ(watch.pids[watch.name(node)])
        assert env.get('ROS_DISCOVERY_SERVER') == server, node
        assert 'ROS_SECURITY_ENABLE' not in env and 'ROS_SECURITY_ENCLAVE_OVERRIDE' not in env, node
    wait_until(lambda: plc.client_count >= 1, 30.0, what='plc_output connected')


# ------------------------------------------------------------------- sim.launch.py study:=accuracy
#: Seven processes' start-up, then one accuracy trial (a 3 s rest, at most the scene's 15 s timeout).
STUDY_DEADLINE_S = 60.0


@launch_pytest.fixture
def study_graph(sim_ports):
    watch, domain_id = Watch(), fresh_domain_id()
    return _graph(watch, domain_id, _include('sim.launch.py', study='accuracy', **sim_ports)), watch, domain_id


def _short_accuracy_study(out, domain_id):
    """One participant, condition 1, one accuracy trial, run on the launched graph as
    session_graph runs it on its own: the Session driven through an Operator, a bag per block."""
    import yaml
    from fabric_guidance.live_study.block_bag import BlockBags
    from fabric_guidance.live_study.driver import SessionDriver
    from fabric_guidance.live_study.operator import Operator
    from fabric_guidance.live_study.simulated import design_of
    from fabric_guidance.sim.scene import load_scene, scene_path
    from fabric_guidance.study.plan import participant_blocks
    from fabric_guidance.study.session import Session
    from fabric_guidance.study.store import Study
    data = yaml.safe_load(scene_path('paper-accuracy').read_text())
    data.update(conditions=[1], repetitions=1)
    (out.parent / 'short.yaml').write_text(yaml.safe_dump(data, sort_keys=False))
    design = design_of(load_scene(out.parent / 'short.yaml'))
    study = Study.open(out)
    study.add_participant('01')
    store = study.session('01', 1, design)
    session = Session(design, participant_blocks(design, '01', 0), {'gaze_source': 'wearer_sim'})
    op = Operator(domain_id)
    bags = BlockBags(op, store)
    try:
        wait_until(lambda: op.has_gaze() and op.controller_condition, STUDY_DEADLINE_S,
                   what='gaze and the controller on the launched graph')
        op.trial_gate(False)
        # The test is the operator: it arms the controller once (the session never does), once the
        # launch has activated it (a node still unconfigured refuses enable: a person waits too).
        from fabric_guidance.live_study.operator import OperatorError

        def armed():
            try:
                op.enable(True)
                return True
            except OperatorError as exc:
                if 'activate it first' not in str(exc):
                    raise
                return False
        wait_until(armed, STUDY_DEADLINE_S, interval=0.2, what='the launched controller active and armed')

        def set_condition(cond):
            op.set_condition(cond, extra_nodes=('wearer_sim',))
            bags.begin(session.block)
        SessionDriver(op, session, bags, set_condition=set_condition,
                      before_trial=lambda cond, rep: op.set_parameters('wearer_sim', condition=cond,
                                                                       repetition=rep)).run()
    finally:
        bags.close()
        op.close()
    return store


@pytest.mark.launch(fixture=study_graph)
def test_a_short_accuracy_study_on_the_launched_sim_graph_writes_its_trials_and_bag(study_graph, tmp_path):
    from rosbags.highlevel import AnyReader
    from fabric_guidance.study.store import read_tsv
    _, watch, domain_id = study_graph
    store = _short_accuracy_study(tmp_path / 'study', domain_id)
    header, rows = read_tsv(store.trials_path)
    assert len(rows) == 1, rows
    row = rows[0]
    # wearer_sim (study-accuracy.yaml: press_confirm) pressed; the error at the press was recorded
    assert row['status'] == 'ok' and row['press_source'] == 'wearer_sim' and row['condition'] == '1', row
    assert 0.0 <= float(row['h_error_deg']) < 60.0 and 0.0 <= float(row['v_error_deg']) < 60.0
    bags = sorted(store.folder.glob('*_bag'))
    assert [b.name for b in bags] == ['sub-01_ses-1_task-accuracy_run-1_bag']
    with AnyReader(bags) as reader:
        topics = {c.topic: c for c in reader.connections}
        presses = [reader.deserialize(raw, c.msgtype).frame_id
                   for c, _, raw in reader.messages(connections=[topics['/confirm']])]
    assert presses and set(presses) == {'wearer_sim'}
    # study-accuracy.yaml reached headset_display: the target unseen from its start (a respawn too)
    with Probe(domain_id) as probe:
        response = probe.call(GetParameters, '/headset_display/get_parameters',
                              GetParameters.Request(names=['draw_targets', 'dummies']), attempts=3)
    assert [response.values[0].bool_value, response.values[1].integer_value] == [False, 0]
