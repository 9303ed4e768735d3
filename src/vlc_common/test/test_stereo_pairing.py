"""Stereo pairing by stamp: the newest complete pair, everything older dropped and counted."""
from vlc_common.core.stereo_pairing import StereoPairing

MS = 1_000_000


def test_a_pair_is_handed_over_once_both_halves_arrived():
    p = StereoPairing()
    assert p.add(0, 33 * MS, 'L1') is None and p.newest_pair() is None
    p.add(1, 33 * MS, 'R1')
    assert p.newest_pair() == (33 * MS, 'L1', 'R1')
    assert p.newest_pair() is None


def test_a_backlog_collapses_to_the_newest_pair():
    """Three complete pairs and a lone left half waited: only the newest pair is
    processed; the two older pairs are superseded, the half without partner unpaired.
    """
    p = StereoPairing()
    for k in range(1, 4):
        p.add(0, k * 33 * MS, f'L{k}')
        p.add(1, k * 33 * MS, f'R{k}')
    p.add(0, 2 * 33 * MS + MS, 'lone')          # never completed, older than pair 3
    p.add(0, 4 * 33 * MS, 'L4')                 # newer than pair 3: kept for its partner
    assert p.newest_pair() == (99 * MS, 'L3', 'R3')
    assert (p.stats.superseded, p.stats.unpaired) == (4, 1)
    p.add(1, 4 * 33 * MS, 'R4')
    assert p.newest_pair() == (132 * MS, 'L4', 'R4')


def test_old_stamps_are_out_of_order_and_a_large_jump_back_restarts():
    p = StereoPairing(backward_reset_ns=1000 * MS)
    p.add(0, 2000 * MS, 'L')
    p.add(1, 2000 * MS, 'R')
    assert p.newest_pair()[0] == 2000 * MS
    assert p.add(0, 1500 * MS, 'old') == 'out_of_order' and p.stats.out_of_order == 1
    assert p.add(0, 10 * MS, 'looped') == 'reset' and p.stats.stamp_resets == 1
    p.add(1, 10 * MS, 'looped_right')
    assert p.newest_pair() == (10 * MS, 'looped', 'looped_right')


def test_pending_halves_are_bounded():
    p = StereoPairing(max_pending=3)
    for k in range(10):
        p.add(0, k * MS, k)
    assert p.stats.unpaired == 7
    p.add(1, 9 * MS, 'R')
    assert p.newest_pair() == (9 * MS, 9, 'R') and p.stats.unpaired == 9
