"""`fabric-guidance security-policy`: the SROS2 permissions policy of the lab graph, generated
from the interface table (fabric_guidance/interface.py; docs/security.md).

One enclave per node of the package, `/fabric_guidance/<node>`. Each may publish and subscribe
exactly the topics the table lists it under, and answer the services the table says it serves;
plus what every rclpy node of this ROS release opens by itself:
- publish `/rosout` (its log) and `/parameter_events`;
- answer its parameter services (`~/describe_parameters`, `~/get_parameter_types`,
  `~/get_parameters`, `~/list_parameters`, `~/set_parameters`, `~/set_parameters_atomically`)
  and `~/get_type_description` (rclpy starts it by default since Jazzy);
- subscribe `/clock`: the table's "nodes with `use_sim_time`", which any node may be started with.
This is sros2's common node profile (sros2 test/policies/common/node/*.xml) less what a node
does not do here: it neither calls its own parameter services nor reads `/parameter_events`.
How the table's words become grants: `table_grants()`. The file names ROS topics and services
fully qualified in the root namespace, where the launch files start the nodes (`/gaze`,
`/pressure_controller/get_parameters`), as SROS2 policies take them: no `rt/`, `rq/`, `rr/`
(sros2's permissions.xsl adds those); `live_targets/<name>` becomes the pattern `/live_targets/*`.

A further enclave, `/fabric_guidance/operator`, is for the operator's `ros2` commands (no node
of the table): it may call the table's services and the package nodes' parameter services, and
subscribe every topic of the table; it publishes nothing but `/rosout` and `/parameter_events`
and answers only `~/get_type_description` (ros2cli's node starts no parameter services).
`--no-operator` leaves it out.

    fabric-guidance security-policy --out policy.xml
    ros2 security generate_artifacts -k ~/lab/keystore -p policy.xml

No rclpy here (the table and the launch helpers use it without ROS).
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from pathlib import Path
import re
import sys
import xml.etree.ElementTree as ET

from .. import interface, subcommand
from ..atomic import write_text

PROG = 'fabric-guidance security-policy'
HELP = 'write the SROS2 permissions policy of the lab graph, generated from the interface table'

POLICY_VERSION = '0.2.0'           # sros2's policy.xsd (fixed)
ENCLAVE_ROOT = '/fabric_guidance'
OPERATOR = 'operator'

#: The package's nodes (setup.py's console scripts, less the `fabric-guidance` command).
NODES = ('gaze_bridge', 'target_selector', 'pressure_controller', 'plc_output', 'headset_display',
         'mock_plc', 'wearer_sim', 'micromanipulator_sim', 'bag_recorder')
#: Nodes that are rclpy lifecycle nodes: they also answer the lifecycle services and publish
#: `~/transition_event` (sros2's common/lifecycle_node.xml).
LIFECYCLE_NODES: tuple[str, ...] = interface.MANAGED_NODES
#: Words of the table's publisher and subscriber columns that name no node of the package: other
#: software (which needs an enclave of its own where security is enforced) or people.
NOT_NODES = ('RViz', 'micromanipulator stack', 'the demo', 'tests', '`fabric-guidance replay`', 'the study session')
#: The table's words for "every node of the package" (/clock's subscribers).
EVERY_NODE = 'nodes with `use_sim_time`'

PARAMETER_SERVICES = ('describe_parameters', 'get_parameter_types', 'get_parameters', 'list_parameters',
                      'set_parameters', 'set_parameters_atomically')
NODE_PUBLISHES = ('/rosout', '/parameter_events')
NODE_SUBSCRIBES = (interface.CLOCK,)
NODE_REPLIES = tuple(f'~/{s}' for s in PARAMETER_SERVICES + ('get_type_description',))
LIFECYCLE_REPLIES = tuple(f'~/{s}' for s in ('change_state', 'get_available_states',
                                             'get_available_transitions', 'get_state', 'get_transition_graph'))
LIFECYCLE_PUBLISHES = ('~/transition_event',)


@dataclass
class Grants:
    """What one enclave may do: ROS names (or patterns) per permission."""
    publish: set = field(default_factory=set)
    subscribe: set = field(default_factory=set)
    reply: set = field(default_factory=set)
    request: set = field(default_factory=set)


def _entries(text: str) -> list[str]:
    """The comma-separated entries of a publisher or subscriber cell, each without its
    parenthetical remark ("wearer_sim (with a scene, condition 4)") and a leading "or"."""
    text = re.sub(r'\([^)]*\)', '', text)
    out = []
    for part in text.split(','):
        part = part.strip()
        part = part[3:].strip() if part.startswith('or ') else part
        if part:
            out.append(part)
    return out


def nodes_named(text: str, where: str) -> set[str]:
    """The package's nodes a table cell names; ValueError for a word that is neither a node nor
    one of NOT_NODES, so that a new row cannot slip past the policy."""
    nodes = set()
    for entry in _entries(text):
        if entry == EVERY_NODE:
            nodes.update(NODES)
        elif entry in NODES:
            nodes.add(entry)
        elif entry not in NOT_NODES:
            raise ValueError(f'fabric_guidance/interface.py: {where}: {entry!r} is no node of the package '
                             f'({", ".join(NODES)}) nor listed in security_policy.NOT_NODES')
    return nodes


def policy_name(topic_name: str) -> str:
    """A topic of the table as a policy expression: `<name>` placeholders become `*`."""
    return re.sub(r'<[^>]*>', '*', topic_name)


def table_grants(operator: bool = True) -> dict[str, Grants]:
    """Enclave name (the node's, or 'operator') -> its grants, from interface.TOPICS and SERVICES.
    bag_recorder subscribes to every topic the table marks recorded (its `topics` default)."""
    grants = {node: Grants() for node in NODES}
    for t in interface.TOPICS:
        name = policy_name(t.name)
        for node in nodes_named(t.publishers, f'topic {t.name}: publishers'):
            grants[node].publish.add(name)
        subscribers = nodes_named(t.subscribers, f'topic {t.name}: subscribers')
        if t.recorded:
            subscribers.add('bag_recorder')
        for node in subscribers:
            grants[node].subscribe.add(name)
    for s in interface.SERVICES:
        if s.node not in NODES:
            raise ValueError(f'fabric_guidance/interface.py: service {s.name}: node {s.node!r} '
                             'is no node of the package')
        grants[s.node].reply.add(s.name)
    for node, g in grants.items():
        g.publish.update(NODE_PUBLISHES)
        g.subscribe.update(NODE_SUBSCRIBES)
        g.reply.update(NODE_REPLIES)
        if node in LIFECYCLE_NODES:
            g.reply.update(LIFECYCLE_REPLIES)
            g.publish.update(LIFECYCLE_PUBLISHES)
    if operator:
        g = grants[OPERATOR] = Grants()
        g.publish.update(NODE_PUBLISHES)
        # ros2cli's node starts no parameter services, only rclpy's type description service.
        g.reply.add('~/get_type_description')
        # Private names are their node's, not the operator's own.
        g.request.update(interface.full_name(s.name) for s in interface.SERVICES)
        g.request.update(f'/{node}/{s}' for node in NODES for s in PARAMETER_SERVICES)
        # `ros2 lifecycle set/get` on the managed nodes (docs/lifecycle.md)
        g.request.update(f'/{node}/{s[2:]}' for node in LIFECYCLE_NODES for s in LIFECYCLE_REPLIES)
        g.subscribe.update(f'/{node}/{s[2:]}' for node in LIFECYCLE_NODES for s in LIFECYCLE_PUBLISHES)
        g.subscribe.update(policy_name(interface.full_name(t.name) if t.name.startswith('~/') else t.name)
                           for t in interface.TOPICS)
    return grants


def qualified(name: str, node: str) -> str:
    """A name of the grants fully qualified in the root namespace, as the launch files start
    the nodes: `gaze` -> `/gaze`, `~/get_parameters` -> `/<node>/get_parameters`."""
    if name.startswith('~/'):
        return f'/{node}/{name[2:]}'
    return name if name.startswith('/') else '/' + name


def enclave_path(node: str) -> str:
    return f'{ENCLAVE_ROOT}/{node}'


def policy_xml(operator: bool = True) -> str:
    """The policy (sros2 policy format 0.2.0) as text, enclaves and names sorted."""
    root = ET.Element('policy', version=POLICY_VERSION)
    enclaves = ET.SubElement(root, 'enclaves')
    for node, g in sorted(table_grants(operator).items()):
        enclave = ET.SubElement(enclaves, 'enclave', path=enclave_path(node))
        profiles = ET.SubElement(enclave, 'profiles')
        # The operator's `ros2` commands name their node themselves: its `~` matches any node.
        own = '*' if node == OPERATOR else node
        profile = ET.SubElement(profiles, 'profile', ns='/', node=own)
        for kind, child, attribute, names in (('topics', 'topic', 'publish', g.publish),
                                              ('topics', 'topic', 'subscribe', g.subscribe),
                                              ('services', 'service', 'reply', g.reply),
                                              ('services', 'service', 'request', g.request)):
            if names:
                element = ET.SubElement(profile, kind, {attribute: 'ALLOW'})
                for name in sorted(qualified(n, own) for n in names):
                    ET.SubElement(element, child).text = name
    ET.indent(root)
    comment = ('<!-- Generated by fabric-guidance security-policy from fabric_guidance/interface.py; '
               'do not edit (docs/security.md). -->\n')
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + comment + ET.tostring(root, encoding='unicode') + '\n'


def read_policy(text: str, source: str = 'policy') -> dict[str, Grants]:
    """Enclave path -> grants of a policy file, checked against the structure of sros2's
    policy.xsd (version 0.2.0: enclaves/enclave[@path]/profiles/profile[@ns,@node] with topics
    (publish/subscribe) and services (reply/request), ALLOW or DENY); ValueError naming the
    element. A DENY, an action or a second profile is refused: this package generates none."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise ValueError(f'{source}: not XML ({exc})') from None
    if root.tag != 'policy' or root.get('version') != POLICY_VERSION:
        raise ValueError(f'{source}: root is not <policy version="{POLICY_VERSION}">')
    enclaves = list(root)
    if [e.tag for e in enclaves] != ['enclaves'] or not len(enclaves[0]):
        raise ValueError(f'{source}: policy: one <enclaves> with at least one <enclave> expected')
    out: dict[str, Grants] = {}
    for enclave in enclaves[0]:
        path = enclave.get('path')
        if enclave.tag != 'enclave' or not path or not path.startswith('/'):
            raise ValueError(f'{source}: enclaves: <{enclave.tag} path={path!r}> is not an enclave '
                             'with an absolute path')
        if path in out:
            raise ValueError(f'{source}: enclave {path}: listed twice')
        profiles = [p for ps in enclave if ps.tag == 'profiles' for p in ps]
        if len(enclave) != 1 or len(profiles) != 1 or profiles[0].tag != 'profile':
            raise ValueError(f'{source}: enclave {path}: one <profiles> with one <profile> expected')
        profile = profiles[0]
        if profile.get('ns') is None or profile.get('node') is None:
            raise ValueError(f'{source}: enclave {path}: profile without ns or node')
        g = out[path] = Grants()
        for element in profile:
            allowed = {'topics': ('topic', ('publish', 'subscribe')), 'services': ('service', ('reply', 'request'))}
            if element.tag not in allowed:
                raise ValueError(f'{source}: enclave {path}: <{element.tag}> (only topics and services)')
            child, rules = allowed[element.tag]
            if not element.attrib or set(element.attrib) - set(rules) or set(element.attrib.values()) != {'ALLOW'}:
                raise ValueError(f'{source}: enclave {path}: <{element.tag} {element.attrib}>: '
                                 f'{"/".join(rules)}="ALLOW" expected')
            names = [c.text for c in element]
            if [c.tag for c in element] != [child] * len(names) or not names or not all(names):
                raise ValueError(f'{source}: enclave {path}: <{element.tag}> holds other than non-empty <{child}>')
            for rule in element.attrib:
                getattr(g, rule).update(names)
    return out


def write_policy(path: str | Path, operator: bool = True) -> Path:
    path = Path(path).expanduser()
    text = policy_xml(operator)
    read_policy(text)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, text)
    return path


