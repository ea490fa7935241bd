"""`fabric-guidance demo` (= `make demo`): the simulated ROS graph, a short guided session, and
what happened. The graph is started as processes (fabric_guidance/graph/process_graph.py) and watched
by fabric_guidance/commands/demo.py; rclpy is imported only when the demo runs.
"""
from __future__ import annotations

import argparse
from pathlib import Path
import sys

from .. import subcommand

PROG = 'fabric-guidance demo'
HELP = 'run the simulated ROS graph for a short guided session and report it'
#: The line after Ctrl-C (subcommand.interrupted): the demo's `finally` has stopped the graph.
ON_STOP = 'the simulated graph is stopped (each node vented on its way out), its temporary logs removed'


def configure(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    parser.add_argument('--condition', type=int, default=None, choices=(1, 2, 3, 4),
                        help='guidance condition (1 surface adjusted, 2 surface fixed, 3 arm '
                             "adjusted; 4 speech, with --scene only); default 1, or the scene's "
                             'first')
    parser.add_argument('--scene', default=None,
                        help='run a scene of the simulator (config/scenes name or file) through '
                             'the graph')
    parser.add_argument('--timeout', type=float, default=45.0,
                        help='give up after this many seconds')
    parser.add_argument('--out', type=Path, default=None,
                        help='folder for logs (default: a temporary folder)')
    parser.add_argument('--record', type=Path, default=None, metavar='DIR',
                        help='record the session as a ROS 2 bag (MCAP) in DIR')
    return parser


def add_parser(subparsers) -> argparse.ArgumentParser:
    return subcommand.add(subparsers, 'demo', HELP, __doc__, configure, run)


def run(args: argparse.Namespace) -> int:
    for option, folder in (('--out', args.out), ('--record', args.record)):
        why = subcommand.writable_folder(folder) if folder is not None else ''
        if why:   # refused before a graph starts, not after the session it would have kept
            subcommand.error(PROG, f'{option}: {why}')
            return 2
    from .demo import run_demo  # imports rclpy: only for the graph
    return run_demo(args.condition, args.timeout, args.out, scene=args.scene,
                    record_dir=args.record)


def main(argv: list[str] | None = None) -> int:
    return subcommand.main(PROG, __doc__, configure, run, argv)


if __name__ == '__main__':
    sys.exit(main())
