"""StampGuard: lone stamps from another time base dropped, sustained changes confirmed."""
import pytest

from vlc_common.core.stamp_guard import StampGuard

MS = 1_000_000
S = 1000 * MS
NOW = 1_704_067_200 * S           # 2024-01-01, the rig's epoch
YEAR = 365 * 86400 * S


def _feed(guard, stamps):
    released, dropped, rebased = [], [], []
    for stamp in stamps:
        r = guard.push(stamp, stamp)
        released += [s for s, _ in r.released]
        dropped += [s for s, _ in r.dropped]
        if r.rebased:
            rebased.append(r.rebased)
    return released, dropped, rebased


def _stream(start, n, step=2_500_000):
    return [start + k * step for k in range(n)]


@pytest.mark.parametrize('bad', [0, 1 * S, NOW + YEAR, NOW - 5 * S, NOW + 5 * S],
                         ids=['1970_sec0', '1970_sec1', 'future', '5s_back', '5s_ahead'])
def test_a_lone_outlier_is_dropped_and_counted(bad):
    g = StampGuard(1 * S, 1 * S, confirm_count=3)
    good = _stream(NOW, 10)
    released, dropped, rebased = _feed(g, good[:5] + [bad] + good[5:])
    assert released == good and dropped == [bad] and rebased == []
    assert (g.stats.outliers, g.stats.rebases, g.newest_ns) == (1, 0, good[-1])


def test_outliers_a_little_apart_never_add_up_to_a_new_time_base():
    """1970 sec 0 and sec 1 agree with each other, but each is followed by real stamps."""
    g = StampGuard(1 * S, 1 * S, confirm_count=3)
    stamps = _stream(NOW, 3) + [0] + _stream(NOW + 10 * MS, 3) + [S] + _stream(NOW + 20 * MS, 3)
    released, dropped, rebased = _feed(g, stamps)
    assert dropped == [0, S] and rebased == [] and len(released) == 9


def test_a_sustained_jump_back_is_confirmed_and_nothing_is_lost():
    g = StampGuard(1 * S, 1 * S, confirm_count=3)
    before = _stream(NOW + 60 * S, 4)
    after = _stream(NOW, 5)                    # a looped bag starts again
    released, dropped, rebased = _feed(g, before + after)
    assert released == before + after and dropped == []
    assert rebased == [after[0] - before[-1]] and rebased[0] < 0
    assert (g.stats.rebases, g.stats.rebases_back) == (1, 1)
    # the first two of the new base were held until the third confirmed them
    g2 = StampGuard(1 * S, 1 * S, confirm_count=3)
    _feed(g2, before)
    assert g2.push(after[0]).held and g2.push(after[1]).held
    assert [s for s, _ in g2.push(after[2]).released] == after[:3]


def test_a_forward_jump_is_confirmed_the_same_way():
    g = StampGuard(1 * S, 1 * S, confirm_count=2)
    stamps = _stream(NOW, 3) + _stream(NOW + 10 * S, 3)
    released, dropped, rebased = _feed(g, stamps)
    assert released == stamps and rebased == [10 * S - 2 * 2_500_000]
    assert g.stats.rebases_back == 0


def test_a_broken_run_of_held_stamps_is_dropped_when_another_starts():
    g = StampGuard(1 * S, 1 * S, confirm_count=3)
    _feed(g, _stream(NOW, 3))
    released, dropped, _ = _feed(g, [0, 1 * MS, NOW + YEAR])    # 1970 x2, then the future
    assert released == [] and dropped == [0, 1 * MS] and g.held_count == 1


def test_small_steps_back_and_duplicates_are_inside_the_window():
    """Out-of-order and duplicate stamps are the node's business, not outliers."""
    g = StampGuard(1 * S, 1 * S)
    stamps = [NOW, NOW + 10 * MS, NOW + 10 * MS, NOW + 5 * MS]
    released, dropped, _ = _feed(g, stamps)
    assert released == stamps and dropped == [] and g.newest_ns == NOW + 10 * MS


def test_confirm_count_one_acts_on_every_stamp_and_bad_arguments_are_refused():
    g = StampGuard(1 * S, 1 * S, confirm_count=1)
    released, _, rebased = _feed(g, [NOW, 0, NOW])
    assert released == [NOW, 0, NOW] and len(rebased) == 2
    with pytest.raises(ValueError):
        StampGuard(1 * S, 1 * S, confirm_count=0)
    assert StampGuard.from_seconds(0.05, 1.0).max_backward_ns == 50 * MS


def test_the_floor_keeps_a_lagging_half_inside_the_window():
    """The stereo pairing's case: left images ran 100 ms ahead of the right ones; the
    right image of the last paired frame's successor is late, not an outlier.
    """
    g = StampGuard(50 * MS, 1 * S)
    g.push(NOW)
    g.push(NOW + 100 * MS)                             # a left image, far ahead
    assert g.push(NOW + 33 * MS, floor_ns=NOW).released
    assert g.push(NOW + 40 * MS).held                  # by the newest alone: 60 ms back
    assert g.push(NOW + 110 * MS).released             # (and a real one drops it)
    assert g.push(NOW - 30 * MS, floor_ns=NOW).released
    assert g.push(NOW - 60 * MS, floor_ns=NOW).held
