"""The graph without `launch`: the package's nodes as separate processes with its parameter
files, the way launch/sim.launch.py starts them, plus a probe node to watch them.

Used by `fabric-guidance demo` and by the tests (launch and launch_ros do not install from the
package index). Every graph gets its own ROS_DOMAIN_ID and discovery stays on localhost, so
concurrent runs and other machines are never heard.

Every mock_plc a graph starts keeps its write records in a file in the log folder, and
`stop_all()` fails (PlcInvariantError) if any of them shows a write above p_max or outside
the register map (plc/records.py): every test that runs a graph is held to that.

`sim_lab()` and `start_nodes()` wire up the simulated lab graph (mock_plc, the five lab nodes,
wearer_sim as the HoloLens) on free ports, as `fabric-guidance demo` and `soak` run it.

`supervise()` opts nodes into the launch files' restart policy: a supervised process that dies
(not stopped through `stop`/`stop_all`) is started again with the same parameters after a
back-off that doubles while it keeps dying young. Every node ends with the process that
started the graph, even one killed with SIGKILL (nodes/parent.py). Every process of a graph carries its token in
the environment, so `leftovers()` finds any that outlived `stop_all()`, its children included.
"""
from __future__ import annotations

import itertools
import os
from pathlib import Path
import random
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

from .. import interface
from ..lab.lab_network import PROFILE_VARIABLES, profile_env, profile_variable
from .suit_plc import require_own_plc
from ..nodes.parent import PARENT_ENV
from ..paths import share_dir

ROOT = share_dir()
CONFIG = ROOT / 'config'
#: The Fast DDS profile that keeps the simulated graph's DDS on 127.0.0.1 (docs/safety.md).
LOOPBACK_DDS_PROFILE = CONFIG / 'fastdds_loopback.xml'


