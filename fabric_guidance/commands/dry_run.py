"""`fabric-guidance dry-run`: the lab graph against a mock PLC on this PC, without the simulated
wearer: a lab's dry run with the real headset and a person, no suit.

  fabric-guidance dry-run --headset-address 192.168.1.20 --bind-address 192.168.1.10 --study speed

starts what `ros2 launch fabric_guidance guidance.launch.py mock_plc:=true headset_address:=...
study:=speed` starts, as processes (graph/process_graph.py), for an installation without
`ros2 launch` (the wheels): mock_plc first, then, once it listens, plc_output (at 127.0.0.1 and
the mock's port), gaze_bridge, target_selector, pressure_controller and headset_display, with
config/params/guidance.yaml and, with --study, config/params/study-<task>.yaml after it. The
options are the launch arguments of the same names; the headset's address is where the display
and the clock pings go and the one sender whose gaze gaze_bridge accepts (the launch's
headset_address and allowed_senders).

pressure_controller starts disarmed and, if its process dies, is started again 2 s later, disarmed
again (the launch's respawn): nothing guides until the operator's `enable`. Another node that
ends is reported in one line and stays down.

The graph runs on the shell's ROS_DOMAIN_ID (0 when unset), so that the operator's tools on this
PC join it (`fabric-guidance study --participant ...`, `ros2 service call`); its DDS stays on
127.0.0.1 (config/fastdds_loopback.xml): the headset talks to gaze_bridge and headset_display
over UDP, not DDS. Ctrl-C (or SIGTERM) stops every node, each venting on its way out; the nodes'
logs stay in --logs.
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass
from datetime import datetime, timezone
import errno
import ipaddress
import os
from pathlib import Path
import socket
import sys
import time

from .. import subcommand

PROG = 'fabric-guidance dry-run'
HELP = 'run the lab graph against a mock PLC on this PC, with the real headset and no suit (a dry run)'
#: The line after Ctrl-C or SIGTERM (subcommand.interrupted): the command's `finally` has stopped the graph.
ON_STOP = 'the dry run is stopped (each node vented on its way out)'

#: The lab nodes in start order, after mock_plc (process_graph.NODES without the simulation).
LAB_NODES = ('plc_output', 'gaze_bridge', 'target_selector', 'pressure_controller', 'headset_display')
#: The node restarted when its process dies, disarmed (the launch restarts it the same way).
SUPERVISED = 'pressure_controller'
#: How long mock_plc gets to listen: a cold start of rclpy on a loaded PC [s].
MOCK_LISTENS_S = 60.0
#: How often the command looks at its nodes [s].
POLL_S = 0.2
#: The highest ROS_DOMAIN_ID whose DDS ports exist (Fast DDS: 7400 + 250 x the id stays below 65536).
MAX_DOMAIN_ID = 232
#: Above it the DDS ports fall in Linux's ephemeral port range (32768-60999), where any program's
#: UDP socket may hold one (the ROS 2 docs' "About Domain ID").
SAFE_DOMAIN_ID = 101


def configure(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    # Values are read as text and checked in run(): a bad one is one line naming its option.
    parser.add_argument('--headset-address', required=True, metavar='ADDRESS',
                        help="the HoloLens's IP address: the display and the clock pings go there, and only its "
                             'gaze is accepted')
    parser.add_argument('--study', default=None, metavar='TASK',
                        help="the paper's task of a study session, speed or accuracy: loads "
                             'config/params/study-<task>.yaml last (docs/study.md)')
    parser.add_argument('--wearer', default=None,
                        help="the participant's id: a calibration is written as <wearer>.yaml in the calibration "
                             'folder, and that file is loaded when it exists')
    parser.add_argument('--calibration-file', default=None, metavar='FILE', help="the wearer's calibration (YAML)")
    parser.add_argument('--calibration-dir', default=None, metavar='DIR',
                        help='where a calibration is written (default: the parameter file\'s, '
                             '~/.fabric_guidance/calibrations)')
    parser.add_argument('--condition', default=None,
                        help='1 surface adjusted, 2 surface fixed, 3 arm adjusted, 4 speech (default: the file\'s)')
    parser.add_argument('--plc-port', default=None, metavar='PORT',
                        help="the mock PLC's Modbus TCP port on 127.0.0.1 (default: guidance.yaml's)")
    parser.add_argument('--gaze-port', default=None, metavar='PORT',
                        help='UDP port the gaze bridge listens on (default: guidance.yaml\'s)')
    parser.add_argument('--display-port', default=None, metavar='PORT',
                        help="the headset app's downlink UDP port (default: guidance.yaml's)")
    parser.add_argument('--bind-address', default=None, metavar='ADDRESS',
                        help="UDP address the gaze bridge listens on: this PC's on the headset's network "
                             "(default: guidance.yaml's)")
    parser.add_argument('--logs', default=None, metavar='DIR',
                        help='folder for the nodes\' logs (default: ~/.fabric_guidance/dry-runs/<UTC time>)')
    return parser


def add_parser(subparsers) -> argparse.ArgumentParser:
    return subcommand.add(subparsers, 'dry-run', HELP, __doc__, configure, run)


class OptionError(ValueError):
    """A bad option value: the message names the option and the reason."""


@dataclass
class DryRun:
    """The checked settings of one dry run."""
    domain_id: int
    headset: str
    bind_address: str
    plc_port: int
    gaze_port: int
    display_port: int
    files: tuple[str, ...]              # parameter files under config/, in order
    controller: dict                    # pressure_controller's overrides from the options
    logs: Path
    study: str | None

    def overrides(self) -> dict[str, dict]:
        """Every lab node's parameters over the files, as the lab launch with mock_plc:=true sets them."""
        headset = dict(headset_address=self.headset, display_port=self.display_port)
        return {
            'plc_output': dict(plc_host='127.0.0.1', plc_port=self.plc_port),
            'gaze_bridge': dict(bind_address=self.bind_address, port=self.gaze_port,
                                allowed_senders=[self.headset], **headset),
            'target_selector': {},
            # Every start, first or restarted, waits for the operator's enable (the launch's respawn).
            'pressure_controller': dict(self.controller, start_enabled=False),
            'headset_display': headset,
        }


