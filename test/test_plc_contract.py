"""The PLC contract (docs/plc.md), one suite for every server that claims it: the PLC program's
host build (firmware/) and the Python MockPlcServer. Raw Modbus TCP frames, so the exact bytes
are checked, plus mbpoll (libmodbus) as a foreign client comparing the two.

Everything here is observable on the wire, so the same assertions hold for both servers. This
file: the answers (normal and exception frames, unit id, segments), the sequence gate and
mbpoll's answers; test_plc_safety.py: the write claim, the vent latch, the clamp and the
watchdog; plc_contract_support.py: the servers, the raw client, the heartbeat, the fixtures.
"""
from __future__ import annotations

import re
import struct
import time

import pytest

from plc_contract_support import armed_fixture, raw_fixture, server_fixture  # noqa: F401 (fixtures by name)
from plc_contract_support import (
    arm, echo16, exception, HOLDING, INPUT, mbpoll, N, Raw, SEQ, Server, SILENCE_S, UNIT,
)
from plc_program import need_tools


# ------------------------------------------------------------------------------ answers
def test_in_map_reads_and_writes_answer_normally(server, raw, armed):
    assert raw.command([100, 200, 300], seq=armed + 1) == echo16(0, N + 1)
    assert raw.registers(0, N + 1) == [100, 200, 300] + [0] * (N - 3) + [armed + 1]
    assert len(raw.registers(0, HOLDING)) == HOLDING   # the whole map in one read
    assert len(raw.registers(0, INPUT, fc=4)) == INPUT   # measured pressures, the claim holder


OUT_OF_MAP = {
    'FC3 one past the vent register': (struct.pack('>BHH', 3, HOLDING, 1), 3),
    'FC3 block running past the map': (struct.pack('>BHH', 3, 0, HOLDING + 1), 3),
    'FC3 old heartbeat address 100': (struct.pack('>BHH', 3, 100, 1), 3),
    'FC4 past the claim holder': (struct.pack('>BHH', 4, INPUT, 1), 4),
    'FC6 past the vent register': (struct.pack('>BHH', 6, HOLDING, 1), 6),
    'FC6 old heartbeat address 100': (struct.pack('>BHH', 6, 100, 1), 6),
    'FC16 running past the map': (struct.pack('>BHHB3H', 16, N + 1, 3, 6, 1, 2, 1), 16),
    'FC3 at 65535': (struct.pack('>BHH', 3, 0xFFFF, 2), 3),
}


@pytest.mark.parametrize('case', list(OUT_OF_MAP))
def test_out_of_map_answers_exception_02(server, raw, case):
    pdu, fc = OUT_OF_MAP[case]
    assert raw.ask(pdu) == exception(fc, 2)
    assert raw.registers(0, HOLDING) == [0] * HOLDING   # nothing written


@pytest.mark.parametrize('fc', [1, 2, 5, 15, 23, 43, 100])
def test_unknown_function_answers_exception_01(server, raw, fc):
    assert raw.ask(struct.pack('>BHH', fc, 0, 1)) == exception(fc, 1)


BAD_QUANTITY = {
    'FC3 quantity 0': (struct.pack('>BHH', 3, 0, 0), 3),
    'FC3 quantity 126': (struct.pack('>BHH', 3, 0, 126), 3),
    'FC4 quantity 0': (struct.pack('>BHH', 4, 0, 0), 4),
    'FC4 quantity 126': (struct.pack('>BHH', 4, 0, 126), 4),
    # 124 registers cannot fit in a Modbus frame (PDU <= 253 bytes): the header claims them.
    'FC16 quantity 124': (struct.pack('>BHHB2H', 16, 0, 124, 248, 0, 0), 16),
    'FC16 quantity 0': (struct.pack('>BHHB', 16, 0, 0, 0), 16),
    'FC16 byte count != 2 * quantity': (struct.pack('>BHHB2H', 16, 0, 2, 3, 1, 2), 16),
}


@pytest.mark.parametrize('case', list(BAD_QUANTITY))
def test_bad_quantity_answers_exception_03(server, raw, case):
    pdu, fc = BAD_QUANTITY[case]
    assert raw.ask(pdu) == exception(fc, 3)


