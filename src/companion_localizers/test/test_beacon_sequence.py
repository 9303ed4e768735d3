"""Beacon-sequence plausibility (core/beacon_sequence.py): monotonic IDs, distance travelled."""
import pytest

from companion_localizers.core.beacon_sequence import (
    BeaconSequenceChecker,
    BeaconSequenceConfig,
    Verdict,
)
from vlc_common.core.lamp_map import straight_tunnel_map

LAMPS = straight_tunnel_map()      # lamp_id k at chainage 10·k m, UID 0x1000 | k


def uid(k):
    return 0x1000 | k


def sight(checker, k, train_x, ahead=None, odometer_offset=100.0, var=0.0):
    """A sighting of lamp k from a train at chainage train_x, seen ``ahead`` m ahead (the
    true distance by default); the odometer has its own origin.
    """
    ahead = 10.0 * k - train_x if ahead is None else ahead
    return checker.check(uid(k), train_x + odometer_offset, var, ahead, 1e-4)


def test_first_beacon_is_accepted_unchecked_then_in_sequence_ones_are_consistent():
    c = BeaconSequenceChecker(LAMPS)
    assert sight(c, 4, 34.0).verdict == Verdict.FIRST
    assert sight(c, 4, 36.0).verdict == Verdict.REPEAT          # the anchor still in view
    r = sight(c, 5, 42.0)
    assert r.verdict == Verdict.CONSISTENT and r.accepted and r.index_step == 1
    assert r.offset_m == pytest.approx(0.0, abs=1e-9)
    assert c.anchor_uid == uid(5)


def test_skipped_lamps_are_fine_when_the_distance_matches():
    c = BeaconSequenceChecker(LAMPS)
    sight(c, 4, 34.0)
    r = sight(c, 8, 75.0)                  # lamps 5, 6, 7 dark or unread
    assert r.verdict == Verdict.CONSISTENT and r.index_step == 4


def test_a_lamp_broadcasting_another_lamps_id_is_flagged():
    c = BeaconSequenceChecker(LAMPS)
    sight(c, 4, 34.0)
    # The lamp at 50 m broadcasts lamp 8's UID (80 m): seen 5 m ahead of the train at 45 m.
    r = c.check(uid(8), 145.0, 0.0, 5.0, 1e-4)
    assert r.verdict == Verdict.DISTANCE_MISMATCH and r.flagged
    assert r.offset_m == pytest.approx(30.0)
    assert 'forged or misplaced' in r.reason
    assert c.anchor_uid == uid(4)          # the anchor does not move
    assert sight(c, 6, 55.0).verdict == Verdict.CONSISTENT


def test_a_passed_beacons_id_seen_again_ahead_is_out_of_sequence():
    c = BeaconSequenceChecker(LAMPS)
    sight(c, 4, 34.0)
    sight(c, 5, 44.0)
    # Lamp 5's UID again, 5 m ahead of a train now at 52 m (from a forged lamp at 57 m).
    r = c.check(uid(5), 152.0, 0.0, 5.0, 1e-4)
    assert r.verdict == Verdict.OUT_OF_SEQUENCE and r.flagged and r.index_step == 0
    r = c.check(uid(3), 152.0, 0.0, 5.0, 1e-4)                   # an ID from behind
    assert r.verdict == Verdict.OUT_OF_SEQUENCE and r.index_step == -2


def test_a_beacon_moved_from_its_surveyed_place_is_flagged():
    c = BeaconSequenceChecker(LAMPS)
    sight(c, 4, 34.0)
    r = sight(c, 5, 42.0, ahead=8.0 + 3.0)    # lamp 5 physically 3 m further than mapped
    assert r.verdict == Verdict.DISTANCE_MISMATCH


def test_tolerance_grows_with_the_odometer_uncertainty():
    cfg = BeaconSequenceConfig(gate_sigma=4.0, tolerance_floor_m=0.5)
    c = BeaconSequenceChecker(LAMPS, cfg)
    sight(c, 4, 34.0)
    assert sight(c, 5, 42.0, ahead=8.0 + 1.5).flagged
    c = BeaconSequenceChecker(LAMPS, cfg)
    sight(c, 4, 34.0)
    assert sight(c, 5, 42.0, ahead=8.0 + 1.5, var=0.5 ** 2).accepted


def test_unknown_uid_is_flagged_without_touching_the_anchor():
    c = BeaconSequenceChecker(LAMPS)
    sight(c, 4, 34.0)
    r = c.check(0x2005, 140.0, 0.0, 5.0)
    assert r.verdict == Verdict.UNKNOWN_UID and r.flagged
    assert c.anchor_uid == uid(4)


def test_a_forged_first_beacon_is_found_when_the_next_ones_agree_among_themselves():
    c = BeaconSequenceChecker(LAMPS, BeaconSequenceConfig(reanchor_count=2))
    c.check(uid(9), 134.0, 0.0, 6.0, 1e-4)     # forged: lamp 9's UID seen near 40 m
    assert c.anchor_uid == uid(9)
    r1 = sight(c, 5, 44.0)
    assert r1.flagged
    r2 = sight(c, 6, 54.0)
    assert r2.verdict == Verdict.REANCHORED and r2.accepted and r2.suspect_uid == uid(9)
    assert c.anchor_uid == uid(6)
    assert sight(c, 7, 64.0).verdict == Verdict.CONSISTENT


def test_running_toward_decreasing_chainage():
    c = BeaconSequenceChecker(LAMPS, direction=-1)
    # The odometer increases while the chainage decreases; lamps are ahead at lower x.
    assert c.check(uid(8), 0.0, 0.0, 4.0, 1e-4).verdict == Verdict.FIRST       # at 84 m
    assert c.check(uid(7), 10.0, 0.0, 4.0, 1e-4).verdict == Verdict.CONSISTENT  # at 74 m
    assert c.check(uid(9), 20.0, 0.0, 4.0, 1e-4).flagged


def test_reset_forgets_the_anchor():
    c = BeaconSequenceChecker(LAMPS)
    sight(c, 4, 34.0)
    c.reset()
    assert c.anchor_uid is None
    assert sight(c, 9, 84.0).verdict == Verdict.FIRST


@pytest.mark.parametrize('bad', [dict(gate_sigma=0.0), dict(reanchor_count=0),
                                 dict(tolerance_floor_m=-1.0)])
def test_invalid_configuration_is_refused(bad):
    with pytest.raises(ValueError):
        BeaconSequenceConfig(**bad)
