"""`fabric-guidance dds-profile`: a Fast DDS profile that keeps DDS on one network interface of
the lab PC (docs/lab_network.md).

A lab PC has several interfaces (the lab LAN, the HoloLens Wi-Fi, the PLC's field network) and
by default Fast DDS discovers and sends on all of them. The profile written here gives every
participant of the process one UDPv4 transport allowed on the named interface alone (a device
name such as `enp3s0`, or its IPv4 address) and nothing else: no shared-memory transport, no
other interface. Discovery stays Fast DDS's simple discovery (multicast on that interface), or
a discovery server when ROS_DISCOVERY_SERVER is set (fabric_guidance/lab/discovery_server.py).

    fabric-guidance dds-profile --interface enp3s0 --out ~/lab/fastdds_lab.xml
    export FASTDDS_DEFAULT_PROFILES_FILE=~/lab/fastdds_lab.xml   # Kilted (Jazzy: FASTRTPS_DEFAULT_PROFILES_FILE)
    export ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT

(FASTRTPS_... is the name Fast DDS 2.x reads, on ROS 2 Jazzy; FASTDDS_... Fast DDS 3's, on Kilted.)

An allowlist that matches no interface of the PC fails closed: Fast DDS logs "All whitelist
interfaces were filtered out" and the process hears and reaches nobody (the suit vents on stale
commands). No rclpy here: the tests and the CLI write and check profiles without ROS.
"""
from __future__ import annotations

import argparse
import os
import ipaddress
from pathlib import Path
import socket
import sys
import xml.etree.ElementTree as ET

from .. import subcommand
from ..atomic import write_text

PROG = 'fabric-guidance dds-profile'
HELP = 'write (or check) a Fast DDS profile that keeps DDS on one network interface of the lab PC'

NS = 'http://www.eprosima.com'
TRANSPORT_ID = 'fabric_guidance_lab_udp'
PROFILE_NAME = 'fabric_guidance_lab'
#: What a process needs besides the profile: rmw's LOCALHOST and OFF ranges replace the
#: transports with their own (rmw_fastrtps participant.cpp), SYSTEM_DEFAULT leaves the profile alone.
DISCOVERY_RANGE = 'SYSTEM_DEFAULT'

# '/', ':' and whitespace Linux refuses in a device name; quotes, '<', '>' and '&' would break the XML.
_FORBIDDEN_IN_NAME = set('/:"\'<>&') | set(' \t\n\r\f\v')


def check_interface(interface: str) -> str:
    """The interface as the profile names it: an IPv4 address, or a Linux device name.
    ValueError (one line, naming the value) for anything Fast DDS's UDPv4 allowlist cannot match."""
    text = str(interface).strip()
    try:
        address = ipaddress.ip_address(text)
    except ValueError:
        address = None
    if address is not None:
        if address.version != 4:
            raise ValueError(f'interface {text!r}: an IPv6 address; the profile pins the UDPv4 transport, '
                             'give the IPv4 address or the device name')
        if address.is_multicast or address.is_unspecified:
            raise ValueError(f'interface {text!r}: not the address of an interface (multicast or 0.0.0.0)')
        return text
    # Linux device names: at most 15 bytes (IFNAMSIZ 16 with the NUL), no '/', ':' or whitespace.
    if not text or len(text.encode()) > 15 or _FORBIDDEN_IN_NAME & set(text) or text in ('.', '..'):
        raise ValueError(f'interface {interface!r}: neither an IPv4 address nor a network device name '
                         '(1-15 characters, no "/", ":", quotes, "<", ">", "&" or spaces)')
    return text


