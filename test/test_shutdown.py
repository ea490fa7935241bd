"""A node's process ends in bounded time once it has vented, whatever its teardown does, and
however many stop signals arrive.

plc_output once stayed up after logging its vent until `ros2 launch` killed it;
nodes/spin.run() bounds the teardown after safe_shutdown(). Here a node's safe_shutdown()
leaves a non-daemon thread behind that never ends, which would hold the interpreter's exit
forever: the process must still exit 0 after its vent.
"""
import contextlib
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from rosgraph import fresh_domain_id, wait_until

pytestmark = pytest.mark.graph  # starts a process graph with DDS

#: Far above the teardown bound (nodes/spin.py TEARDOWN_LIMIT_S) and a loaded machine's start-up.
EXIT_DEADLINE_S = 30.0

NODE = textwrap.dedent('''
    import threading
    from rclpy.node import Node
    from fabric_guidance.nodes.spin import run

    class Stuck(Node):
        def __init__(self):
            super().__init__('stuck')
            print('ready', flush=True)

        def safe_shutdown(self):
            print('vented', flush=True)
            threading.Thread(target=threading.Event().wait).start()  # never ends, not a daemon

    raise SystemExit(run(Stuck))
''')


def _stopped_with_sigint(script: str, tmp_path) -> tuple[int, str]:
    """Run a node script in its own process; once it says 'ready', SIGINT it and wait for its
    end: (exit status, everything it printed)."""
    import os
    env = dict(os.environ, ROS_DOMAIN_ID=str(fresh_domain_id()))
    out = tmp_path / 'out.txt'
    with open(out, 'w') as f:
        proc = subprocess.Popen([sys.executable, '-c', script], stdout=f, stderr=subprocess.STDOUT, env=env)
    try:
        wait_until(lambda: 'ready' in out.read_text(), EXIT_DEADLINE_S, what='the node up')
        proc.send_signal(signal.SIGINT)
        wait_until(lambda: proc.poll() is not None, EXIT_DEADLINE_S, what='the process ending after its vent')
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, out.read_text()


def test_a_stuck_teardown_does_not_hold_the_process_after_its_vent(tmp_path):
    code, text = _stopped_with_sigint(NODE, tmp_path)
    assert 'vented' in text
    assert code == 0, text


GIL_HELD = textwrap.dedent('''
    import ctypes
    from rclpy.node import Node
    from fabric_guidance.nodes.spin import run

    class HeldTeardown(Node):
        def __init__(self):
            super().__init__('held_teardown')
            print('ready', flush=True)

        def safe_shutdown(self):
            print('vented', flush=True)

        def destroy_node(self):
            # A call into C that keeps the GIL (PyDLL does not release it) and does not return:
            # what a DDS entity's destruction waiting on a thread that waits for the GIL would be.
            ctypes.PyDLL(None).sleep(600)

    raise SystemExit(run(HeldTeardown))
''')


def test_a_teardown_that_holds_the_gil_still_ends_with_its_status_and_says_where(tmp_path):
    """The teardown's timer needs the GIL; faulthandler's watchdog and the C library's exit timer
    do not: every thread's stack in its output, then the process ends with status 0, because it
    vented (CI: wearer_sim's DDS teardown hung in destroy_node, and its status 1 failed a launch
    test that had vented)."""
    code, text = _stopped_with_sigint(GIL_HELD, tmp_path)
    assert 'vented' in text and code == 0, (code, text)
    assert 'Timeout (0:00:03.500000)!' in text and 'in destroy_node' in text, text


ORDER = textwrap.dedent('''
    from rclpy.node import Node
    from fabric_guidance.nodes import spin

    class Told:
        """The node's executor, saying when it is shut down."""
        def __init__(self, executor):
            self.executor = executor

        def add_node(self, node):
            return self.executor.add_node(node)

        def spin_once(self, timeout_sec=None):
            return self.executor.spin_once(timeout_sec=timeout_sec)

        def shutdown(self, timeout_sec=None):
            print('executor shutdown', flush=True)
            return self.executor.shutdown(timeout_sec)

    make = spin.make_executor
    spin.make_executor = lambda kind=spin.DEFAULT_EXECUTOR: Told(make(kind))

    class Ordered(Node):
        def __init__(self):
            super().__init__('ordered')
            print('ready', flush=True)

        def safe_shutdown(self):
            print('vented', flush=True)

        def destroy_node(self):
            print('destroy_node', flush=True)
            super().destroy_node()

    raise SystemExit(spin.run(Ordered))
''')


