"""The gaze stream's sequence numbers: SequenceTracker's gaps, stale and late samples, restarts and
the wrap at 2**32 (the datagram format itself is in test_gaze_wire.py)."""
from hypothesis import given, strategies as st
import pytest

from fabric_guidance.core.gaze_wire import SeqStatus, SequenceTracker


def feed(tracker, seqs):
    return [tracker.update(s) for s in seqs]


def test_consecutive_samples():
    t = SequenceTracker()
    assert t.loss_rate == 0.0
    assert feed(t, range(10)) == [SeqStatus.NEW] * 10
    assert (t.received, t.lost, t.stale, t.restarts, t.loss_rate) == (10, 0, 0, 0, 0.0)


def test_gap_counts_lost_samples():
    t = SequenceTracker()
    assert feed(t, [0, 1, 5, 6]) == [SeqStatus.NEW, SeqStatus.NEW, SeqStatus.GAP, SeqStatus.NEW]
    assert (t.received, t.lost, t.stale) == (4, 3, 0)
    assert t.loss_rate == pytest.approx(3 / 7)
    assert t.last_gap == 0
    t.update(10)
    assert t.last_gap == 3 and t.lost == 6


def test_duplicates_and_reordering_are_stale():
    t = SequenceTracker()
    assert feed(t, [0, 1, 1, 3, 2, 0, 4]) == [SeqStatus.NEW, SeqStatus.NEW, SeqStatus.STALE, SeqStatus.GAP,
                                              SeqStatus.STALE, SeqStatus.STALE, SeqStatus.NEW]
    # 2 arrived late: it was counted lost when 3 came and stays lost.
    assert (t.received, t.lost, t.stale) == (4, 1, 3)
    assert t.loss_rate == pytest.approx(1 / 5)
    assert not SeqStatus.STALE.accepted and SeqStatus.GAP.accepted and SeqStatus.RESTART.accepted


def test_wrap_around():
    top = 2 ** 32 - 1
    t = SequenceTracker()
    assert feed(t, [top - 1, top, 0, 1]) == [SeqStatus.NEW] * 4
    assert t.lost == 0
    t = SequenceTracker()
    assert feed(t, [top - 1, 2]) == [SeqStatus.NEW, SeqStatus.GAP]
    assert t.lost == 3                         # top, 0, 1
    assert t.update(top) is SeqStatus.STALE    # 3 behind, across the wrap
    assert t.update(0) is SeqStatus.STALE
    assert (t.received, t.lost, t.stale) == (2, 3, 2)


def test_restart_threshold_boundary():
    t = SequenceTracker(restart_threshold=1000)
    feed(t, [2000])
    assert t.update(1000) is SeqStatus.STALE    # exactly 1000 behind: still a late sample
    assert t.update(999) is SeqStatus.RESTART   # 1001 behind: the sender restarted
    assert t.update(1000) is SeqStatus.NEW
    assert (t.received, t.lost, t.stale, t.restarts) == (3, 0, 1, 1)


def test_restart_from_zero_and_across_the_wrap():
    t = SequenceTracker()
    feed(t, [5000, 5001])
    assert feed(t, [0, 1, 2]) == [SeqStatus.RESTART, SeqStatus.NEW, SeqStatus.NEW]
    assert (t.received, t.lost, t.restarts) == (5, 0, 1)
    t = SequenceTracker(restart_threshold=10)
    feed(t, [3])
    assert t.update(2 ** 32 - 20) is SeqStatus.RESTART   # 23 behind across the wrap


def test_half_ring_decides_forward_or_backward():
    t = SequenceTracker()
    feed(t, [0])
    assert t.update(2 ** 31 - 1) is SeqStatus.GAP and t.lost == 2 ** 31 - 2
    t = SequenceTracker()
    feed(t, [0])
    assert t.update(2 ** 31) is SeqStatus.RESTART


def test_reset_and_argument_checks():
    t = SequenceTracker()
    feed(t, [0, 3, 3])
    t.reset()
    assert (t.received, t.lost, t.stale, t.last_seq, t.loss_rate) == (0, 0, 0, None, 0.0)
    assert t.update(77) is SeqStatus.NEW
    for bad in (-1, 2 ** 32):
        with pytest.raises(ValueError):
            t.update(bad)
    for bad in (0, 2 ** 31):
        with pytest.raises(ValueError):
            SequenceTracker(restart_threshold=bad)


@given(start=st.integers(0, 2 ** 32 - 1), steps=st.lists(st.integers(1, 50), max_size=60))
def test_forward_stream_accounts_for_every_seq(start, steps):
    """In-order delivery with drops: received + lost spans exactly first..last (mod 2**32)."""
    t = SequenceTracker()
    seq = start
    t.update(seq)
    for step in steps:
        seq = (seq + step) % 2 ** 32
        assert t.update(seq).accepted
    assert t.received == len(steps) + 1 and t.stale == 0
    assert t.received + t.lost == sum(steps) + 1
    assert t.lost == sum(s - 1 for s in steps)
