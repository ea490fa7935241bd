"""The PLC program (firmware/): the core's host unit tests, the host build, and the compile for
the ATmega2560 with Debian's gcc-avr and arduino-core-avr."""
from pathlib import Path
import re
import subprocess

import pytest

from plc_program import FIRMWARE, make, need_tools

ARDUINO_AVR = Path('/usr/share/arduino/hardware/arduino/avr')


def test_core_unit_tests_pass():
    output = make('unit')
    assert re.search(r'core_tests: \d+ checks, 0 failed', output), output
    print(output.strip().splitlines()[-1])


def test_core_has_no_arduino_header():
    """The portable core builds on the host as it is flashed: no Arduino header in it."""
    for path in (FIRMWARE / 'fabric_plc' / 'src').iterdir():
        includes = re.findall(r'#include\s*[<"]([^>"]+)', path.read_text())
        arduino = ('Arduino.h', 'Ethernet.h', 'SPI.h', 'Client.h')
        assert not [i for i in includes if i in arduino], path


def test_host_build_compiles_and_refuses_bad_options():
    make('build/plc_host')
    binary = FIRMWARE / 'build' / 'plc_host'
    out = subprocess.run([str(binary), '--channels', '40'], capture_output=True, text=True,
                         timeout=10)
    assert out.returncode == 2
    assert out.stderr.strip() == "plc_host: --channels must be an integer 1..32, got '40'"
    out = subprocess.run([str(binary), '--bogus', '1'], capture_output=True, text=True, timeout=10)
    assert out.returncode == 2 and 'unknown option --bogus' in out.stderr


def test_program_compiles_for_the_atmega2560():
    need_tools('avr-g++', 'avr-size')
    if not (ARDUINO_AVR / 'cores' / 'arduino' / 'Arduino.h').exists():
        pytest.skip(f'Arduino AVR core not found at {ARDUINO_AVR} '
                    f'(Debian package arduino-core-avr)')
    output = make('avr')
    full = re.search(r'Program:\s+(\d+) bytes.*?Data:\s+(\d+) bytes', output, re.S)
    if full:   # ETHERNET_DIR given: the whole sketch linked
        print(f'\nATmega2560, the whole sketch: {full[1]} bytes flash, {full[2]} bytes RAM')
        assert int(full[1]) < 256 * 1024 and int(full[2]) < 8 * 1024
        return
    sizes = re.findall(r'^\s*(\d+)\s+(\d+)\s+(\d+)\s+\d+\s+\w+\s+(\S+)$', output, re.M)
    assert {Path(s[3]).name for s in sizes} == {'plc_core.o', 'plc_io.o'}, output
    text = sum(int(s[0]) for s in sizes)
    ram = sum(int(s[1]) + int(s[2]) for s in sizes)
    print(f'\nATmega2560, the program\'s own code (-Os): {text} bytes flash, {ram} bytes '
          f'static RAM (without the Ethernet library and the Arduino core; ETHERNET_DIR '
          f'links the whole sketch)')
    assert text < 256 * 1024
