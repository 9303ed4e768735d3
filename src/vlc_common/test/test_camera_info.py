"""camera_info checked before use; the last good one kept, a stray one never taken."""
import math

import pytest
from sensor_msgs.msg import CameraInfo

from vlc_common.camera_info import CameraInfoKeeper, camera_info_problem
from vlc_common.core.camera import StereoRig


def _infos():
    out = []
    for info in StereoRig().camera_info_dicts():
        out.append(CameraInfo(width=info['width'], height=info['height'],
                              k=[float(v) for v in info['K'].ravel()],
                              r=[float(v) for v in info['R'].ravel()],
                              p=[float(v) for v in info['P'].ravel()],
                              d=[float(v) for v in info['D']],
                              distortion_model=info['distortion_model']))
    return out


def _spoiled(msg, **fields):
    bad = CameraInfo(width=msg.width, height=msg.height, k=list(msg.k), r=list(msg.r),
                     p=list(msg.p), d=list(msg.d), distortion_model=msg.distortion_model)
    for name, value in fields.items():
        setattr(bad, name, value)
    return bad


def test_the_rigs_camera_info_is_valid():
    assert [camera_info_problem(m) for m in _infos()] == [None, None]


@pytest.mark.parametrize('fields, reason', [
    (dict(k=[0.0] * 9, p=[0.0] * 12), 'K has no positive focal length'),   # all-zero K/P
    (dict(p=[0.0] * 12), 'P has no positive focal length'),
    (dict(width=0, height=0), 'zero size'),
    (dict(d=[math.nan] * 5), 'D not finite'),
    (dict(k=[math.inf] + [0.0] * 8), 'K not finite'),
], ids=['zero_k_p', 'zero_p', 'zero_size', 'nan_d', 'inf_k'])
def test_invalid_camera_info_is_named(fields, reason):
    assert reason in camera_info_problem(_spoiled(_infos()[0], **fields))


def test_nan_in_p_is_invalid():
    left = _infos()[0]
    p = list(left.p)
    p[2] = math.nan
    assert camera_info_problem(_spoiled(left, p=p)) == 'P not finite'


def test_a_bad_camera_info_never_replaces_the_good_one():
    """The fault injector's camera_info kinds, each between the camera's own messages."""
    left, right = _infos()
    keeper = CameraInfoKeeper(confirm_count=3)
    assert keeper.update(0, left)[0] == keeper.KEPT and keeper.both() is None
    assert keeper.update(1, right)[0] == keeper.KEPT
    p = list(left.p)
    p[2] = math.nan
    for bad in (_spoiled(left, k=[0.0] * 9, p=[0.0] * 12), _spoiled(left, p=p)):
        outcome, reason = keeper.update(0, bad)
        assert outcome == keeper.REFUSED and reason
        assert keeper.current[0] is left
        assert keeper.update(0, left)[0] == keeper.SAME
    half = _spoiled(left, width=left.width // 2, height=left.height // 2)
    outcome, reason = keeper.update(0, half)
    assert outcome == keeper.PENDING and '1 of 3' in reason
    assert keeper.current[0] is left                      # a stray size is not taken
    assert keeper.update(0, left)[0] == keeper.SAME
    assert (keeper.refused, keeper.ignored) == (2, 1)
    assert keeper.both() == (left, right)


def test_a_changed_camera_info_is_taken_once_it_is_sent_repeatedly():
    left, _ = _infos()
    keeper = CameraInfoKeeper(confirm_count=3)
    keeper.update(0, left)
    new = _spoiled(left, width=640, height=360)
    assert [keeper.update(0, new)[0] for _ in range(3)] == [keeper.PENDING, keeper.PENDING,
                                                           keeper.KEPT]
    assert keeper.current[0] is new
    with pytest.raises(ValueError):
        CameraInfoKeeper(confirm_count=0)


def test_raw_camera_model_tells_raw_from_rectified_images():
    """The rig's ideal pair (D = 0, R = I, P[:, :3] = K), an all-zero R and an empty D
    are rectified images; a lens (D ≠ 0) or a rectification (R ≠ I) make them raw.
    """
    from vlc_common.camera_info import raw_camera_model
    left, right = _infos()
    assert raw_camera_model(left) is None and raw_camera_model(right) is None
    assert raw_camera_model(_spoiled(left, r=[0.0] * 9, d=[])) is None
    lens = _spoiled(left, d=[-0.3, 0.1, 0.0, 0.0, 0.0])
    model = raw_camera_model(lens)
    assert model is not None and model.D[0] == -0.3
    # the principal point is not moved by the lens; a corner is
    assert model.rectify_points([[639.5, 359.5]])[0] == pytest.approx([639.5, 359.5])
    assert abs(model.rectify_points([[20.0, 20.0]])[0, 0] - 20.0) > 10.0
    turned = _spoiled(left, r=[1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 1.0, 0.0])
    assert raw_camera_model(turned) is not None
    with pytest.raises(ValueError, match='R'):
        raw_camera_model(_spoiled(left, r=[2.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 2.0]))


def test_a_new_lens_calibration_alone_is_a_change():
    """D (or R) alone differing from the kept message is a different calibration: taken
    after the confirmations like another K or P, not passed as the same.
    """
    keeper = CameraInfoKeeper()
    left = _infos()[0]
    assert keeper.update(0, left)[0] == CameraInfoKeeper.KEPT
    lens = _spoiled(left, d=[-0.3, 0.1, 0.0, 0.0, 0.0])
    assert keeper.update(0, lens)[0] == CameraInfoKeeper.PENDING
    assert keeper.update(0, lens)[0] == CameraInfoKeeper.PENDING
    assert keeper.update(0, lens)[0] == CameraInfoKeeper.KEPT
    assert list(keeper.current[0].d) == [-0.3, 0.1, 0.0, 0.0, 0.0]