def loopback_dds_env() -> dict[str, str]:
    """Environment that confines a process's DDS to loopback: the profile decides alone
    (SYSTEM_DEFAULT: rmw's LOCALHOST mode would add a send socket on every interface)."""
    if not LOOPBACK_DDS_PROFILE.is_file():  # without it SYSTEM_DEFAULT would reach the network
        raise FileNotFoundError(f'{LOOPBACK_DDS_PROFILE} is missing: DDS would not stay on loopback')
    return {**profile_env(LOOPBACK_DDS_PROFILE), 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SYSTEM_DEFAULT'}


_counter = itertools.count()


def fresh_domain_id() -> int:
    """A domain id (1..100) distinct for every graph of this process and unlikely to be shared
    with another test process: the pid spreads processes, the counter graphs within one. Under
    pytest-xdist each of the N workers (and what it starts) draws from its own ids, those equal
    to its index modulo N: the workers' graphs run side by side and never share a domain."""
    worker, workers = _xdist_worker()
    spread = (os.getpid() * 13 + next(_counter)) % (100 // workers)
    return 1 + spread * workers + worker


def _xdist_worker() -> tuple[int, int]:
    """(index, count) of this pytest-xdist worker, from the variables xdist sets in each worker
    (inherited by the processes a test starts); (0, 1) outside xdist."""
    name, count = os.environ.get('PYTEST_XDIST_WORKER', ''), os.environ.get('PYTEST_XDIST_WORKER_COUNT', '')
    if name.startswith('gw') and name[2:].isdigit() and count.isdigit() and 0 <= int(name[2:]) < int(count) <= 50:
        return int(name[2:]), int(count)
    return 0, 1


def _above_ephemeral() -> tuple[int, int] | None:
    """The ports above the kernel's ephemeral range (Linux: 61000-65535), or None where there is
    no such range to read or no room above it."""
    try:
        _, high = map(int, Path('/proc/sys/net/ipv4/ip_local_port_range').read_text().split())
    except (OSError, ValueError):
        return None
    return (high + 1, 65535) if high < 65000 else None


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    """A port free on 127.0.0.1 now, for a node to bind later. Taken above the kernel's ephemeral
    range where there is one: a port the kernel numbers (a client's connect, a bind to port 0)
    was once given the port a graph had chosen before its node bound it ("Address already in
    use": wearer_sim's display port in a full test run), which cannot happen there. Within that
    range each pytest-xdist worker has its own ports (those equal to its index modulo the count,
    as fresh_domain_id's ids) and a process hands them out in turn from a random start: two
    calls before either port is bound (a test's listen port, then its bridge's) once drew the
    same port at random."""
    candidates = _port_candidates()
    for _ in range(64 if candidates is not None else 0):
        port = next(candidates)
        with socket.socket(socket.AF_INET, kind) as s:
            try:
                s.bind(('127.0.0.1', port))
            except OSError:
                continue        # in use: the next
            return port
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


_PORT_CYCLES: dict = {}


def _port_candidates():
    """This process's turn through its worker's ports above the ephemeral range (None: no range)."""
    span = _above_ephemeral()
    if span is None:
        return None
    worker, workers = _xdist_worker()
    key = (span, worker, workers)
    if key not in _PORT_CYCLES:
        ports = [p for p in range(span[0], span[1] + 1) if p % workers == worker]
        start = random.SystemRandom().randrange(len(ports))    # another process, another start
        _PORT_CYCLES[key] = itertools.cycle(ports[start:] + ports[:start])
    return _PORT_CYCLES[key]


def wait_until(predicate: Callable[[], Any], timeout: float, interval: float = 0.02, what: str = 'condition') -> Any:
    """Poll until predicate() is truthy; return its value, or fail with `what` at the deadline."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f'timed out after {timeout:.1f} s waiting for {what}')
        time.sleep(interval)


class PlcInvariantError(AssertionError):
    """A mock PLC of the graph received a write above p_max or outside the register map."""


#: The environment variable that marks every process of one graph (Graph.leftovers).
GRAPH_TOKEN = 'FABRIC_GUIDANCE_GRAPH'


@dataclass
class Restart:
    """One restart by the supervisor: when the death was seen, when the new process started."""
    node: str
    returncode: int
    died: float      # time.monotonic() the supervisor saw the exit
    started: float   # time.monotonic() the new process was started
    pid: int


@dataclass
class _Policy:
    delay_s: float
    max_delay_s: float
    stable_s: float
    fresh: Callable[[int], dict] | None
    next_delay_s: float = 0.0
    due: float | None = None      # time.monotonic() of the pending restart
    died: float = 0.0
    returncode: int = 0


def processes_with(variable: str, value: str) -> list[str]:
    """Live processes (not this one) whose environment has variable=value, one line each: pid and
    command. Children inherit the environment, so a value set for one run finds all it started."""
    found = []
    for entry in Path('/proc').iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            environ = (entry / 'environ').read_bytes()
            if f'{variable}={value}'.encode() not in environ.split(b'\0'):
                continue
            state = (entry / 'stat').read_text().rsplit(')', 1)[1].split()[0]
            cmdline = (entry / 'cmdline').read_bytes().replace(b'\0', b' ').decode(errors='replace')
        except OSError:   # gone meanwhile, or not ours to read
            continue
        if state != 'Z':  # a zombie has ended; only its parent's wait is missing
            found.append(f'pid {entry.name}: {cmdline.strip()[:120]}')
    return found


class Graph:
    """Nodes of the package as separate processes, the way a launch file starts them."""

    def __init__(self, log_dir: Path, domain_id: int | None = None, namespace: str = ''):
        self.domain_id = fresh_domain_id() if domain_id is None else domain_id
        #: Every node of the graph runs in it ('' : the root), as a launch's `namespace:=` does.
        self.namespace = '/'.join(part for part in namespace.split('/') if part)
        self.log_dir = Path(log_dir)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.processes: dict[str, subprocess.Popen] = {}
        self.records_files: list[Path] = []   # one per mock_plc started, restarts included
        self.token = f'{os.getpid()}-{self.domain_id}-{next(_counter)}-{time.monotonic_ns()}'
        # PYTHONFAULTHANDLER: a node that dies of a signal in native code writes its stacks to its log.
        self.env = dict(os.environ, ROS_DOMAIN_ID=str(self.domain_id), PYTHONUNBUFFERED='1', PYTHONFAULTHANDLER='1',
                        RCUTILS_COLORIZED_OUTPUT='0', **{GRAPH_TOKEN: self.token}, **loopback_dds_env())
        # The limits its controller holds across restarts (nodes/held_limits.py) are this graph's
        # own: every restart within it finds them, no other graph does.
        self.env['FABRIC_GUIDANCE_STATE_DIR'] = str(self.log_dir / 'held_limits')
        for name in PROFILE_VARIABLES:   # an inherited other name would win over the loopback profile
            if name != profile_variable():
                self.env.pop(name, None)
        self.specs: dict[str, tuple[str, tuple, dict]] = {}   # key -> node, files, overrides
        self.started_at: dict[str, float] = {}
        self.pids: list[tuple[str, int]] = []   # every process ever started, restarts included
        self.restarts: list[Restart] = []
        self._policies: dict[str, _Policy] = {}
        self._stopping: set[str] = set()   # stopped on purpose: not restarted
        self._lock = threading.RLock()
        self._closing = threading.Event()
        self._supervisor: threading.Thread | None = None
        self._restarting = False

    def command_prefix(self, node: str) -> list[str]:
        """Words put before a node's command (e.g. `ip netns exec NAME`); none here."""
        return []

    def start(self, node: str, params_files=('params/guidance.yaml',), as_name: str | None = None,
              **overrides) -> subprocess.Popen:
        """Start fabric_guidance.nodes.<node> with the package's parameter files (in order) and
        `-p name:=value` overrides. ``as_name``: the key of the process and its log (default: the
        node), so that a graph can run two of a node (two mock PLCs)."""
        proc_key = as_name or node
        if node == 'plc_output':   # as the launch files: a namespaced suit names its own PLC
            require_own_plc(self.namespace, {k: overrides.get(k) for k in ('plc_host', 'plc_port')},
                            'Graph.start(plc_output) in')
        with self._lock:
            self.specs[proc_key] = (node, tuple(params_files), dict(overrides))
            self._stopping.discard(proc_key)
        if node == 'mock_plc' and 'records_file' not in overrides:
            overrides['records_file'] = str(self.log_dir / f'mock_plc-{len(self.records_files)}.records.json')
            self.records_files.append(Path(overrides['records_file']))
        cmd = self.command_prefix(node) + [sys.executable, '-m', f'fabric_guidance.nodes.{node}', '--ros-args']
        if self.namespace:
            cmd += ['-r', f'__ns:=/{self.namespace}']
        for f in params_files:
            cmd += ['--params-file', str(CONFIG / f)]
        for key, value in overrides.items():
            cmd += ['-p', f'{key}:={_param_text(value)}']
        # A supervised restart appends: its log follows its predecessor's.
        log = open(self.log_dir / f'{proc_key}.log', 'a' if self._restarting else 'w')
        # The node ends with this process, however it ends (nodes/parent.py).
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=ROOT,
                                env={**self.env, PARENT_ENV: str(os.getpid())})
        log.close()   # the child has its own descriptor
        with self._lock:
            self.processes[proc_key] = proc
            self.started_at[proc_key] = time.monotonic()
            self.pids.append((proc_key, proc.pid))
        return proc

    # ---- restarts
    def supervise(self, *keys: str, delay_s: float = 0.5, max_delay_s: float = 8.0, stable_s: float = 10.0,
                  fresh: dict[str, Callable[[int], dict]] | None = None) -> None:
        """Restart each of `keys` (started already) whenever its process dies, delay_s after the
        death; the delay doubles up to max_delay_s while the node dies within stable_s of its
        start, and is back to delay_s once it ran longer. ``fresh[key](n)``: parameters that
        replace the recorded ones at the n-th restart (a bag recorder's new folder)."""
        with self._lock:
            for key in keys:
                if key not in self.specs:
                    raise KeyError(f'supervise: {key} was never started in this graph')
                self._policies[key] = _Policy(delay_s, max_delay_s, stable_s, (fresh or {}).get(key),
                                              next_delay_s=delay_s)
            if self._supervisor is None:
                self._supervisor = threading.Thread(target=self._supervise_loop, name='graph-supervisor',
                                                    daemon=True)
                self._supervisor.start()

    def restart_count(self, key: str) -> int:
        with self._lock:
            return sum(1 for r in self.restarts if r.node == key)

    def _supervise_loop(self) -> None:
        while not self._closing.wait(0.02):
            now = time.monotonic()
            with self._lock:
                for key, policy in self._policies.items():
                    proc = self.processes[key]
                    if key in self._stopping or proc.poll() is None:
                        continue
                    if policy.due is None:   # a death just seen: schedule the restart
                        lived = now - self.started_at[key]
                        policy.next_delay_s = (min(2 * policy.next_delay_s, policy.max_delay_s)
                                               if lived < policy.stable_s else policy.delay_s)
                        policy.due, policy.died, policy.returncode = now + policy.next_delay_s, now, proc.returncode
                    elif now >= policy.due:
                        node, files, overrides = self.specs[key]
                        n = self.restart_count(key) + 1
                        if policy.fresh is not None:
                            overrides = {**overrides, **policy.fresh(n)}
                        self._restarting = True
                        try:
                            new = self.start(node, files, as_name=key, **overrides)
                        finally:
                            self._restarting = False
                        self.restarts.append(Restart(key, policy.returncode, policy.died, time.monotonic(), new.pid))
                        policy.due = None

    def log(self, node: str) -> str:
        return (self.log_dir / f'{node}.log').read_text()

    def ended(self) -> dict[str, int]:
        """The nodes whose process has ended without being stopped, with their exit codes."""
        with self._lock:
            return {key: proc.returncode for key, proc in self.processes.items()
                    if key not in self._stopping and proc.poll() is not None}

    def stop(self, node: str, sig: int = signal.SIGINT, timeout: float = 10.0) -> int:
        with self._lock:
            self._stopping.add(node)   # not restarted by the supervisor
            proc = self.processes[node]
        if proc.poll() is None:
            proc.send_signal(sig)
            try:
                proc.wait(timeout)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
                raise AssertionError(f'{node} did not exit within {timeout} s of signal {sig}')
        return proc.returncode

    def stop_all(self, check: bool = True) -> None:
        """SIGINT every node, wait for them, then (with `check`) hold the mock PLCs' records to
        the invariants."""
        self._closing.set()
        if self._supervisor is not None:
            self._supervisor.join(5)
        for name, proc in list(self.processes.items()):
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for proc in self.processes.values():
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        if check:
            found = self.plc_violations()
            if found:
                raise PlcInvariantError('\n'.join(found))

    def leftovers(self) -> list[str]:
        """Processes still alive that this graph started (restarts and their children included:
        they inherit the graph's token), one line each: pid and command."""
        return processes_with(GRAPH_TOKEN, self.token)

    def plc_violations(self) -> list[str]:
        """Broken invariants in the records of every mock_plc started so far (a mock that never
        listened, e.g. refused at start-up, has no records)."""
        from ..plc.records import load_records, violations
        found = []
        for path in self.records_files:
            if path.exists():
                found += violations(load_records(path), source=str(path))
        return found

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop_all()


def _param_text(value) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (list, tuple)):
        return '[' + ','.join(_param_text(v) for v in value) + ']'
    if isinstance(value, str):
        return f"'{value}'" if value == '' else value
    return repr(value)