def test_exception_frame_bytes(server, raw):
    """MBAP echoed (transaction id, protocol 0, length 3, unit id), function | 0x80, code."""
    adu = raw.ask_adu(struct.pack('>BHH', 3, 100, 1))
    assert adu == struct.pack('>HHHBBB', raw.tid, 0, 3, UNIT, 0x83, 2)


def test_another_unit_id_gets_no_answer_and_the_connection_stays_open(server, raw):
    assert raw.ask(struct.pack('>BHH', 3, 0, 1), unit=UNIT + 1, timeout_s=SILENCE_S) is None
    assert raw.ask(struct.pack('>BHH', 6, 0, 1), unit=UNIT + 1, timeout_s=SILENCE_S) is None
    # The same connection still works for the right unit id (a late answer to the requests
    # above would show up here as a wrong transaction id).
    assert raw.registers(0, 1) == [0]


def test_a_request_split_over_two_segments_is_answered(server, raw):
    """TCP is a byte stream: a request may arrive in pieces."""
    frame = struct.pack('>HHHBBHH', 7, 0, 6, UNIT, 3, 0, 2)
    raw.sock.sendall(frame[:5])
    time.sleep(0.05)   # the first part alone on the wire
    raw.sock.sendall(frame[5:])
    answer = raw._exactly(7 + 6)
    assert answer[:2] == b'\x00\x07' and answer[7:9] == b'\x03\x04', answer.hex()


def test_the_program_answers_two_requests_sent_back_to_back(tmp_path):
    """Not in the contract (plc_output has one request out at a time; pymodbus 3.9.2's server
    answers only the first of two requests in one segment), but the program does."""
    server = Server('program', tmp_path)
    try:
        raw = Raw(server.port)
        raw.sock.sendall(struct.pack('>HHHBBHH', 7, 0, 6, UNIT, 3, 0, 2)
                         + struct.pack('>HHHBBHH', 8, 0, 6, UNIT, 4, 0, 1))
        answers = raw._exactly(7 + 6) + raw._exactly(7 + 4)
        raw.close()
    finally:
        server.stop()
    assert answers[:2] == b'\x00\x07' and answers[7:9] == b'\x03\x04', answers.hex()
    assert answers[13:15] == b'\x00\x08' and answers[20:22] == b'\x04\x02', answers.hex()


# ----------------------------------------------------------------------- sequence gate
def test_stale_write_is_answered_normally_and_undone(server, raw, armed):
    s = armed + 1000
    assert raw.command([500, 600], seq=s) == echo16(0, N + 1)
    assert raw.command([3000, 3000], seq=s - 1) == echo16(0, N + 1)      # older
    assert raw.command([3000, 3000], seq=s) == echo16(0, N + 1)          # the same number again
    assert raw.command([3000, 3000], seq=s + 0x8000) == echo16(0, N + 1)  # half the ring: stale
    assert raw.registers(0, 2) + raw.registers(SEQ, 1) == [500, 600, s]
    assert raw.command([700], seq=s + 0x7FFF) == echo16(0, N + 1)        # farthest still newer
    assert raw.registers(0, 1) == [700]


def test_sequence_numbers_wrap_modulo_65536(server, raw, armed):
    for seq in (armed + 30000, armed + 60000, 65535):   # up the ring in steps under half of it
        raw.command([100], seq=seq)
    raw.command([200], seq=0)
    assert raw.registers(0, 1) + raw.registers(SEQ, 1) == [200, 0]
    raw.command([300], seq=65535)
    assert raw.registers(0, 1) + raw.registers(SEQ, 1) == [200, 0]


def test_unsequenced_command_writes_are_answered_normally_and_undone(server, raw, armed):
    raw.command([500, 600], seq=armed + 10)
    assert raw.write6(1, 3000) == struct.pack('>BHH', 6, 1, 3000)
    assert raw.write16(0, [3000, 3000, 3000]) == echo16(0, 3)
    assert raw.registers(0, 3) + raw.registers(SEQ, 1) == [500, 600, 0, armed + 10]


