"""Stereo pairing by stamp: the newest complete pair, everything older dropped and counted."""
import pytest

from vlc_common.core.stereo_pairing import StereoPairing

MS = 1_000_000


def test_a_pair_is_handed_over_once_both_halves_arrived():
    p = StereoPairing()
    assert p.add(0, 33 * MS, 'L1') == [] and p.newest_pair() is None
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


def test_a_short_backlog_is_caught_up_oldest_first_and_a_longer_one_cut_to_it():
    """With two pairs of catch-up, a stall of two frames costs nothing: both pairs are
    handed over, oldest first; a backlog of four keeps its newest two, the two older
    pairs superseded and a lone half between the kept ones unpaired.
    """
    p = StereoPairing()
    for k in (1, 2):
        p.add(0, k * 33 * MS, f'L{k}')
        p.add(1, k * 33 * MS, f'R{k}')
    assert p.complete_pairs(2) == [(33 * MS, 'L1', 'R1'), (66 * MS, 'L2', 'R2')]
    assert (p.stats.superseded, p.stats.unpaired) == (0, 0)
    assert p.complete_pairs(2) == []
    for k in (3, 4, 5, 6):
        p.add(0, k * 33 * MS, f'L{k}')
        p.add(1, k * 33 * MS, f'R{k}')
    p.add(0, 5 * 33 * MS + MS, 'lone')          # between the two kept pairs
    assert p.complete_pairs(2) == [(165 * MS, 'L5', 'R5'), (198 * MS, 'L6', 'R6')]
    assert (p.stats.superseded, p.stats.unpaired) == (4, 1)
    assert p.add(0, 5 * 33 * MS, 'late') == ['out_of_order']


def test_images_taken_together_are_offered_in_stamp_order():
    """A three-frame backlog taken every left first, then every right: offered in stamp
    order, the older rights are not 66 ms behind the newest left (beyond a 50 ms
    jump-back guard, the decoder's) and every pair completes; one by one as given, they
    are held and dropped as outliers.
    """
    backlog = ([(0, k * 33 * MS, f'L{k}') for k in (1, 2, 3)]
               + [(1, k * 33 * MS, f'R{k}') for k in (1, 2, 3)])
    p = StereoPairing(backward_reset_ns=50 * MS)
    assert p.add_many(backlog) == []
    assert [pair[0] for pair in p.complete_pairs(3)] == [33 * MS, 66 * MS, 99 * MS]
    given = StereoPairing(backward_reset_ns=50 * MS)
    for image in backlog:
        given.add(*image)
    given.add(0, 4 * 33 * MS, 'L4')           # the stream goes on: held ones dropped
    assert given.stats.stamp_outliers > 0


def test_catch_up_needs_at_least_one_pair():
    with pytest.raises(ValueError):
        StereoPairing().complete_pairs(0)


def test_old_stamps_are_out_of_order_and_a_sustained_jump_back_restarts():
    """A looped bag: the first images of the new time base are held until three agree,
    then the pairing restarts with them (none lost).
    """
    p = StereoPairing(backward_reset_ns=1000 * MS)
    p.add(0, 2000 * MS, 'L')
    p.add(1, 2000 * MS, 'R')
    assert p.newest_pair()[0] == 2000 * MS
    assert p.add(0, 1500 * MS, 'old') == ['out_of_order'] and p.stats.out_of_order == 1
    assert p.add(0, 10 * MS, 'looped') == [] and p.newest_pair() is None     # held
    assert p.add(1, 10 * MS, 'looped_right') == []
    assert p.add(0, 43 * MS, 'next') == ['reset'] and p.stats.stamp_resets == 1
    assert p.newest_pair() == (10 * MS, 'looped', 'looped_right')
    assert p.stats.stamp_outliers == 0


def test_a_lone_1970_or_future_stamp_is_dropped_and_the_pairing_goes_on():
    """One image pair stamped 1970 (sec 0), one in 1970 (sec 1), one a year ahead, each
    between real frames: every one is dropped as an outlier, nothing resets, and the
    real frames pair as before.
    """
    p = StereoPairing()
    base = 1_704_067_200 * 1000 * MS
    frame = 33 * MS
    for k, bad in enumerate((0, 1000 * MS, base + 365 * 86400 * 1000 * MS)):
        for side in (0, 1):
            assert p.add(side, base + 2 * k * frame, f'{k}{side}') == []
        assert p.newest_pair()[0] == base + 2 * k * frame
        assert p.add(0, bad, 'bad') == [] and p.add(1, bad, 'bad') == []       # held
        events = p.add(0, base + (2 * k + 1) * frame, 'L')
        assert events == ['outlier', 'outlier']
        p.add(1, base + (2 * k + 1) * frame, 'R')
        assert p.newest_pair() == (base + (2 * k + 1) * frame, 'L', 'R')
    assert (p.stats.stamp_outliers, p.stats.stamp_resets, p.stats.out_of_order) == (6, 0, 0)


def test_a_forward_jump_is_confirmed_without_reset():
    """The camera was away for 5 s: its first images after the gap are held, then handed
    on together; nothing is reset.
    """
    p = StereoPairing(forward_jump_ns=1000 * MS, confirm_count=3)
    for side in (0, 1):
        p.add(side, 100 * MS, side)
    p.newest_pair()
    for side, stamp in ((0, 5100), (1, 5100), (0, 5133)):
        p.add(side, stamp * MS, stamp)
    assert p.stats.stamp_resets == 0 and p.stats.stamp_outliers == 0
    assert p.newest_pair() == (5100 * MS, 5100, 5100)


def test_pending_halves_are_bounded():
    p = StereoPairing(max_pending=3)
    for k in range(10):
        p.add(0, k * MS, k)
    assert p.stats.unpaired == 7
    p.add(1, 9 * MS, 'R')
    assert p.newest_pair() == (9 * MS, 9, 'R') and p.stats.unpaired == 9
