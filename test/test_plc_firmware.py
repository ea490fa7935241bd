"""The PLC program (firmware/): the core's host unit tests, the host build, and the compile for
the ATmega2560 with Debian's gcc-avr and arduino-core-avr."""
from pathlib import Path
import re
import socket
import struct
import subprocess
import threading
import time

import pytest

from fabric_guidance.plc import RegisterMap
from plc_program import FIRMWARE, PlcProgram, make, need_tools
from rosgraph import CONFIG, wait_until

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


# ------------------------------------------------------------- a client that stalls the scan
#: Watchdog trip -> every output 0 in the state file: one scan plus load slack.
STALL_WATCHDOG_S = 0.5
STALL_VENT_S = STALL_WATCHDOG_S + 0.01 + 0.3
#: How long the stalling peers are kept (longer than the watchdog, so a blocked scan shows).
STALL_S = 3.0
#: How long the flood runs before the heartbeat stops (the host's socket buffers fill by then).
FLOOD_S = 2.0


def _request(sock, tid: int, pdu: bytes, unit: int = 1) -> bytes:
    sock.sendall(struct.pack('>HHHB', tid & 0xFFFF, 0, len(pdu) + 1, unit) + pdu)
    header = b''
    while len(header) < 7:
        header += sock.recv(7 - len(header))
    body = b''
    length = struct.unpack('>H', header[4:6])[0] - 1
    while len(body) < length:
        body += sock.recv(length - len(body))
    return body


def test_a_stalling_client_never_holds_the_scan(tmp_path):
    """One client commands pressure with a live heartbeat; a second one floods read requests and
    never reads an answer (its receive window closes: the program's sends cannot complete), a
    third sends half a request and falls silent (a half-open link). Then the writer's heartbeat
    stops: every output must be 0 within the watchdog, and the host build's longest interval
    between two scans stays far below it. `-s` prints the figure (docs/plc.md, "Timing")."""
    regmap = RegisterMap.load(CONFIG / 'hardware/plc_register_map.yaml')
    n = len(regmap)
    with PlcProgram(tmp_path / 'plc.state.json', regmap, watchdog_s=STALL_WATCHDOG_S) as program:
        writer = socket.create_connection(('127.0.0.1', program.port), timeout=2.0)
        beat = [0]
        stop, beating, lock = threading.Event(), threading.Event(), threading.Lock()

        def heartbeat():
            while not beating.is_set():
                beat[0] += 1
                with lock:
                    try:
                        _request(writer, beat[0], struct.pack('>BHH', 6, n + 1, beat[0] & 0xFFFF))
                    except OSError:   # the program blocked: the heartbeat is lost, as on a link
                        return
                beating.wait(0.05)

        def command():
            with lock:
                _request(writer, 0, struct.pack(f'>BHHB{n + 1}H', 16, 0, n + 1, 2 * (n + 1),
                                                *([2000] * n), next(seq)))
            return program.state()['output_counts'][0] == 2000
        thread = threading.Thread(target=heartbeat, daemon=True)
        thread.start()
        seq = iter(range(1, 10000))
        wait_until(command, 5.0, what='the outputs at 2000 counts')
        stalled = socket.socket()
        stalled.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 2048)
        stalled.connect(('127.0.0.1', program.port))
        stalled.setblocking(False)
        half = socket.create_connection(('127.0.0.1', program.port))
        half.sendall(struct.pack('>HHH', 1, 0, 6)[:5])
        flood = struct.pack('>HHHBBHH', 1, 0, 6, 1, 3, 0, n + 2) * 100

        def stall():   # requests as fast as they are taken, never an answer read
            while not stop.is_set():
                try:
                    stalled.send(flood)
                except BlockingIOError:
                    stop.wait(0.005)
                except OSError:
                    return
        flooding = threading.Thread(target=stall, daemon=True)
        flooding.start()
        time.sleep(FLOOD_S)   # the fault's duration before the heartbeat stops, not a wait for it
        beating.set()
        thread.join(2)
        t0, vent_s = time.monotonic(), None
        try:
            while time.monotonic() < t0 + STALL_S:   # the stall lasts STALL_S whatever happens
                if vent_s is None and not any(program.state()['output_counts']):
                    vent_s = time.monotonic() - t0
                time.sleep(0.01)
        finally:
            stop.set()
            flooding.join(2)
            stalled.close()
            half.close()
            writer.close()
        # Once the stalling peers are gone a program that blocked runs again: the state file
        # then shows how long its scan was held.
        wait_until(lambda: program.state()['scans'] and not any(program.state()['output_counts']), 10.0,
                   what='the program scanning again')
        longest_ms = program.state()['longest_scan_ms']
        serve_us = program.state().get('longest_serve_us')
        closed = program.state()['closed']
    vent = 'never' if vent_s is None else f'{vent_s:.3f} s'
    print(f'\nstalling client: every output 0 {vent} after the heartbeat stopped (deadline '
          f'{STALL_VENT_S:.3f} s, watched {STALL_S:g} s); longest interval between two scans {longest_ms} ms, '
          f'longest pass over the sockets {serve_us} us')
    assert vent_s is not None and vent_s <= STALL_VENT_S, vent
    # Both peers' sockets were reaped by the program itself, not left to the test's close.
    assert closed['stalled'] >= 1 and closed['idle'] >= 1, closed
    # The watchdog must be able to run: no pass may hold it for its whole time (a busy host's
    # scheduler alone can delay a scan by tens of milliseconds; a blocked socket, by seconds).
    assert longest_ms < 1000 * STALL_WATCHDOG_S, longest_ms


def test_sockets_left_by_dead_clients_never_lock_the_next_one_out(tmp_path):
    """Seven connections that never say anything (half-open links after cable pulls: every
    client socket the W5500 has) and then plc_output's: it is served, the longest-silent
    one having been closed to make room."""
    regmap = RegisterMap.load(CONFIG / 'hardware/plc_register_map.yaml')
    with PlcProgram(tmp_path / 'plc.state.json', regmap) as program:
        dead = [socket.create_connection(('127.0.0.1', program.port)) for _ in range(7)]
        try:
            wait_until(lambda: program.state()['scans'] > 5, 5.0, what='the program scanning')
            with socket.create_connection(('127.0.0.1', program.port), timeout=2.0) as live:
                answer = _request(live, 1, struct.pack('>BHH', 3, 0, 1))
            assert answer == struct.pack('>BBH', 3, 2, 0), answer.hex()
            wait_until(lambda: program.state()['closed']['idle'] >= 1, 2.0, what='a dead socket closed')
        finally:
            for s in dead:
                s.close()