# ---- what a launch file gives a node when the lab sets a keystore (launch_support.py uses it)

def node_security(node: str, keystore: str) -> dict:
    """launch_ros Node keyword arguments that run `node` in its enclave of `keystore`, security
    enforced (`--enclave`, ROS_SECURITY_*); {} without a keystore (security off, as before)."""
    if not keystore:
        return {}
    if node not in NODES:
        raise ValueError(f'{node}: no enclave in the policy (nodes: {", ".join(NODES)})')
    return {'ros_arguments': ['--enclave', enclave_path(node)],
            'additional_env': {'ROS_SECURITY_KEYSTORE': keystore, 'ROS_SECURITY_ENABLE': 'true',
                               'ROS_SECURITY_STRATEGY': 'Enforce'}}


# ---- command line

def configure(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    parser.add_argument('--out', type=Path, metavar='FILE', help='write the policy here (default: print it)')
    parser.add_argument('--no-operator', action='store_true',
                        help=f'leave out the {enclave_path(OPERATOR)} enclave of the operator\'s ros2 commands')
    parser.add_argument('--list-enclaves', action='store_true', help='print the enclave paths, one a line')
    return parser


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the `security-policy` subcommand to an argparse subparsers object; dispatch to run(args)."""
    return subcommand.add(subparsers, 'security-policy', HELP, __doc__, configure, run)


def run(args: argparse.Namespace) -> int:
    operator = not args.no_operator
    try:
        if args.list_enclaves:
            print('\n'.join(enclave_path(n) for n in sorted(table_grants(operator))))
            return 0
        if args.out is None:
            sys.stdout.write(policy_xml(operator))
            return 0
        path = write_policy(args.out, operator)
    except (OSError, ValueError) as exc:
        subcommand.error(PROG, exc)
        return 2
    print(f'wrote {path}: {len(table_grants(operator))} enclaves under {ENCLAVE_ROOT}/')
    return 0


def main(argv: list[str] | None = None) -> int:
    return subcommand.main(PROG, __doc__, configure, run, argv)


if __name__ == '__main__':
    sys.exit(main())
