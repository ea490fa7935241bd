"""The PLC contract's safety half (docs/plc.md), on the PLC program's host build and the Python
MockPlcServer alike: one writer at a time (the write claim, and the vent when its holder is lost),
the vent latch, the clamp at p_max and the watchdog, with the times measured against their
deadlines. The answers on the wire, the sequence gate and mbpoll's answers: test_plc_contract.py;
the servers, the raw client, the heartbeat, the fixtures: plc_contract_support.py.
"""
from __future__ import annotations

import struct
import time

import pytest

from deadlines import DeadlineLog
from plc_contract_support import armed_fixture, raw_fixture, server_fixture  # noqa: F401 (fixtures by name)
from plc_contract_support import (
    arm, echo16, exception, Heartbeat, HEARTBEAT, HOLDING, mbpoll, N, P_MAX, Raw, SEQ, UNIT, VENT,
    WATCHDOG_S, WATCHDOG_VENT_S,
)
from plc_program import need_tools
from rosgraph import wait_until

LOG = DeadlineLog('contract')

report = LOG.report_at_module_end('worst times, PLC contract')


# ------------------------------------------------------------------ one writer at a time
#: A closed connection of the claim holder -> registers 0: one scan, a read round trip, slack.
CLOSE_VENT_S = 0.01 + 0.3


def test_a_second_client_s_writes_are_refused_with_exception_06(server, raw, armed):
    raw.command([500], seq=armed + 1)
    other = Raw(server.port)
    try:
        assert other.command([3000] * N, seq=armed + 1024) == exception(16, 6)
        assert other.write6(HEARTBEAT, 4242) == exception(6, 6)
        assert other.write6(SEQ, armed + 2000) == exception(6, 6)
        assert other.write16(0, [3000]) == exception(16, 6)
        # Reads are anyone's; the map's addresses are checked first (02 before 06).
        assert other.registers(0, 1) + other.registers(SEQ, 2)[:1] == [500, armed + 1]
        assert other.write6(HOLDING, 1) == exception(6, 2)
    finally:
        other.close()
    assert raw.registers(0, 1) + raw.registers(SEQ, 1) == [500, armed + 1]


def test_a_second_writer_that_dies_never_holds_pressure(server, raw, armed):
    """The two-writer fault: the survivor (raw, first to connect) writes zeros with its own
    heartbeat; a second client numbered 1024 ahead writes 200 kPa with its heartbeat and dies.
    Its writes must never have held the registers, whatever its numbers."""
    raw.command([0] * N, seq=armed + 1)
    second = Raw(server.port)
    answers = [second.command([2000] * N, seq=armed + 1024)]
    for k in range(10):
        answers.append(second.write6(HEARTBEAT, 30000 + k))
    second.close()
    for k in range(2, 30):   # the survivor's zeros go on, with its heartbeat
        raw.command([0] * N, seq=armed + k)
        assert raw.registers(0, N) == [0] * N
        time.sleep(0.02)
    assert answers == [exception(16, 6)] + [exception(6, 6)] * 10


@pytest.mark.parametrize('death', ['closed', 'silent'])
def test_the_claim_holder_s_loss_vents_and_frees_the_claim(server, death):
    """The claim holder commands 200 kPa and dies: its connection closed (a process killed) or
    silent and open (a half-open link). The other client's writes (heartbeat included) are
    refused meanwhile, so they cannot keep the watchdog armed; the registers read 0 within one
    scan of the close, or within the watchdog of the silence, and then the other client claims
    and commands, whatever its sequence number."""
    holder, survivor = Raw(server.port), Raw(server.port)
    heartbeat, seq = arm(holder, server.port)
    try:
        holder.command([2000] * N, seq=seq + 5000)
        assert holder.registers(0, 2) == [2000, 2000]
        heartbeat.pause()
        t0 = time.monotonic()
        if death == 'closed':
            holder.close()
        deadline = CLOSE_VENT_S if death == 'closed' else WATCHDOG_VENT_S
        beat = iter(range(100, 10000))

        def vented():   # the survivor keeps trying: heartbeat and zeros, refused until free
            survivor.write6(HEARTBEAT, next(beat))
            return survivor.registers(0, N) == [0] * N
        wait_until(vented, deadline, what=f'registers 0 after the claim holder {death} ({server.kind})')
        LOG.record(f'claim holder {death} -> registers 0 ({server.kind})', time.monotonic() - t0, deadline)
        # Free (at once when closed, within the watchdog when silent): the survivor claims; its
        # first write is taken though its number is far behind the holder's.
        wait_until(lambda: survivor.command([700], seq=seq + 1) == echo16(0, N + 1)
                   and survivor.registers(SEQ, 1) == [seq + 1], WATCHDOG_VENT_S, what='the claim taken')
        survivor_beat = Heartbeat(survivor)
        try:
            wait_until(lambda: survivor.command([700], seq=seq + 2 + next(beat) % 100) and
                       survivor.registers(0, 1) == [700], 2.0, what='the survivor commanding')
        finally:
            survivor_beat.stop()
        if death == 'silent':   # the silent holder is refused now
            assert holder.write6(HEARTBEAT, 1) == exception(6, 6)
    finally:
        heartbeat.stop()
        holder.close()
        survivor.close()