def interface_profile(interface: str) -> str:
    """The profile's XML text for `interface` (checked first)."""
    interface = check_interface(interface)
    return f'''<?xml version="1.0" encoding="UTF-8"?>
<!-- Written by fabric-guidance dds-profile: DDS on interface {interface} only
     (docs/lab_network.md). Load it with
     FASTDDS_DEFAULT_PROFILES_FILE=<this file> (Fast DDS 3, Kilted) or FASTRTPS_DEFAULT_PROFILES_FILE=<this file>
     (Fast DDS 2.14, Jazzy) and ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT.
     One UDPv4 transport allowed on that interface; no shared memory (it would cross network
     namespaces on one machine, and the test of this profile relies on there being none). -->
<dds xmlns="{NS}">
  <profiles>
    <transport_descriptors>
      <transport_descriptor>
        <transport_id>{TRANSPORT_ID}</transport_id>
        <type>UDPv4</type>
        <interfaces>
          <allowlist>
            <interface name="{interface}"/>
          </allowlist>
        </interfaces>
      </transport_descriptor>
    </transport_descriptors>
    <participant profile_name="{PROFILE_NAME}" is_default_profile="true">
      <rtps>
        <userTransports>
          <transport_id>{TRANSPORT_ID}</transport_id>
        </userTransports>
        <useBuiltinTransports>false</useBuiltinTransports>
        <!-- No XTypes type lookup service (Fast DDS 3.2's can crash a node at discovery:
             config/fastdds_loopback.xml says why); Fast DDS 2.14 has none and ignores this. -->
        <propertiesPolicy>
          <properties>
            <property>
              <name>fastdds.type_propagation</name>
              <value>disabled</value>
            </property>
          </properties>
        </propertiesPolicy>
      </rtps>
    </participant>
  </profiles>
</dds>
'''


def _q(tag: str) -> str:
    return f'{{{NS}}}{tag}'


def validate_profile(text: str, source: str = 'profile') -> str:
    """The interface a profile pins DDS to; ValueError `<source>: <field> <reason>` when it
    does not pin every participant to exactly one interface."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise ValueError(f'{source}: not XML ({exc})') from None
    if root.tag != _q('dds'):
        raise ValueError(f'{source}: root element {root.tag!r} is not <dds xmlns="{NS}">')
    descriptors = root.findall(f'{_q("profiles")}/{_q("transport_descriptors")}/{_q("transport_descriptor")}')
    if len(descriptors) != 1:
        raise ValueError(f'{source}: transport_descriptor: {len(descriptors)} found, one expected')
    d = descriptors[0]
    transport_id = (d.findtext(_q('transport_id')) or '').strip()
    if (d.findtext(_q('type')) or '').strip() != 'UDPv4':
        raise ValueError(f'{source}: transport_descriptor/type is not UDPv4')
    if d.find(_q('interfaceWhiteList')) is not None or d.find(f'{_q("interfaces")}/{_q("blocklist")}') is not None:
        raise ValueError(f'{source}: transport_descriptor: interfaceWhiteList or blocklist present; '
                         'the allowlist alone decides')
    allowed = d.findall(f'{_q("interfaces")}/{_q("allowlist")}/{_q("interface")}')
    if len(allowed) != 1:
        raise ValueError(f'{source}: interfaces/allowlist: {len(allowed)} interfaces, exactly one expected')
    interface = check_interface(allowed[0].get('name', ''))
    defaults = [p for p in root.findall(f'{_q("profiles")}/{_q("participant")}')
                if p.get('is_default_profile') == 'true']
    if len(defaults) != 1:
        raise ValueError(f'{source}: participant: {len(defaults)} with is_default_profile="true", one expected '
                         '(the profile every participant of the process takes)')
    rtps = defaults[0].find(_q('rtps'))
    used = [(e.text or '').strip() for e in (rtps.findall(f'{_q("userTransports")}/{_q("transport_id")}')
                                             if rtps is not None else [])]
    if used != [transport_id]:
        raise ValueError(f'{source}: participant/rtps/userTransports: {used}, expected [{transport_id!r}]')
    if (rtps.findtext(_q('useBuiltinTransports')) or '').strip() != 'false':
        raise ValueError(f'{source}: participant/rtps/useBuiltinTransports is not false '
                         '(the built-in transports use every interface and shared memory)')
    return interface


def write_profile(path: str | Path, interface: str) -> Path:
    """Write the profile for `interface` to `path` atomically (a reader sees the old or the new)."""
    text = interface_profile(interface)
    validate_profile(text)
    path = Path(path).expanduser()
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_text(path, text)


#: The variables that name the profiles file: Fast DDS 3 (ROS 2 Kilted) reads the first, Fast DDS
#: 2.x (ROS 2 Jazzy, Fast DDS 2.14) only the second.
PROFILE_VARIABLES = ('FASTDDS_DEFAULT_PROFILES_FILE', 'FASTRTPS_DEFAULT_PROFILES_FILE')
#: ROS 2 distributions whose rmw_fastrtps runs Fast DDS 2.x.
FAST_DDS_2_DISTROS = ('humble', 'iron', 'jazzy')


def profile_variable(distro: str | None = None) -> str:
    """The variable the running distribution's Fast DDS reads: ROS_DISTRO (a workspace's
    setup.bash sets it) names it; without it, the stand-alone Kilted wheels: Fast DDS 3. One
    only: Fast DDS 3 also takes the old name, prefers it when both are set, and warns about it
    in every process."""
    distro = (os.environ.get('ROS_DISTRO', '') if distro is None else distro).strip().lower()
    return PROFILE_VARIABLES[1] if distro in FAST_DDS_2_DISTROS else PROFILE_VARIABLES[0]


def profile_env(profile: str | Path, distro: str | None = None) -> dict[str, str]:
    """The running distribution's profile variable (profile_variable) set to `profile`."""
    return {profile_variable(distro): str(Path(profile).expanduser())}


