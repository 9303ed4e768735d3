"""Lamp identification figures from decoder records against the rig's true spots."""
import numpy as np
import pytest

from vlc_evaluation import identification
from vlc_evaluation.bag_eval import RunData

TRUTH = np.dtype([('uid', '<u4'), ('in_left', '<u4'), ('in_right', '<u4'), ('u_left', '<f8'),
                  ('v_left', '<f8'), ('u_right', '<f8'), ('v_right', '<f8'),
                  ('along_track_m', '<f8')])
LAMPS = np.dtype([('uid', '<u4'), ('state', '<u4'), ('left_u', '<f4'), ('left_v', '<f4'),
                  ('right_u', '<f4'), ('right_v', '<f4')])


def _run(frames):
    """frames: list of (truth rows, lamp rows) per stamp."""
    truth, lamps = {}, {}
    for k, (t_rows, l_rows) in enumerate(frames):
        truth[k] = np.array(t_rows, dtype=TRUTH)
        if l_rows is not None:
            lamps[k] = np.array(l_rows, dtype=LAMPS)
    empty = np.zeros(0)
    return RunData(empty, np.zeros((0, 3)), np.zeros((0, 4)), empty, np.zeros((0, 3)),
                   truth_spots=truth, lamps=lamps)


def test_detection_identification_first_confirmation():
    A, B = 0x1005, 0x1006
    run = _run([
        ([(A, 1, 1, 1000, 100, 980, 100, 9.0)], None),                         # frame lost
        ([(A, 1, 1, 900, 150, 870, 150, 8.0)], [(0, 1, 905, 152, 872, 152)]),  # partial
        ([(A, 1, 1, 800, 200, 760, 200, 7.0)], [(A, 2, 802, 201, 761, 201)]),  # confirmed
        ([(A, 1, 1, 600, 300, 540, 300, 6.0), (B, 0, 0, 1400, 50, 1390, 50, 16.0)],
         [(A, 2, 601, 299, 541, 299)]),
        ([(A, 1, 0, 300, 500, 1300, 500, 5.0)], [(A, 2, 302, 500, float('nan'),
                                                  float('nan'))]),
    ])
    out = identification.identification(run)
    # B never had its centre in an image: not counted
    assert out['first_confirmation_m'] == {str(A): 7.0}
    assert [f[2:] for f in out['frames']] == [[False, False], [True, False], [True, True],
                                               [True, True], [True, True]]
    assert out['wrong_uids'] == 0 and out['anomalies'] == 0


def test_wrong_uid_and_anomaly_are_counted():
    A, B = 0x1005, 0x1006
    run = _run([
        ([(A, 1, 1, 800, 200, 760, 200, 7.0)], [(B, 2, 801, 200, 761, 200)]),   # wrong UID
        ([(A, 1, 1, 700, 250, 650, 250, 6.5)], [(A, 2, 100, 600, 60, 600)]),   # on no lamp
        ([(A, 1, 1, 600, 300, 540, 300, 6.0)], [(0x1FFF, 3, 601, 300, 541, 300)]),
    ])
    out = identification.identification(run)
    assert out['wrong_uids'] == 2 and out['wrong_uid_list'] == [A, B]
    assert out['anomalies'] == 1
    assert out['first_confirmation_m'] == {str(A): None}


def test_success_by_distance_bins():
    frames = [[1, 0.5, True, True], [1, 0.7, True, False], [1, 9.5, False, False]]
    bins = identification.success_by_distance(frames)
    assert len(bins) == 10
    assert bins[0]['frames'] == 2 and bins[0]['identified'] == pytest.approx(0.5)
    assert bins[0]['detected'] == 1.0
    assert bins[9]['frames'] == 1 and bins[9]['detected'] == 0.0
    assert bins[5]['frames'] == 0 and bins[5]['identified'] is None


def test_spot_cut_by_the_border_belongs_to_its_lamp():
    """A lamp 0.35 m ahead: its true centre lies 60 px below the image, the decoder's
    spot (bounding box rows 714-719) is what is left of it inside.
    """
    box = np.dtype([('uid', '<u4'), ('state', '<u4'), ('left_u', '<f4'), ('left_v', '<f4'),
                    ('right_u', '<f4'), ('right_v', '<f4'), ('left_u_min', '<f4'),
                    ('left_v_min', '<f4'), ('left_u_max', '<f4'), ('left_v_max', '<f4'),
                    ('right_u_min', '<f4'), ('right_v_min', '<f4'), ('right_u_max', '<f4'),
                    ('right_v_max', '<f4')])
    nan = float('nan')
    A, B = 0x1002, 0x1003
    truth = np.array([(A, 0, 0, -5.1, 781.9, -72.6, 781.9, 0.35),
                      (B, 1, 1, 1246.2, 17.4, 1232.6, 17.4, 10.86)], dtype=TRUTH)
    recs = np.array([(A, 2, 42.3, 712.0, nan, nan, 18, 714, 64, 719, nan, nan, nan, nan)],
                    dtype=box)
    empty = np.zeros(0)
    run = RunData(empty, np.zeros((0, 3)), np.zeros((0, 4)), empty, np.zeros((0, 3)),
                  truth_spots={0: truth}, lamps={0: recs})
    out = identification.identification(run)
    assert out['wrong_uids'] == 0
    # B is in view but not detected; A's centre is outside both images: not counted
    assert out['frames'] == [[B, 10.86, False, False]]


def test_a_lamp_glimpsed_only_far_away_is_not_passed():
    frames = [[0x1005, 8.0, True, False], [0x1005, 6.0, True, True], [0x1005, 1.5, True, True],
              [0x1006, 11.6, True, False], [0x1006, 9.7, True, False]]   # the run ends
    first = {str(0x1005): 6.0, str(0x1006): None}
    assert identification.passed_lamps(frames, first) == (1, 1)
    # the same lamp reached within 5 m and never identified is a passed, missed lamp
    frames.append([0x1006, 4.0, True, False])
    assert identification.passed_lamps(frames, first) == (2, 1)
