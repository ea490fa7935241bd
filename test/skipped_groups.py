"""Print, at the end of `make test`, one block naming the groups of tests this machine skipped
for want of a system package or of root, and the one command that runs them; nothing when
every group ran. What each test checks for itself, in one place (the tests' own skip lines
name the same tools).

    python test/skipped_groups.py [ROS_TOOLING]
"""
from __future__ import annotations

import os
from pathlib import Path
import shutil
import sys

ARDUINO_AVR_CORE = Path('/usr/share/arduino/hardware/arduino/avr/cores/arduino/Arduino.h')
BIDS_VALIDATOR = Path(__file__).resolve().parent.parent / '.npm-bids' / 'node_modules' / '.bin' / 'bids-validator'

#: (group, what it needs, missing?) : the Debian packages are make system-deps's.
GROUPS = (
    ("the headset's C# library and its graph tests (make test-hololens, test_hololens_core, test_headset_graph)",
     'mono-mcs, mono-runtime', lambda: not (shutil.which('mcs') and shutil.which('mono'))),
    ("the PLC program's host build: its contract, scan and graph tests "
     "(test_plc_contract, test_plc_safety, test_plc_program_graph)",
     'g++, make', lambda: not (shutil.which('g++') and shutil.which('make'))),
    ("the PLC program's AVR build (test_plc_firmware)", 'gcc-avr, avr-libc, arduino-core-avr',
     lambda: not (shutil.which('avr-g++') and shutil.which('avr-size') and ARDUINO_AVR_CORE.exists())),
    ('mbpoll as a foreign Modbus client (test_plc_contract, test_plc_safety)', 'mbpoll',
     lambda: not shutil.which('mbpoll')),
    ("npm's BIDS validator on the study folder (test_study_bids; make bids-validator installs it)", 'nodejs, npm',
     lambda: not (shutil.which('node') and BIDS_VALIDATOR.exists())),
    ('the loopback socket check (test_bad_input)', 'iproute2', lambda: not shutil.which('ss')),
    ("plc_output's vent on a command stamped in the future (test_plc_stop)", 'faketime',
     lambda: not shutil.which('faketime')),
    ('the graph split over network namespaces (test_netns, test_lab_network)', 'iproute2 and root',
     lambda: not shutil.which('ip') or os.geteuid() != 0),
)


def skipped(tooling: str | None = None) -> list[str]:
    lines = [f'  - {group}: needs {needs}' for group, needs, missing in GROUPS if missing()]
    if tooling is not None and not Path(tooling).is_dir():
        lines.append(f'  - the launch test stage (Kilted and Jazzy launch, colcon build): {tooling} is absent '
                     '(docs/launch.md)')
    return lines


def main(argv: list[str]) -> int:
    lines = skipped(argv[0] if argv else None)
    if not lines:
        return 0
    print('\n' + '=' * 100)
    print('SKIPPED on this machine (the rest of the suite ran):')
    print('\n'.join(lines))
    print('Run them with one command, as root (it installs the packages, then runs the suite):')
    print('    sudo make test')
    print('(SROS2 enforcement never runs from the pip wheels: their Fast DDS has no security libraries.)')
    print('=' * 100)
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
