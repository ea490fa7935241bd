"""Write sequence numbers (plc/sequence.py): newer modulo 2**16, the PLC-side gate, resync."""
from hypothesis import given
from hypothesis import strategies as st

from fabric_guidance.plc.sequence import HALF_RING, RESYNC_JUMP, SEQ_MODULUS, SequenceGate, is_newer, resync

seqs = st.integers(0, SEQ_MODULUS - 1)


def test_newer_is_up_to_half_the_ring_ahead_and_wraps():
    assert is_newer(1, 0) and is_newer(0, SEQ_MODULUS - 1) and is_newer(HALF_RING - 1, 0)
    assert not is_newer(0, 0) and not is_newer(0, 1) and not is_newer(HALF_RING, 0)


@given(seqs, seqs)
def test_of_two_different_numbers_at_most_one_is_newer(a, b):
    assert not (is_newer(a, b) and is_newer(b, a))
    assert is_newer(a, b) or is_newer(b, a) or a == b or (a - b) % SEQ_MODULUS == HALF_RING


def test_gate_accepts_the_first_then_only_newer_and_counts_rejections():
    gate = SequenceGate()
    assert gate.accept(500) and gate.accept(501) and gate.accept(600)
    assert not gate.accept(600) and not gate.accept(599) and not gate.accept(1)
    assert gate.rejected == 3 and gate.last == 600
    gate.reset()                       # PLC power-up
    assert gate.accept(3) and gate.rejected == 3


@given(seqs, st.integers(0, 50))
def test_a_resynced_client_stays_ahead_of_every_write_still_in_flight(plc_last, in_flight):
    """Writes in flight were numbered after the PLC's last applied one, at most a few of them:
    whatever the client's own counter, its next write is newer than all of them."""
    gate = SequenceGate()
    gate.accept(plc_last)
    for own in (None, plc_last, (plc_last + in_flight) % SEQ_MODULUS):
        nxt = (resync(own, plc_last) + 1) % SEQ_MODULUS
        for k in range(1, in_flight + 1):
            assert is_newer(nxt, (plc_last + k) % SEQ_MODULUS)
    assert RESYNC_JUMP > 50
