"""`fabric-guidance replay BAG`: a recorded session again.

  replay BAG --offline [--set gain=0.1 ...]
      reruns pressure_controller's control steps over the inputs it recorded (controller_input,
      controller_parameters), without DDS, with the same core classes, and compares each step's
      command with the recorded pressure_command channel by channel: the largest difference,
      where it happens, and how much faster than real time the replay ran. Exit 0 when every
      compared command is reproduced exactly, 1 when some differ (expected with --set), 3 when
      part of the bag could not be read (a damaged chunk, fewer messages than its summary
      counts): what was unreadable is listed and the comparison is not called exact.
  replay BAG [--rate R] [--loop] [--topics ...]
      republishes the recorded inputs (gaze, head_pose, target, active_target) with /clock
      for nodes started with use_sim_time:=true (pressure_controller reruns live on the bag's
      time); --loop plays again from the start, the clock jumping back. A damaged bag is not
      republished (exit 2, naming the damage). Never into a live graph: a topic that moves a
      suit (gaze, target, pressure_command, ...) heard by a pressure_controller on the wall
      clock or published where a plc_output runs stops the replay in one line (exit 2), before
      its first message or at once while playing; --namespace NS publishes under /NS instead.

A recording cut off before it was closed (no summary section, no or a stale metadata.yaml) is
replayed, both ways, up to its last intact chunk, after one line saying what was recovered and
what was lost; `fabric-guidance recover BAG` makes it a complete bag.
"""
from __future__ import annotations

import argparse
import math
import sys

from .. import subcommand

PROG = 'fabric-guidance replay'
#: The line after Ctrl-C (subcommand.interrupted), the usual end of a --loop replay.
ON_STOP = 'the replay is stopped; nothing more is republished'
HELP = ('replay a recorded session: offline through the controller, or republished with /clock '
        'for the graph')


def configure(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    p.add_argument('bag', help='the bag folder (or its .mcap file), e.g. written by demo --record')
    p.add_argument('--offline', action='store_true',
                   help='rerun the controller over the recorded inputs without DDS and compare its commands')
    p.add_argument('--set', action='append', default=[], metavar='NAME=VALUE',
                   help='offline: change a controller parameter (gain, p_max_kpa, rate_deadband_dps, '
                        'follow_moving_target, use_wearer_gain, condition, gaze_timeout_s); repeatable')
    p.add_argument('--rate', type=float, default=1.0, help='graph replay: speed factor (default 1)')
    p.add_argument('--loop', action='store_true', help='graph replay: play again from the start, until Ctrl-C')
    p.add_argument('--loops', type=int, default=0, help='graph replay with --loop: stop after this many passes')
    p.add_argument('--topics', nargs='+', default=None, help='graph replay: topics to republish '
                   '(default gaze head_pose target active_target)')
    p.add_argument('--namespace', default='', metavar='NS',
                   help='graph replay: publish every topic under /NS (the replay\'s own controller started '
                        'there, -r __ns:=/NS, with use_sim_time:=true); /clock stays /clock')
    p.add_argument('--wait', type=float, default=2.0,
                   help='graph replay: wait up to this long for subscribers before starting [s]')
    return p


def add_parser(subparsers) -> argparse.ArgumentParser:
    return subcommand.add(subparsers, 'replay', HELP, __doc__, configure, run)


def run(args, stream=sys.stdout) -> int:
    say = subcommand.printer(stream)

    from ..bag.reader import bag_dir
    try:
        bag_dir(args.bag)
    except FileNotFoundError as exc:
        say(f'fabric-guidance replay: {exc}')
        return 2
    if args.offline:
        from ..bag import offline
        try:
            overrides = offline.parse_overrides(args.set)
            rec = offline.load(args.bag)
            result = offline.replay(rec, overrides)
        except ValueError as exc:
            say(f'fabric-guidance replay: {exc}')
            return 2
        offline.report(result, overrides, say)
        return 0 if result.exact else 3 if result.problems else 1
    if not (math.isfinite(args.rate) and args.rate > 0):
        say(f'fabric-guidance replay: --rate must be a finite number > 0, got {args.rate}')
        return 2
    if args.set:
        say('fabric-guidance replay: --set applies to --offline; set parameters of the live nodes instead')
        return 2
    from ..bag.player import LiveGraphError, play
    from ..bag.topics import REPLAYED_INPUTS
    try:
        n = play(args.bag, args.topics or REPLAYED_INPUTS, args.rate, args.loop, args.loops, args.wait, say,
                 namespace=args.namespace)
    except (ValueError, LiveGraphError) as exc:
        say(f'fabric-guidance replay: {exc}')
        return 2
    say(f'{n} messages republished')
    return 0


def main(argv: list[str] | None = None) -> int:
    return subcommand.main(PROG, __doc__, configure, run, argv)


if __name__ == '__main__':
    sys.exit(main())
