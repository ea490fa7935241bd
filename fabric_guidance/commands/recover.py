"""`fabric-guidance recover BAG [--out OUT]`: a complete bag from a cut-off one.

A recorder killed without warning (SIGKILL, power loss, a full disk) leaves its MCAP file
without the summary section and its folder without metadata.yaml. `replay` reads such a bag up
to its last intact chunk already; this writes that intact part as a new bag that every reader
opens (`ros2 bag`, Foxglove, the mcap and rosbags libraries): the same messages with their
topics, types, definitions and offered QoS profiles, a summary and a metadata.yaml. The input
is never changed: OUT must not exist (default: BAG-recovered beside BAG), and it appears only
when it is complete (written under a temporary name, read back, then renamed).

Exit 0 when OUT was written (or BAG needs no recovery: nothing written), 2 when nothing could
be recovered or OUT cannot be written (one line saying why).
"""
from __future__ import annotations

import argparse
from pathlib import Path
import shutil
import sys
import tempfile

from .. import subcommand

PROG = 'fabric-guidance recover'
HELP = 'write a complete bag (summary, metadata.yaml) from the intact part of a cut-off recording'


def configure(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    p.add_argument('bag', help='the bag folder (or its .mcap file) of a recording that was cut off')
    p.add_argument('--out', type=Path, default=None,
                   help='the bag folder to write (must not exist; default: BAG-recovered beside BAG)')
    return p


def add_parser(subparsers) -> argparse.ArgumentParser:
    return subcommand.add(subparsers, 'recover', HELP, __doc__, configure, run)


def write_recovered(found, out: Path, note: str) -> dict[str, int]:
    """The messages of `found` (Recovered per file) as a new bag at `out`, in time order, each
    topic with its type and the QoS profiles its channel carried; returns messages per topic.
    Written beside `out` under a temporary name and renamed when closed and read back whole."""
    from rosbags.rosbag2.metadata import parse_qos
    from ..bag.reader import raw_messages
    from ..bag.writer import BagWriter

    messages = []
    topics = {}
    for r in found:
        for channel in r.channels.values():       # a topic without messages is kept too
            schema = r.schemas.get(channel.schema_id)
            if channel.topic not in topics:
                qos = channel.metadata.get('offered_qos_profiles', '')
                topics[channel.topic] = (schema.name if schema else '', parse_qos(qos) if qos else [])
        messages += [(log_time, r.channels[cid].topic, m.data) for log_time, cid, m in r.messages]
    messages.sort(key=lambda m: m[0])
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f'.{out.name}.', dir=out.parent))
    try:
        bag = staging / out.name
        with BagWriter(bag, custom_data={'fabric_guidance.recovered': note}) as writer:
            for topic, (msgtype, qos) in topics.items():
                writer.add_topic(topic, msgtype, qos)
            for log_time, topic, data in messages:
                writer.write(topic, log_time, data)
            counts = dict(writer.counts)
        recovered = []
        read = sum(1 for _ in raw_messages(bag, recovered=recovered))
        if recovered or read != len(messages):   # the new bag must read whole through its index
            raise ValueError(f'{bag}: written with {len(messages)} messages, read back {read}')
        if out.exists():
            raise FileExistsError(f'{out} exists already: not overwritten')
        bag.rename(out)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return counts


def run(args, stream=sys.stdout) -> int:
    say = subcommand.printer(stream)
    from ..bag.reader import BagReadError, scan_bag
    try:
        directory, found, missing = scan_bag(args.bag)
    except (FileNotFoundError, BagReadError) as exc:
        say(f'{PROG}: {exc}')
        return 2
    if not missing:
        say(f'{directory}: complete (every file has its summary, metadata.yaml is there): nothing to recover')
        return 0
    out = args.out.expanduser() if args.out is not None else directory.with_name(directory.name + '-recovered')
    if out.exists():
        say(f'{PROG}: {out} exists already: not overwritten (name another with --out)')
        return 2
    for r in found:
        say(r.describe())
    note = f'recovered from {directory} ({missing})'
    try:
        counts = write_recovered(found, out, note)
    except Exception as exc:  # a full disk, a read-only folder; rosbags: a type it does not know
        say(f'{PROG}: cannot write {out}: {type(exc).__name__}: {" ".join(str(exc).split())[:200]}')
        return 2
    say(f'written {out}: {sum(counts.values())} messages on {len(counts)} topics, with its summary and '
        f'metadata.yaml; {directory} is unchanged')
    return 0


def main(argv: list[str] | None = None) -> int:
    return subcommand.main(PROG, __doc__, configure, run, argv)


if __name__ == '__main__':
    sys.exit(main())