def run(args: argparse.Namespace) -> int:
    try:
        plan = check(args)
    except OptionError as exc:   # before anything starts
        subcommand.error(PROG, exc)
        return 2
    return run_dry_run(plan, subcommand.printer(sys.stdout))


def main(argv: list[str] | None = None) -> int:
    return subcommand.main(PROG, __doc__, configure, run, argv)


# ---- the options, checked before anything starts
def check(args: argparse.Namespace) -> DryRun:
    """The settings of `args`; OptionError naming the option at the first bad value."""
    from ..graph.lab_graph import study_params_file
    files = ['params/guidance.yaml']
    if args.study is not None:
        try:
            files.append(study_params_file(args.study))
        except ValueError as exc:
            raise OptionError(f'--study {args.study}: {exc}') from None
    bridge, plc = _file_values(files, 'gaze_bridge'), _file_values(files, 'plc_output')
    domain_id = _domain_id(os.environ.get('ROS_DOMAIN_ID', ''))
    headset = _address('--headset-address', args.headset_address)
    bind = _address('--bind-address', bridge['bind_address'] if args.bind_address is None else args.bind_address)
    if headset.version == 6 and bind.version == 4:
        raise OptionError(f'--headset-address {headset}: IPv6, but the gaze bridge listens on IPv4 {bind} '
                          '(--bind-address)')
    if bind.is_loopback and not headset.is_loopback:
        raise OptionError(f'--bind-address {bind}: a headset at {headset} cannot reach a loopback address; give '
                          "this PC's address on the headset's network")
    plc_port = _port('--plc-port', args.plc_port, plc['plc_port'])
    gaze_port = _port('--gaze-port', args.gaze_port, bridge['port'])
    display_port = _port('--display-port', args.display_port, bridge['display_port'])
    _can_listen('--plc-port', plc_port, '127.0.0.1', socket.SOCK_STREAM, 'the mock PLC')
    _can_listen('--gaze-port', gaze_port, str(bind), socket.SOCK_DGRAM, 'the gaze bridge', '--bind-address')
    controller = _controller(args)
    logs = Path(args.logs).expanduser() if args.logs else (
        Path.home() / '.fabric_guidance' / 'dry-runs' / datetime.now(timezone.utc).strftime('%Y%m%d_%H%M%S'))
    # Last: these make the folders they check.
    for option, folder in (('--calibration-dir', controller.get('calibration_dir')), ('--logs', logs)):
        why = subcommand.writable_folder(folder) if folder else ''
        if why:
            raise OptionError(f'{option}: {why}')
    return DryRun(domain_id, str(headset), str(bind), plc_port, gaze_port, display_port, tuple(files),
                  controller, logs.resolve(), args.study)


def _file_values(files: list[str], node: str) -> dict:
    """A node's parameters as the files give them, the later file's values winning."""
    from ..paths import node_parameters
    values: dict = {}
    for name in files:
        values.update(node_parameters(name, node))
    return values