def test_sequence_register_alone_moves_the_gate_and_heartbeat_is_always_accepted(
        server, raw, armed):
    raw.command([500], seq=armed + 10)
    assert raw.write6(SEQ, armed + 20) == struct.pack('>BHH', 6, SEQ, armed + 20)
    assert raw.registers(0, 1) + raw.registers(SEQ, 1) == [500, armed + 20]
    raw.command([900], seq=armed + 15)    # behind the moved gate
    raw.write6(SEQ, armed + 5)            # stale on its own
    assert raw.registers(0, 1) + raw.registers(SEQ, 1) == [500, armed + 20]
    # A stale command write that also carries the heartbeat: the heartbeat is taken (the
    # heartbeat thread paused, so 4242 can only come from this write).
    raw.heartbeat.pause()
    raw.write16(0, [900] * N + [armed + 3, 4242])
    assert raw.registers(0, 1) + raw.registers(SEQ, 2) == [500, armed + 20, 4242]


def test_first_write_after_power_up_is_accepted_whatever_its_number(server, raw):
    # The sequence register shows it (the commands themselves are zeroed while the watchdog
    # has not been armed yet).
    assert raw.command([123], seq=40000) == echo16(0, N + 1)
    assert raw.registers(SEQ, 1) == [40000]
    raw.command([123], seq=40000 - 1)
    assert raw.registers(SEQ, 1) == [40000]


# --------------------------------------------------------------------------- mbpoll
def mbpoll_session(port: int) -> dict[str, str]:
    """In-map, out-of-map and stale requests from mbpoll, after a known command (raw), with a
    live heartbeat (else the watchdog zeroes the commands). Not the input registers: the two
    servers simulate the regulators differently."""
    raw = Raw(port)
    heartbeat, _seq = arm(raw, port)
    try:
        raw.command([1111, 2222], seq=1000)
        assert raw.registers(0, 2) + raw.registers(SEQ, 1) == [1111, 2222, 1000]
        values = tuple(str(v) for v in [3333] * N + [999])  # a whole command write, older number
        unit = ('-a', str(UNIT))
        return {
            'in-map read': mbpoll(port, *unit, '-t', '4', '-r', '0', '-c', str(N + 1)),
            'out-of-map read': mbpoll(port, *unit, '-t', '4', '-r', str(HOLDING), '-c', '1'),
            'out-of-map write': mbpoll(port, *unit, '-t', '4', '-r', '100', values=('5',)),
            'unknown function (coils)': mbpoll(port, *unit, '-t', '0', '-r', '0', '-c', '1'),
            # raw holds the write claim: a second client's write is refused, whatever its number.
            'write from a second client': mbpoll(port, *unit, '-t', '4', '-r', '0', values=values),
            'read after the refused write': mbpoll(port, *unit, '-t', '4', '-r', '0', '-c', '2'),
        }
    finally:
        heartbeat.stop()
        raw.close()


EXPECTED_MBPOLL = {
    'in-map read': rf'^exit 0\n.*\[0\]:\s+1111\n\[1\]:\s+2222\n.*\[{N}\]:\s+1000$',
    'out-of-map read': r'^exit 1\n.*Illegal data address',
    'out-of-map write': r'^exit 1\n.*Illegal data address',
    'unknown function (coils)': r'^exit 1\n.*Illegal function',
    'write from a second client': r'^exit 1\n.*busy',
    'read after the refused write': r'^exit 0\n.*\[0\]:\s+1111\n\[1\]:\s+2222',
}


def test_mbpoll_gets_the_contract_answers(server):
    need_tools('mbpoll')
    session = mbpoll_session(server.port)
    for probe, pattern in EXPECTED_MBPOLL.items():
        assert re.search(pattern, session[probe], re.S), f'{probe}:\n{session[probe]}'


def test_mbpoll_gets_the_same_answers_from_the_mock_and_the_program(tmp_path):
    need_tools('mbpoll')
    sessions = {}
    for kind in ('program', 'mock'):
        s = Server(kind, tmp_path)
        try:
            sessions[kind] = mbpoll_session(s.port)
        finally:
            s.stop()
    for probe in sessions['program']:
        assert sessions['mock'][probe] == sessions['program'][probe], probe