def test_a_half_sent_request_of_the_claim_holder_closes_its_connection(server):
    """A holder that sends part of a request and then nothing (a link gone mid-frame) is closed
    by the PLC after 1 s, as a dead peer, and the registers read 0."""
    holder, other = Raw(server.port), Raw(server.port)
    heartbeat, seq = arm(holder, server.port)
    try:
        holder.command([2000] * N, seq=seq + 1)
        heartbeat.pause()
        holder.sock.sendall(struct.pack('>HHH', 9, 0, 6)[:5])
        t0 = time.monotonic()
        holder.sock.settimeout(3.0)
        assert holder.sock.recv(1) == b'', 'the PLC kept the connection'
        closed_s = time.monotonic() - t0
        assert other.registers(0, N) == [0] * N
        LOG.record(f'half-sent request -> connection closed, registers 0 ({server.kind})', closed_s, 1.0 + 0.3)
        assert 0.9 <= closed_s <= 1.3, closed_s
    finally:
        heartbeat.stop()
        holder.close()
        other.close()


# --------------------------------------------------------------------- the vent latch
#: A vent request -> registers read 0: at once (the request zeroes them), a read round trip and slack.
VENT_REQUEST_S = 0.01 + 0.3


def hold_commands(raw: Raw, seq: int, counts: list[int], duration_s: float, check) -> int:
    """The holder's ordinary writes (commands numbered on, its heartbeat running) for
    duration_s, `check()` after each; returns the last sequence number used."""
    end = time.monotonic() + duration_s
    while time.monotonic() < end:
        seq += 1
        raw.command(counts, seq=seq)
        check()
        time.sleep(0.02)
    return seq


def test_a_vent_request_from_any_client_vents_until_the_holder_re_arms(server, raw, armed):
    raw.command([2000] * N, seq=armed + 1)
    assert raw.registers(0, 2) == [2000, 2000]
    other = Raw(server.port)
    try:
        t0 = time.monotonic()
        assert other.write6(VENT, 1) == struct.pack('>BHH', 6, VENT, 1)   # no claim needed
        wait_until(lambda: other.registers(0, N) == [0] * N, VENT_REQUEST_S,
                   what=f'registers 0 after another client\'s vent request ({server.kind})')
        LOG.record(f'vent request from a second client -> registers 0 ({server.kind})',
                   time.monotonic() - t0, VENT_REQUEST_S)
        assert other.registers(VENT, 1) == [1]

        def still_vented():
            assert other.registers(0, N) == [0] * N and raw.registers(VENT, 1) == [1]
        # The holder's commands and heartbeat go on: they do not lift it.
        seq = hold_commands(raw, armed + 1, [2000] * N, 1.0, still_vented)
        # Only the holder re-arms; 0 or any other value is no re-arm.
        assert other.write6(VENT, 2) == exception(6, 6)
        assert other.write6(VENT, 0) == exception(6, 3)
        assert raw.write6(VENT, 0) == exception(6, 3)
        assert raw.write16(SEQ, [seq + 1, 77, 1234]) == exception(16, 3)
        still_vented()
        # The re-arm starts nothing: the commands stay 0 until the holder's next command.
        assert raw.write6(VENT, 2) == struct.pack('>BHH', 6, VENT, 2)
        assert raw.registers(VENT, 1) == [0]
        assert other.registers(0, N) == [0] * N
        raw.command([700], seq=seq + 1)
        assert raw.registers(0, 1) == [700]
    finally:
        other.close()


