"""Joining vlc_decoder lamp records with spot_locator pairs of the same stamp."""
import math

import numpy as np

from spot_locator.conversions import PAIR_DTYPE
from train_localizer.core.join import FrameJoiner, JoinConfig, join_frame
from vlc_decoder.conversions import LAMP_DTYPE


def spots(*uvs):
    rec = np.zeros(len(uvs), dtype=PAIR_DTYPE)
    for i, (u, v) in enumerate(uvs):
        rec[i]['u_left'], rec[i]['v_left'] = u, v
        rec[i]['u_right'], rec[i]['v_right'] = u - 30.0, v
        rec[i]['stamp_offset_s'] = v * 30e-6 + 25e-6
        rec[i]['sigma_u_left'] = rec[i]['sigma_v_left'] = 0.05
        rec[i]['sigma_u_right'] = rec[i]['sigma_v_right'] = 0.07
        rec[i]['sigma_disparity'] = 0.09
    return rec


def lamps(*rows):
    rec = np.zeros(len(rows), dtype=LAMP_DTYPE)
    for i, (uid, state, u, v) in enumerate(rows):
        rec[i]['uid'], rec[i]['state'] = uid, state
        rec[i]['left_u'], rec[i]['left_v'] = u, v
    return rec


def test_records_join_the_nearest_spot_and_keep_the_spot_locators_values():
    obs, unmatched = join_frame(10, spots((500.0, 200.0), (900.0, 100.0)),
                                lamps((4098, 2, 901.0, 99.0), (4097, 1, 499.0, 201.5)))
    assert unmatched == 0
    assert [o.uid for o in obs] == [None, 4098]        # state 1 (partial): unconfirmed
    assert obs[1].uv_left.tolist() == [900.0, 100.0]
    assert obs[1].sigma_u_px == np.float32(0.05)
    assert math.isclose(obs[1].sigma_v_px, math.sqrt(0.5 * (0.05 ** 2 + 0.07 ** 2)), rel_tol=1e-6)
    assert math.isclose(obs[1].sigma_disparity_px, 0.09, rel_tol=1e-6)
    assert math.isclose(obs[1].exposure_mid_offset_s, 100 * 30e-6 + 25e-6, rel_tol=1e-6)


def test_anomaly_uid_is_passed_on_far_records_stay_unmatched():
    obs, unmatched = join_frame(10, spots((500.0, 200.0)),
                                lamps((0x7ABC, 3, 501.0, 200.0), (4097, 2, 700.0, 200.0)),
                                JoinConfig(match_radius_px=12.0))
    assert obs[0].uid == 0x7ABC and unmatched == 1


def test_a_spot_cut_by_the_border_joins_within_its_box_a_small_one_only_close():
    # the lamp 0.5 m ahead (rig, out/eval static_00.5m): the decoder centres the visible
    # part of a spot cut by the bottom border, the spot locator the fitted ellipse
    cut = lamps((4101, 2, 149.5, 681.0))
    cut[0]['left_u_min'], cut[0]['left_u_max'] = 91.0, 198.0
    cut[0]['left_v_min'], cut[0]['left_v_max'] = 652.0, 719.0
    obs, unmatched = join_frame(10, spots((146.1, 700.0)), cut)
    assert unmatched == 0 and obs[0].uid == 4101
    small = lamps((4101, 2, 149.5, 681.0))
    small[0]['left_u_min'], small[0]['left_u_max'] = 145.0, 154.0
    small[0]['left_v_min'], small[0]['left_v_max'] = 677.0, 685.0
    obs, unmatched = join_frame(10, spots((146.1, 700.0)), small)
    assert unmatched == 1 and obs[0].uid is None


def test_frames_wait_for_both_halves_and_are_released_when_the_decoder_moves_on():
    j = FrameJoiner(JoinConfig(timeout_s=10.0))
    assert j.add_spots(100, spots((500.0, 200.0)), 0.0) == []
    ready = j.add_lamps(100, lamps((4097, 2, 500.0, 200.0)), 0.01)
    assert [(s, [o.uid for o in obs]) for s, obs in ready] == [(100, [4097])]
    # Lamps first, then spots: joined as well.
    assert j.add_lamps(200, lamps((4097, 2, 500.0, 200.0)), 0.02) == []
    assert j.add_spots(200, spots((500.0, 200.0)), 0.03)[0][1][0].uid == 4097
    # The decoder skipped stamp 300: its spots go on without UIDs once lamps of 400 come.
    assert j.add_spots(300, spots((500.0, 200.0)), 0.04) == []
    ready = j.add_lamps(400, lamps((4097, 2, 500.0, 200.0)), 0.05)
    assert [(s, obs[0].uid) for s, obs in ready] == [(300, None)]
    assert j.stats.spots_without_lamps == 1


def test_timeout_releases_spots_and_drops_orphan_lamp_records():
    j = FrameJoiner(JoinConfig(timeout_s=0.1))
    j.add_spots(100, spots((500.0, 200.0)), 0.0)
    j.add_lamps(50, lamps((4097, 2, 500.0, 200.0)), 0.0)
    assert j.flush(0.05) == []
    ready = j.flush(0.2)
    assert [s for s, _ in ready] == [100]
    assert j.stats.lamps_without_spots == 1