#: How long a probe waits for a service to appear on the graph [s].
DISCOVERY_TIMEOUT_S = 15.0


class Probe:
    """An rclpy node in this process, on the graph's domain, spinning in a background thread."""

    def __init__(self, domain_id: int, name: str = 'test_probe', namespace: str = ''):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        os.environ.update(loopback_dds_env())   # read by rclpy.init of this process's participant
        self._rclpy = rclpy
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        #: The graph's namespace the probe sits in: relative names resolve there, and the
        #: interface's private names (interface.ENABLE ...) to their node's in it.
        self.namespace = '/'.join(part for part in namespace.split('/') if part)
        self.node = rclpy.create_node(name, context=self.context, namespace='/' + self.namespace)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._lock = threading.Lock()
        self.messages: dict[str, list] = {}
        self.subscriptions: dict[str, Any] = {}
        self._clients: dict[str, Any] = {}
        self._running = True
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        while self._running and self.context.ok():
            self.executor.spin_once(timeout_sec=0.02)

    def resolve(self, name: str) -> str:
        """A name of the interface as this probe's node must ask for it: a private name of the
        tables (`~/enable`) is its node's in the probe's namespace; any other name unchanged."""
        return interface.full_name(name, self.namespace) if name.startswith('~/') else name

    def subscribe(self, msg_type, topic: str, qos, callback: Callable[[Any], None] | None = None) -> list:
        """Collect every message on `topic`; returns the (growing) list. `callback`, if given,
        also sees each message (on the probe's thread)."""
        topic = self.resolve(topic)
        received = self.messages.setdefault(topic, [])

        def keep(msg):
            with self._lock:
                received.append(msg)
            if callback is not None:
                callback(msg)
        self.subscriptions[topic] = self.node.create_subscription(msg_type, topic, keep, qos)
        return received

    def hears(self, topic: str, publishers: int = 1) -> bool:
        """The probe's subscription to `topic` has matched at least `publishers` publishers
        (being on the graph is not enough for a volatile topic: discovery is pairwise)."""
        topic = self.resolve(topic)
        sub = self.subscriptions.get(topic)
        return sub is not None and sub.get_publisher_count() >= publishers

    def latest(self, topic: str):
        topic = self.resolve(topic)
        with self._lock:
            msgs = self.messages.get(topic, [])
            return msgs[-1] if msgs else None

    def _client(self, srv_type, name: str, timeout: float):
        name = self.resolve(name)
        client = self._clients.get(name)
        if client is None:
            client = self._clients[name] = self.node.create_client(srv_type, name)
        # Discovery under load can take seconds whatever the response deadline is.
        wait_until(lambda: client.service_is_ready(), max(timeout, DISCOVERY_TIMEOUT_S), what=f'service {name}')
        return client

    def call(self, srv_type, name: str, request, timeout: float = 10.0, attempts: int = 1):
        """The service's response. A server that has not yet matched this client's response
        reader drops the response ("failed to send response"), though it handled the request:
        attempts > 1 sends the request again after `timeout`, for requests that may be repeated."""
        client = self._client(srv_type, name, timeout)
        for attempt in range(attempts):
            future = client.call_async(request)
            try:
                wait_until(future.done, timeout, what=f'response of {name}')
                return future.result()
            except AssertionError:
                if attempt + 1 == attempts:
                    raise

    def send(self, srv_type, name: str, request, timeout: float = 10.0):
        """Send a request without waiting for its response (the caller watches the outcome on a
        topic instead: a response can be lost while discovery is still under way)."""
        return self._client(srv_type, name, timeout).call_async(request)

    def close(self):
        self._running = False
        self._thread.join(5)
        self.executor.shutdown()
        self.node.destroy_node()
        self._rclpy.shutdown(context=self.context)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