def test_a_vent_request_takes_no_claim_and_outlives_the_holder(server):
    requester, holder = Raw(server.port), Raw(server.port)
    try:
        assert requester.write6(VENT, 1) == struct.pack('>BHH', 6, VENT, 1)
        heartbeat = Heartbeat(holder)   # the claim was free: the holder takes it
        try:
            seq = hold_commands(holder, 100, [2000], 0.8,
                                lambda: holder.registers(0, 1) == [0] or pytest.fail('not vented'))
            assert requester.write6(HEARTBEAT, 5) == exception(6, 6)   # holder's claim
        finally:
            heartbeat.stop()
        holder.close()
        assert requester.registers(VENT, 1) == [1]   # a new holder must re-arm explicitly
        assert seq > 100
    finally:
        requester.close()
        holder.close()


def test_any_client_reads_the_claim_holder_s_address(server, raw, armed):
    other = Raw(server.port)
    try:
        port = raw.sock.getsockname()[1]
        assert other.registers(N, 3, fc=4) == [0x7F00, 0x0001, port]
        raw.heartbeat.stop()
        raw.close()
        wait_until(lambda: other.registers(N, 3, fc=4) == [0, 0, 0], CLOSE_VENT_S,
                   what='the claim holder\'s address cleared after its close')
    finally:
        other.close()


def test_mbpoll_vents_a_foreign_writer_that_holds_the_claim(server, raw, armed):
    """A tool (mbpoll, a foot switch on Modbus) stops the suit although another client holds
    the PLC at 200 kPa with a live heartbeat."""
    need_tools('mbpoll')
    raw.command([2000] * N, seq=armed + 1)
    t0 = time.monotonic()
    out = mbpoll(server.port, '-a', str(UNIT), '-t', '4', '-r', str(VENT), values=('1',))
    assert out.startswith('exit 0'), out
    wait_until(lambda: raw.registers(0, N) == [0] * N, VENT_REQUEST_S, what='vented by mbpoll')
    LOG.record(f'mbpoll vent request -> registers 0 ({server.kind})', time.monotonic() - t0,
               VENT_REQUEST_S + 1.0)
    hold_commands(raw, armed + 1, [2000] * N, 0.5,
                  lambda: raw.registers(0, N) == [0] * N or pytest.fail('the writer lifted it'))


# ------------------------------------------------------------------------------- clamp
def test_over_limit_values_are_stored_clamped(server, raw, armed):
    assert raw.command([P_MAX + 1, 0xFFFF, P_MAX], seq=armed + 1) == echo16(0, N + 1)
    assert raw.registers(0, 3) == [P_MAX, P_MAX, P_MAX]


# ---------------------------------------------------------------------------- watchdog
def test_watchdog_starts_vented(server, raw):
    """Commands written before any heartbeat change never stay: the registers are zeroed."""
    raw.command([1000, 1000], seq=1)
    raw.write6(HEARTBEAT, 0)   # written, but not changed: no proof of a live client
    wait_until(lambda: raw.registers(0, N) == [0] * N, 1.0, what='commands zeroed while vented')
    # A second write is zeroed too: the zeroing is not a one-off at power-up.
    raw.command([1000, 1000], seq=2)
    wait_until(lambda: raw.registers(0, 2) == [0, 0], 1.0, what='second write zeroed while vented')


def test_watchdog_holds_while_the_heartbeat_changes_and_trips_when_it_stops(server, raw):
    heartbeat, seq = arm(raw, server.port)
    try:
        raw.command([1000, 2000], seq=seq + 1)
        t_end = time.monotonic() + 2 * WATCHDOG_S
        while time.monotonic() < t_end:   # longer than the watchdog: the heartbeat keeps it armed
            assert raw.registers(0, 2) == [1000, 2000]
            time.sleep(0.05)
    finally:
        heartbeat.stop()
    t0 = time.monotonic()
    wait_until(lambda: raw.registers(0, N) == [0] * N, WATCHDOG_VENT_S,
               what=f'registers zeroed by the watchdog ({server.kind})')
    LOG.record(f'heartbeat stopped -> registers 0 ({server.kind})', time.monotonic() - t0,
               WATCHDOG_VENT_S)
