"""Left/right matching on the rectified epipolar constraint."""
from spot_locator.core.matching import MatchConfig, SpotSummary, match_spots


def _spot(u, v, rows=(100, 130), area=200.0):
    return SpotSummary(u=u, v=v, row_min=rows[0], row_max=rows[1], area_px=area)


def test_two_lamps_are_paired_one_to_one():
    left = [_spot(900.0, 115.0), _spot(300.0, 600.0, rows=(560, 640), area=3000.0)]
    right = [_spot(250.0, 600.0, rows=(560, 640), area=2900.0), _spot(885.0, 115.0)]
    pairs, ul, ur = match_spots(left, right)
    assert sorted(pairs) == [(0, 1), (1, 0)]
    assert ul == [] and ur == []


def test_a_spot_with_no_partner_is_rejected():
    left = [_spot(900.0, 115.0), _spot(500.0, 400.0, rows=(390, 410))]
    right = [_spot(885.0, 115.0)]
    pairs, ul, ur = match_spots(left, right)
    assert pairs == [(0, 0)] and ul == [1] and ur == []


def test_gates_reject_wrong_sign_wrong_rows_wrong_size_and_out_of_range():
    left = [_spot(900.0, 115.0)]
    cfg = MatchConfig(max_row_diff_px=3.0, min_disparity_px=2.0, max_disparity_px=400.0,
                      max_area_ratio=2.0)
    for right in ([_spot(905.0, 115.0)],                      # negative disparity
                  [_spot(890.0, 125.0, rows=(110, 140))],     # rows 10 px off
                  [_spot(890.0, 115.0, area=500.0)],          # 2.5x the area
                  [_spot(899.0, 115.0)],                      # 1 px: beyond the range
                  [_spot(400.0, 115.0)]):                     # 500 px: closer than 0.3 m
        pairs, ul, ur = match_spots(left, right, cfg)
        assert pairs == [] and ul == [0] and ur == [0]


def test_ambiguity_is_resolved_by_rows():
    """Two right candidates at admissible disparities: the one on the same rows wins."""
    left = [_spot(900.0, 115.0, rows=(100, 130))]
    right = [_spot(880.0, 117.0, rows=(102, 132)), _spot(885.0, 115.0, rows=(100, 130))]
    pairs, _, ur = match_spots(left, right)
    assert pairs == [(0, 1)] and ur == [0]


def test_empty_sides():
    assert match_spots([], [_spot(1.0, 1.0)]) == ([], [], [0])
    assert match_spots([_spot(1.0, 1.0)], []) == ([], [0], [])