# ---- the simulated lab graph (demo, soak)
SIM_CALIBRATION = 'config/calibrations/sim-wearer.yaml'
#: The parameter files of every node, in order (sim.yaml's values win).
FILES = ('params/guidance.yaml', 'params/sim.yaml')
#: Nodes in start order: the PLC side first so plc_output finds its PLC.
NODES = ('mock_plc', 'plc_output', 'gaze_bridge', 'target_selector', 'pressure_controller', 'headset_display',
         'wearer_sim')


@dataclass
class SimLab:
    """The ports of one simulated lab graph and every node's parameter overrides (node -> dict;
    a caller may change them before start_nodes)."""
    plc_port: int
    gaze_port: int
    display_port: int
    overrides: dict[str, dict]


def sim_lab(condition: int, layout: str, calibration_dir: Path) -> SimLab:
    """Free ports and the overrides that wire the simulated graph together: the task waits for
    the operator's next_target; wearer_sim is the headset (it answers the bridge's clock pings
    and shows the display)."""
    plc_port, gaze_port, display_port = free_port(), free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_DGRAM)
    overrides = {
        'mock_plc': dict(port=plc_port),
        'plc_output': dict(plc_port=plc_port),
        'gaze_bridge': dict(port=gaze_port, headset_address='127.0.0.1', display_port=display_port),
        'headset_display': dict(headset_address='127.0.0.1', display_port=display_port),
        'target_selector': dict(autostart=False),
        'pressure_controller': dict(condition=condition, calibration_file=SIM_CALIBRATION,
                                    calibration_dir=str(calibration_dir)),
        'wearer_sim': dict(bridge_port=gaze_port, layout=layout, display_port=display_port),
    }
    return SimLab(plc_port, gaze_port, display_port, overrides)


def start_nodes(graph: Graph, lab: SimLab, files: Sequence[str] = FILES,
                extra_files: Mapping[str, Sequence[str]] | None = None) -> None:
    """Every node of NODES in order, with `files` (then the node's `extra_files`, absolute
    paths allowed) and its overrides."""
    extra = extra_files or {}
    for node in NODES:
        graph.start(node, (*files, *extra.get(node, ())), **lab.overrides[node])


def start_task(probe: Probe, started: Callable[[], object], attempts: int = 3) -> None:
    """Call next_target as an operator would until `started()` says the first target is active.
    The outcome is watched, not the response: a service response can be lost while discovery
    is under way, though the request was handled (asking again would skip a target)."""
    from std_srvs.srv import Trigger
    for attempt in range(attempts):
        probe.send(Trigger, interface.NEXT_TARGET, Trigger.Request())
        try:
            wait_until(started, 5.0, what='the first target to be active')
            return
        except AssertionError:
            if attempt + 1 == attempts:
                raise
