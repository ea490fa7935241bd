"""`fabric-guidance discovery-server`: run Fast DDS's discovery server for the lab graph
(docs/lab_network.md), and the environment that makes a ROS process its client.

With a discovery server no participant discovers by multicast (the usual first failure on a
Wi-Fi or managed network): each process, given ROS_DISCOVERY_SERVER=ADDRESS:PORT, is a
discovery client of the server at that address and learns its peers from it alone.

    fabric-guidance discovery-server --listen 192.168.1.10:11811     # on the lab PC
    export ROS_DISCOVERY_SERVER=192.168.1.10:11811                    # in every ROS process

Which server runs, found at run time (no path is written in the code):
1. the `fast-discovery-server` of the ros-fastdds wheel (make venv), located through the wheel's
   file list. As installed it cannot start from the venv: it does not find libfastdds (the
   wheels' libraries are found by ros_wheels_bootstrapper's LD_LIBRARY_PATH, which only the
   venv's Python sets), and the wheel's `fastdds` script runs whichever `python3` is first on
   PATH and needs psutil, which no wheel installs. So the binary is run directly with the
   wheels' library folders on LD_LIBRARY_PATH;
2. otherwise `fast-discovery-server` on PATH (a ROS distribution: /opt/ros/<distro>/bin).
Fast DDS 3's binary takes a command index before its options (the `fastdds discovery` front end
passes 42 for "run a server": tools/fastdds/discovery/parser.py); asked for help without it, it
answers "Invalid command index", which is how the index is detected. The process execs the
server: signals (Ctrl-C, launch's SIGINT) reach it directly. No rclpy here.
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass
from importlib import metadata
import ipaddress
import os
from pathlib import Path
import shutil
import subprocess
import sys

from .. import subcommand

PROG = 'fabric-guidance discovery-server'
HELP = "run Fast DDS's discovery server for the lab graph (no multicast discovery)"

DEFAULT_PORT = 11811
BINARY = 'fast-discovery-server'
#: The index Fast DDS 3's `fastdds discovery` front end passes to run a server (Command.SERVER).
SERVER_COMMAND_INDEX = '42'
#: The wheels whose shared libraries the binary links against (libfastdds and its bundled
#: tinyxml2, OpenSSL; libfastcdr).
LIBRARY_WHEELS = ('ros-fastdds', 'ros-fastcdr')


def parse_locator(text: str) -> tuple[str, int]:
    """ADDRESS[:PORT] as (IPv4 address, port); ValueError (one line) naming the value."""
    host, _, port_text = str(text).strip().partition(':')
    try:
        address = ipaddress.IPv4Address(host)
    except ValueError:
        raise ValueError(f'discovery server {text!r}: {host!r} is not an IPv4 address '
                         '(ADDRESS[:PORT], e.g. 192.168.1.10:11811)') from None
    if address.is_multicast or address.is_unspecified:
        raise ValueError(f'discovery server {text!r}: give the address of one interface, not {host}')
    try:
        port = int(port_text) if port_text else DEFAULT_PORT
    except ValueError:
        port = -1
    if not 1 <= port <= 65535:
        raise ValueError(f'discovery server {text!r}: port {port_text!r} is not 1-65535')
    return str(address), port


def client_env(servers) -> dict[str, str]:
    """The environment that makes a ROS process (Fast DDS) a discovery client of `servers`
    (one ADDRESS[:PORT] or several): ROS_DISCOVERY_SERVER, semicolon-separated."""
    servers = [servers] if isinstance(servers, str) else list(servers)
    if not servers:
        raise ValueError('discovery server: no ADDRESS[:PORT] given')
    return {'ROS_DISCOVERY_SERVER': ';'.join('%s:%d' % parse_locator(s) for s in servers)}


@dataclass(frozen=True)
class ServerTool:
    """How to start the server: argv before the options, and what to add to the environment."""
    prefix: tuple[str, ...]
    env: dict
    origin: str


def _wheel_files(distribution: str):
    try:
        dist = metadata.distribution(distribution)
    except metadata.PackageNotFoundError:
        return None, []
    return dist, list(dist.files or [])


def _wheel_binary() -> tuple[Path, list[str]] | None:
    """The ros-fastdds wheel's binary and the folders of the wheels' shared libraries."""
    dist, files = _wheel_files('ros-fastdds')
    binaries = [f for f in files if f.name == BINARY]
    if dist is None or not binaries:
        return None
    binary = Path(dist.locate_file(binaries[0])).resolve()
    if not os.access(binary, os.X_OK):
        return None
    folders: list[str] = []
    for name in LIBRARY_WHEELS:
        d, fs = _wheel_files(name)
        for f in fs:
            if f.name.startswith('lib') and '.so' in f.name:
                folder = str(Path(d.locate_file(f)).resolve().parent)
                if folder not in folders:
                    folders.append(folder)
    return binary, folders


def _needs_index(binary: str, env: dict) -> bool:
    out = subprocess.run([binary, '-h'], capture_output=True, text=True, timeout=30, env=env)
    return 'Invalid command index' in out.stdout + out.stderr


def find_server() -> ServerTool:
    """The discovery server of the wheels, else the one on PATH; FileNotFoundError naming both."""
    found = _wheel_binary()
    if found is not None:
        binary, folders = found
        library_path = os.pathsep.join(folders + [p for p in os.environ.get('LD_LIBRARY_PATH', '').split(os.pathsep)
                                                  if p and p not in folders])
        env = {'LD_LIBRARY_PATH': library_path}
        origin = f'{binary} (ros-fastdds wheel)'
    else:
        on_path = shutil.which(BINARY)
        if on_path is None:
            raise FileNotFoundError(f'no Fast DDS discovery server: the ros-fastdds wheel is not installed and '
                                    f'{BINARY} is not on PATH (source /opt/ros/<distro>/setup.bash)')
        binary, env, origin = Path(on_path), {}, f'{on_path} (PATH)'
    index = (SERVER_COMMAND_INDEX,) if _needs_index(str(binary), {**os.environ, **env}) else ()
    return ServerTool(prefix=(str(binary), *index), env=env, origin=origin)


def server_command(listen: str, tool: ServerTool | None = None) -> tuple[list[str], dict]:
    """argv and the full environment of a server listening on ADDRESS[:PORT] (UDP)."""
    address, port = parse_locator(listen)
    tool = find_server() if tool is None else tool
    return [*tool.prefix, '--udp-address', address, '--udp-port', str(port)], {**os.environ, **tool.env}


# ---- command line

def configure(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    parser.add_argument('--listen', required=True, metavar='ADDRESS[:PORT]',
                        help=f"the server's address on the lab network (port {DEFAULT_PORT} if none); "
                             'the clients set ROS_DISCOVERY_SERVER to the same')
    parser.add_argument('--print', action='store_true', dest='print_only',
                        help='print the command and the environment it needs instead of running it')
    return parser


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the `discovery-server` subcommand to an argparse subparsers object; dispatch to run(args)."""
    return subcommand.add(subparsers, 'discovery-server', HELP, __doc__, configure, run)


def run(args: argparse.Namespace) -> int:
    """Exec the server (this process becomes it), or print how. 2 on bad input or no server."""
    try:
        tool = find_server()
        argv, env = server_command(args.listen, tool)
    except (OSError, ValueError, subprocess.SubprocessError) as exc:
        subcommand.error(PROG, exc)
        return 2
    clients = client_env(args.listen)
    if args.print_only:
        print(f'server: {tool.origin}')
        for key, value in tool.env.items():
            print(f'{key}={value}')
        print(' '.join(argv))
        print('clients: ' + ' '.join(f'{k}={v}' for k, v in clients.items()))
        return 0
    print(f'{PROG}: {tool.origin} on {args.listen}; clients set '
          + ' '.join(f'{k}={v}' for k, v in clients.items()), flush=True)
    os.execve(argv[0], argv, env)
    return 1  # not reached


def main(argv: list[str] | None = None) -> int:
    return subcommand.main(PROG, __doc__, configure, run, argv)


if __name__ == '__main__':
    sys.exit(main())