def _domain_id(text: str) -> int:
    if not text.strip():
        return 0
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= MAX_DOMAIN_ID:
        raise OptionError(f'ROS_DOMAIN_ID={text!r} (the environment): not a domain id 0-{MAX_DOMAIN_ID}')
    return value


def _address(option: str, text: str):
    try:
        return ipaddress.ip_address(text.strip())
    except ValueError:
        raise OptionError(f'{option} {text!r}: not an IP address') from None


def _port(option: str, text: str | None, default: int) -> int:
    if text is None:
        return int(default)
    try:
        value = int(text)
    except ValueError:
        value = 0
    if not 1 <= value <= 65535:
        raise OptionError(f'{option} {text!r}: not a port 1-65535')
    return value


def _can_listen(option: str, port: int, address: str, kind: int, who: str, address_option: str = '') -> None:
    """OptionError when `who` could not listen on address:port (taken, or not this PC's address)."""
    family = socket.AF_INET6 if ipaddress.ip_address(address).version == 6 else socket.AF_INET
    with socket.socket(family, kind) as s:
        if kind == socket.SOCK_STREAM:   # as a listener does: a connection closed earlier is no obstacle
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((address, port))
        except OSError as exc:
            why = exc.strerror or str(exc)
            if address_option and exc.errno != errno.EADDRINUSE:
                raise OptionError(f'{address_option} {address}: {who} cannot listen there ({why}); give an '
                                  'address of this PC') from None
            raise OptionError(f'{option} {port}: {who} cannot listen on {address}:{port} ({why})') from None


def _controller(args: argparse.Namespace) -> dict:
    """pressure_controller's parameters from the options (checked as the node would refuse them)."""
    from ..core.controller_parameters import default
    from ..core.safe_input import check_wearer
    out = {}
    if args.condition is not None:
        if args.condition.strip() not in ('1', '2', '3', '4'):
            raise OptionError(f'--condition {args.condition!r}: one of 1, 2, 3, 4')
        out['condition'] = int(args.condition)
    if args.wearer is not None:
        try:
            out['wearer'] = check_wearer(args.wearer, '--wearer')
        except ValueError as exc:
            raise OptionError(str(exc)) from None
    if args.calibration_file is not None:
        path = _calibration_path(args.calibration_file)
        from ..core import Calibration
        try:
            calibration = Calibration.load(path)
        except (OSError, ValueError) as exc:
            raise OptionError(f'--calibration-file: {exc}') from None
        wearer = out.get('wearer', default('wearer'))
        if wearer != default('wearer') and calibration.wearer != wearer:
            # The controller would refuse it at every start (one person's calibration never guides another).
            raise OptionError(f'--calibration-file {path}: its wearer is {calibration.wearer!r}, --wearer is '
                              f'{wearer!r}')
        out['calibration_file'] = str(path)
    if args.calibration_dir is not None:
        out['calibration_dir'] = str(Path(args.calibration_dir).expanduser().resolve())
    return out


def _calibration_path(text: str) -> Path:
    """The file a --calibration-file names: from here, else from the package's share (as the node reads a
    relative path); OptionError when neither exists."""
    from ..paths import resolve
    for path in (Path(text).expanduser(), resolve(text, '')):
        if path.is_file():
            return path.resolve()
    raise OptionError(f'--calibration-file {text}: no such file')


# ---- the graph
def run_dry_run(plan: DryRun, say) -> int:
    """Start the graph, say how to use it, and watch it until Ctrl-C or SIGTERM (KeyboardInterrupt,
    raised through here once the graph is stopped). 1 when mock_plc did not come up."""
    from ..graph.process_graph import Graph
    graph = Graph(plan.logs, domain_id=plan.domain_id)
    try:
        say(f'{PROG}: starting the lab graph against a mock PLC on this PC (no suit, no wearer_sim) on '
            f'ROS_DOMAIN_ID {plan.domain_id}; logs in {plan.logs}')
        graph.start('mock_plc', (), port=plan.plc_port)   # only its port, as the launch starts it
        why = _mock_listens(graph)
        if why:
            say(f'{PROG}: mock_plc did not listen on 127.0.0.1:{plan.plc_port}: {why}; '
                f'its log: {plan.logs / "mock_plc.log"}')
            return 1
        overrides = plan.overrides()
        for node in LAB_NODES:
            graph.start(node, (*plan.files, override_file(plan.logs, node, overrides[node])))
        from ..graph.lab_graph import RESPAWN_DELAY_S
        # A fixed delay, as launch's respawn (it has no growing back-off).
        graph.supervise(SUPERVISED, delay_s=RESPAWN_DELAY_S, max_delay_s=RESPAWN_DELAY_S)
        for line in started_lines(plan):
            say(line)
        watch(graph, plan, say)
    finally:
        stop(graph, say)
    return 0