def test_the_executor_lets_go_of_the_node_before_it_is_destroyed(tmp_path):
    """rclpy's teardown order: the executor shut down, then the node destroyed (fresh run 115: the
    events executor's destructor releasing an entity after the node and the context were gone
    hung with the GIL held)."""
    code, text = _stopped_with_sigint(ORDER, tmp_path)
    assert code == 0, text
    lines = [line for line in text.splitlines() if line in ('vented', 'executor shutdown', 'destroy_node')]
    assert lines == ['vented', 'executor shutdown', 'destroy_node'], text


BUSY_START = textwrap.dedent('''
    import time
    from rclpy.node import Node
    from fabric_guidance.nodes.spin import run

    class SlowStart(Node):
        def __init__(self):
            super().__init__('slow_start')
            print('ready', flush=True)
            end = time.monotonic() + 3.0
            while time.monotonic() < end:   # a start-up in Python bytecode (imports, a configure)
                pass

        def safe_shutdown(self):
            print('vented', flush=True)

    raise SystemExit(run(SlowStart))
''')


def test_a_storm_of_stop_signals_in_the_start_up_still_ends_in_a_vent(tmp_path):
    """SIGINT and SIGTERM back to back, as a parent's death, a launch's escalation and a second
    Ctrl-C deliver them: the handler runs inside itself. A handler that takes a lock (it set a
    threading.Event) deadlocked there and the process hung for good, never venting."""
    import os
    env = dict(os.environ, ROS_DOMAIN_ID=str(fresh_domain_id()))
    out = tmp_path / 'out.txt'
    with open(out, 'w') as f:
        proc = subprocess.Popen([sys.executable, '-c', BUSY_START], stdout=f, stderr=subprocess.STDOUT, env=env)
    try:
        wait_until(lambda: 'ready' in out.read_text(), EXIT_DEADLINE_S, what='the node up')
        sent, end = 0, time.monotonic() + 2.0
        while proc.poll() is None and time.monotonic() < end:
            with contextlib.suppress(ProcessLookupError):
                proc.send_signal(signal.SIGTERM if sent % 2 else signal.SIGINT)
            sent += 1
            time.sleep(0.0002)
        wait_until(lambda: proc.poll() is not None, EXIT_DEADLINE_S,
                   what=f'the process exiting after {sent} stop signals')
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert 'vented' in out.read_text(), out.read_text()
    assert proc.returncode == 0, out.read_text()


def test_the_mock_plc_waits_for_its_client_to_vent_and_leave():
    """mock_plc's shutdown (sim.launch.py: one Ctrl-C reaches every process) waits until its
    clients have vented and disconnected, and gives up at its deadline."""
    import threading

    from fabric_guidance.core import ChannelMap
    from fabric_guidance.plc import MockPlcServer, PlcClient, RegisterMap
    from rosgraph import CONFIG
    channels = ChannelMap.load(CONFIG / 'hardware/channel_map.yaml').channels
    regmap = RegisterMap.load(CONFIG / 'hardware/plc_register_map.yaml', expected_channels=channels)
    with MockPlcServer(regmap, watchdog_s=60.0) as server:  # no watchdog vent meanwhile
        client = PlcClient(regmap, '127.0.0.1', server.port)
        assert client.connect()
        beats = iter(range(1, 1000))

        def cycle():
            # As plc_output's cycle: the command, then a new heartbeat. The PLC zeroes commands at
            # every scan until a changing heartbeat arms its watchdog; a lone write was seen only
            # when a read fell between it and the next scan (once, it never was).
            client.write_pressures([100.0] * len(regmap))
            client.write_heartbeat(next(beats))
            return server.watchdog_armed and server.commands_kpa().any()
        wait_until(cycle, 10.0, what='the command written and kept (the watchdog armed by the heartbeat)')
        assert not server.wait_until_vented(0.3)  # commanding and connected: not vented

        def vent_then_leave():
            client.vent()
            client.close()
        threading.Timer(0.2, vent_then_leave).start()
        assert server.wait_until_vented(10.0)
        assert server.client_count == 0 and not server.commands_kpa().any()
