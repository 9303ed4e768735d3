"""Message conversions of stereo_camera_node: CameraInfo, Image, truth PointCloud2, stamps."""
import numpy as np
import pytest

from vlc_common.core.camera import CameraIntrinsics
from vlc_stereo_camera import conversions
from vlc_stereo_camera.core.renderer import LampTruth, RendererConfig


def test_camera_info_consistent_with_intrinsics():
    cfg = RendererConfig(intrinsics=CameraIntrinsics(fx=1040.0, fy=1041.0, cx=639.5, cy=359.5),
                         baseline_m=0.12)
    infos = cfg.rig().camera_info_dicts()
    hdr = conversions.header(conversions.stamp_ns(1704067200.0, 0.1), 'cam')
    left, right = (conversions.camera_info_msg(i, hdr) for i in infos)
    for msg in (left, right):
        assert (msg.width, msg.height) == (1280, 720)
        np.testing.assert_array_equal(np.reshape(msg.k, (3, 3)),
                                      [[1040.0, 0, 639.5], [0, 1041.0, 359.5], [0, 0, 1]])
        np.testing.assert_array_equal(np.reshape(msg.r, (3, 3)), np.eye(3))
        np.testing.assert_array_equal(np.reshape(msg.p, (3, 4))[:, :3], np.reshape(msg.k, (3, 3)))
        assert msg.distortion_model == 'plumb_bob' and not any(msg.d)
        assert msg.header.stamp == hdr.stamp
    assert left.p[3] == 0.0
    assert right.p[3] == pytest.approx(-1040.0 * 0.12)
    # image_geometry's baseline: −P[0,3]/P[0,0].
    assert -right.p[3] / right.p[0] == pytest.approx(0.12)


def test_stamps_are_exact_integer_nanoseconds():
    epoch = 1704067200.0
    assert conversions.stamp_ns(epoch) == 1704067200 * 10 ** 9
    for k in (1, 29, 30, 10 ** 6 + 7):
        assert conversions.stamp_ns(epoch, k / 30.0) == 1704067200 * 10 ** 9 + round(k * 1e9 / 30)
    t = conversions.ns_to_stamp(1704067200 * 10 ** 9 + 33_333_333)
    assert (t.sec, t.nanosec) == (1704067200, 33_333_333)


def test_image_round_trip_and_bad_input():
    img = np.arange(720 * 1280, dtype=np.uint32).reshape(720, 1280).astype(np.uint8)
    msg = conversions.image_msg(img, conversions.header(0, 'camera_left_optical_frame'))
    assert (msg.encoding, msg.step, msg.height, msg.width) == ('mono8', 1280, 720, 1280)
    np.testing.assert_array_equal(conversions.image_to_array(msg), img)
    with pytest.raises(ValueError):
        conversions.image_msg(img.astype(np.float32), msg.header)
    msg.encoding = 'rgb8'
    with pytest.raises(ValueError, match='mono8'):
        conversions.image_to_array(msg)
    msg.encoding = 'mono8'
    msg.height = 721                        # truncated data
    with pytest.raises(ValueError):
        conversions.image_to_array(msg)


def test_truth_cloud_round_trip():
    truth = [LampTruth(uid=4097, uv_left=np.array([649.5, 427.6]),
                       uv_right=np.array([608.2, 427.6]), depth_m=3.0166, range_m=3.0232,
                       along_track_m=2.0, viewing_angle_deg=55.8, t_centre_s=1.0129,
                       rows_left=(395, 460), rows_right=(396, 461), in_left=True,
                       in_right=True),
             LampTruth(uid=4098, uv_left=np.array([1290.0, 58.0]),
                       uv_right=np.array([1275.0, 58.0]), depth_m=8.4, range_m=10.3,
                       along_track_m=10.0, viewing_angle_deg=80.0, t_centre_s=1.0018,
                       rows_left=None, rows_right=(45, 70), in_left=False, in_right=True)]
    records = conversions.truth_records(truth, t0_s=1.0)
    msg = conversions.records_to_cloud(records, conversions.header(5, 'camera_left_optical_frame'))
    assert msg.point_step == 96 and msg.width == 2 and msg.height == 1
    assert {f.name for f in msg.fields} >= {'uid', 'u_left', 'v_left', 'u_right', 'v_right',
                                             'depth_m', 'along_track_m'}
    back = conversions.cloud_to_records(msg)
    assert back['uid'].tolist() == [4097, 4098]
    assert back['in_left'].tolist() == [1, 0]
    assert (back['row_first'].tolist(), back['row_last'].tolist()) == ([395, 45], [461, 70])
    np.testing.assert_allclose(back['u_left'], [649.5, 1290.0])
    np.testing.assert_allclose(back['t_offset_s'], [0.0129, 0.0018], atol=1e-12)
    np.testing.assert_allclose(back['depth_m'], [3.0166, 8.4])
    empty = conversions.records_to_cloud(conversions.truth_records([], 0.0), msg.header)
    assert empty.width == 0 and len(conversions.cloud_to_records(empty)) == 0