def override_file(logs: Path, node: str, values: dict) -> str:
    """A parameter file keyed by the node's own name, loaded after the package's files so that its
    values win, as the lab launch passes its arguments; kept with the logs (what each node was given)."""
    import yaml
    folder = logs / 'parameters'
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f'{node}.yaml'
    path.write_text(yaml.safe_dump({f'/{node}': {'ros__parameters': values}}, sort_keys=False))
    return str(path)


def _mock_listens(graph) -> str:
    """'' once mock_plc says it listens; why not if it ended first or took too long."""
    from ..graph.lab_graph import MOCK_PLC_LISTENING
    deadline = time.monotonic() + MOCK_LISTENS_S
    while True:
        log = graph.log('mock_plc')
        if MOCK_PLC_LISTENING in log:
            return ''
        code = graph.processes['mock_plc'].poll()
        if code is not None:
            last = [line for line in log.splitlines() if line.strip()][-1:]
            return f'it ended (exit code {code})' + (f': {last[0].strip()}' if last else '')
        if time.monotonic() > deadline:
            return f'not within {MOCK_LISTENS_S:.0f} s'
        time.sleep(0.05)


def started_lines(plan: DryRun) -> list[str]:
    """What the operator needs once the graph runs: the domain, the ports, the logs, how to arm, how to stop."""
    from .. import interface
    session = (f'; the session: fabric-guidance study --participant ID --protocol {plan.study} --out STUDY_DIR'
               if plan.study else '')
    return [
        f'{PROG}: running, {len(LAB_NODES) + 1} nodes' + (f', study {plan.study}' if plan.study else ''),
        f'  ROS_DOMAIN_ID {plan.domain_id} (from the shell), DDS on 127.0.0.1: the operator\'s tools join from this PC '
        f'with the same ROS_DOMAIN_ID{session}',
        f'  mock PLC 127.0.0.1:{plan.plc_port} (Modbus TCP, plc_output\'s link); gaze from {plan.headset} on UDP '
        f'{_endpoint(plan.bind_address, plan.gaze_port)}; display to {_endpoint(plan.headset, plan.display_port)}',
        *([f'  WARNING: ROS_DOMAIN_ID {plan.domain_id} is above {SAFE_DOMAIN_ID}: its DDS ports lie in Linux\'s '
            'ephemeral range, where another program may take one and discovery then fails by chance; 0-101 are safe']
          if plan.domain_id > SAFE_DOMAIN_ID else []),
        f'  pressure_controller is disarmed, and again whenever it restarts: arm it with '
        f'`ros2 service call {interface.full_name(interface.ENABLE)} std_srvs/srv/SetBool "{{data: true}}"`',
        f'  logs in {plan.logs}',
        '  Ctrl-C stops every node, each venting on its way out.',
    ]


def _endpoint(address: str, port: int) -> str:
    return f'[{address}]:{port}' if ':' in address else f'{address}:{port}'


def watch(graph, plan: DryRun, say) -> None:
    """Until interrupted: one line for each node that ended (not restarted) and for each restart of
    the supervised controller."""
    reported: set[str] = set()
    restarts = 0
    while True:
        for node, code in sorted(graph.ended().items()):
            if node != SUPERVISED and node not in reported:
                reported.add(node)
                say(f'{PROG}: {node} ended (exit code {code}) and stays down; its log: {plan.logs / (node + ".log")}')
        for restart in list(graph.restarts)[restarts:]:
            restarts += 1
            say(f'{PROG}: {restart.node} ended (exit code {restart.returncode}) and was started again, disarmed: '
                'arm it again with enable')
        time.sleep(POLL_S)


def stop(graph, say) -> None:
    """The lab nodes first, each venting on its way out, then the mock PLC (which takes their vents):
    as the lab launch's Ctrl-C ends them. A mock PLC write above p_max is said."""
    for node in (*reversed(LAB_NODES), 'mock_plc'):
        if node not in graph.processes:
            continue
        try:
            graph.stop(node)
        except AssertionError as exc:   # killed after its time: said, and the others still stopped
            say(f'{PROG}: {exc}; killed')
    graph.stop_all(check=False)
    for line in graph.plc_violations():
        say(f'{PROG}: WARNING: {line}')


if __name__ == '__main__':
    sys.exit(main())
