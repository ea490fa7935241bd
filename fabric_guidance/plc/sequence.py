"""Write sequence numbers: an old command that arrives late never overwrites a newer one.

Why: plc_output drops a connection whose request timed out and writes the next command on a
fresh one. A request that was only slow (a congested switch, a retransmission) can still
reach the PLC on the dead connection after a newer command arrived on the new one, and would
overwrite it; after a shutdown vent it would pressurise the suit again until the watchdog
trips. TCP orders bytes within one connection, never across two.

So every command write carries a 16-bit sequence number in the register right after the
command block (one write-multiple-registers request: the PLC sees both or neither). The PLC
(and the mock) applies a write only if its number is newer than the last applied one, modulo
2**16: up to half the ring ahead is newer. The client keeps its counter across reconnects,
and when it (re)connects it reads the PLC's last applied number and jumps RESYNC_JUMP ahead
of it, so that a restarted plc_output is not taken for a stale one and writes still in flight
from before (at most one per dead connection: the client has one request out at a time) stay
behind. Plain Python, no pymodbus, no ROS.
"""
from __future__ import annotations

SEQ_MODULUS = 1 << 16
HALF_RING = SEQ_MODULUS // 2
#: How far ahead of the PLC's last applied number a (re)connected client starts. Far more
#: than the writes that can be in flight on dead connections, far less than half the ring.
RESYNC_JUMP = 1024


def is_newer(seq: int, last: int) -> bool:
    """True when `seq` is ahead of `last` by 1 .. HALF_RING - 1 (modulo 2**16)."""
    return 0 < (seq - last) % SEQ_MODULUS < HALF_RING


def resync(own: int | None, plc_last: int) -> int:
    """The client's last-used number after reading the PLC's last applied one on connect:
    RESYNC_JUMP past the PLC's, unless the client's own counter is newer still."""
    candidate = (plc_last + RESYNC_JUMP) % SEQ_MODULUS
    if own is None or is_newer(candidate, own):
        return candidate
    return own


class SequenceGate:
    """The PLC side: accepts a write's sequence number only if it is newer than the last one
    accepted. The first write after power-up is always accepted."""

    def __init__(self):
        self.rejected = 0
        self.reset()

    def reset(self) -> None:
        """PLC power-up: no reference; the rejection count is kept."""
        self.last: int | None = None

    def accept(self, seq: int) -> bool:
        if self.last is not None and not is_newer(seq, self.last):
            self.rejected += 1
            return False
        self.last = seq % SEQ_MODULUS
        return True