def process_env(profile: str | Path) -> dict[str, str]:
    """The environment a process needs to take the profile, the profile alone deciding."""
    return {**profile_env(profile), 'ROS_AUTOMATIC_DISCOVERY_RANGE': DISCOVERY_RANGE}


def local_interface_names() -> set[str]:
    return {name for _, name in socket.if_nameindex()}


# ---- command line

def configure(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    what = parser.add_mutually_exclusive_group(required=True)
    what.add_argument('--interface', metavar='NAME|ADDRESS',
                      help='the lab network interface: its device name (enp3s0) or its IPv4 address')
    what.add_argument('--check', type=Path, metavar='FILE', help='check a profile and print the interface it pins')
    parser.add_argument('--out', type=Path, metavar='FILE', help='where to write the profile (with --interface)')
    return parser


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the `dds-profile` subcommand to an argparse subparsers object; dispatch to run(args)."""
    return subcommand.add(subparsers, 'dds-profile', HELP, __doc__, configure, run)


def run(args: argparse.Namespace) -> int:
    """Write the profile and print the environment that loads it, or check one. 2 on bad input."""
    try:
        if args.check is not None:
            interface = validate_profile(args.check.read_text(), source=str(args.check))
            print(f'{args.check}: DDS pinned to interface {interface}')
            return 0
        if args.out is None:
            raise ValueError('--out FILE is required with --interface')
        path = write_profile(args.out, args.interface)
    except (OSError, ValueError) as exc:
        subcommand.error(PROG, exc)
        return 2
    interface = check_interface(args.interface)
    print(f'wrote {path}: DDS on interface {interface} only')
    if not _is_address(interface) and interface not in local_interface_names():
        # Not an error: the profile may be written for another PC. Here it would fail closed.
        print(f'note: this machine has no interface named {interface}', file=sys.stderr)
    print('load it in every ROS process of the lab graph with:')
    for key, value in process_env(path).items():
        print(f'  export {key}={value}')
    return 0


def _is_address(interface: str) -> bool:
    try:
        ipaddress.ip_address(interface)
        return True
    except ValueError:
        return False


def main(argv: list[str] | None = None) -> int:
    return subcommand.main(PROG, __doc__, configure, run, argv)


if __name__ == '__main__':
    sys.exit(main())
