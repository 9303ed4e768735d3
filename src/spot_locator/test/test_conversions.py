"""Messages ↔ arrays: images of every accepted encoding, bad images, the pair cloud."""
import pathlib

import numpy as np
import pytest
from sensor_msgs.msg import CameraInfo, PointField
from std_msgs.msg import Header
import yaml

from spot_locator import conversions
from spot_locator.core.locator import SpotPair, StereoGeometry
from spot_locator.spot_locator_node import NODE_PARAMETERS


def _info(p03, width=1280, height=720):
    return CameraInfo(width=width, height=height,
                      p=[1040.0, 0.0, 639.5, p03, 0.0, 1040.0, 359.5, 0.0, 0.0, 0.0, 1.0, 0.0])


def test_stereo_geometry_from_camera_info():
    g = conversions.stereo_geometry(_info(0.0), _info(-1040.0 * 0.12))
    assert g == StereoGeometry(fx=1040.0, fy=1040.0, cx=639.5, cy=359.5, baseline_m=0.12,
                               width=1280, height=720)
    with pytest.raises(ValueError, match='baseline'):
        conversions.stereo_geometry(_info(0.0), _info(0.0))
    with pytest.raises(ValueError, match='sizes'):
        conversions.stereo_geometry(_info(0.0), _info(-124.8, width=640))
    bad = _info(-124.8)
    bad.p[2] = 600.0
    with pytest.raises(ValueError, match='rectified'):
        conversions.stereo_geometry(_info(0.0), bad)


def test_stereo_geometry_refuses_zero_and_nan_projections():
    """The fault injector's camera_info kinds: all-zero P, NaN in P (the node keeps the
    last good pair before it gets here: vlc_common.camera_info).
    """
    zero = _info(0.0)
    zero.p = [0.0] * 12
    with pytest.raises(ValueError, match='focal length'):
        conversions.stereo_geometry(zero, zero)
    for index in (2, 3):                   # cx, and the right camera's -fx*b
        nan = _info(-124.8)
        nan.p[index] = float('nan')
        with pytest.raises(ValueError):
            conversions.stereo_geometry(_info(0.0), nan)


@pytest.mark.parametrize('fields', [
    dict(encoding='rgb8', step=64), dict(encoding='bayer_rggb8'), dict(encoding='nonsense'),
    dict(width=72, step=72), dict(height=47), dict(step=63), dict(data=bytes(64 * 24)),
    dict(width=0, height=0, step=0, data=b''),
], ids=['rgb8_mono_data', 'bayer_rggb8', 'nonsense', 'width_mismatch', 'height_mismatch',
        'step_too_small', 'truncated', 'empty'])
def test_malformed_images_raise_value_error(fields):
    from sensor_msgs.msg import Image
    msg = Image(width=64, height=48, encoding='mono8', step=64, data=bytes(64 * 48))
    for name, value in fields.items():
        setattr(msg, name, value)
    with pytest.raises(ValueError):
        conversions.image_to_array(msg)


def test_pair_cloud_round_trip_with_named_fields():
    pair = SpotPair(uv_left=np.array([700.25, 300.5]), uv_right=np.array([680.0, 300.5]),
                    sigma_left=np.array([0.01, 0.05]), sigma_right=np.array([0.02, 0.05]),
                    disparity=20.25, sigma_disparity=0.022, row_min=280, row_max=321,
                    stamp_offset_s=0.009, circularity_left=0.71, circularity_right=0.7,
                    offset_left=np.array([-0.05, 0.01]), offset_right=np.array([-0.06, 0.01]),
                    blur_px=0.2, flags=43)
    header = Header(frame_id='camera_left_optical_frame')
    header.stamp.sec, header.stamp.nanosec = 1704067200, 33_333_333
    cloud = conversions.records_to_cloud(conversions.pairs_to_records([pair, pair]), header)
    assert cloud.header == header and cloud.width == 2 and cloud.point_step == 112
    types = {f.name: f.datatype for f in cloud.fields}
    assert types['u_left'] == PointField.FLOAT64 and types['row_min'] == PointField.UINT32
    assert types['sigma_u_left'] == PointField.FLOAT32
    rec = conversions.cloud_to_records(cloud)
    assert rec['u_left'][1] == 700.25 and rec['disparity'][0] == 20.25
    assert rec['row_min'][0] == 280 and rec['row_max'][0] == 321 and rec['flags'][0] == 43
    assert rec['stamp_offset_s'][0] == 0.009
    assert rec['sigma_u_right'][0] == pytest.approx(0.02)
    assert rec['ecc_du_left'][0] == pytest.approx(-0.05)
    empty = conversions.records_to_cloud(conversions.pairs_to_records([]), header)
    assert empty.width == 0 and len(conversions.cloud_to_records(empty)) == 0


def test_config_file_documents_every_parameter_with_its_default():
    path = pathlib.Path(__file__).resolve().parents[1] / 'config' / 'spot_locator_node.yaml'
    values = yaml.safe_load(path.read_text())['/**']['ros__parameters']
    assert values == {name: default for name, default, _ in NODE_PARAMETERS}


def _raw_info(K, D, R, P):
    return CameraInfo(width=1280, height=720, distortion_model='plumb_bob',
                      d=[float(x) for x in D], k=[float(x) for x in np.ravel(K)],
                      r=[float(x) for x in np.ravel(R)], p=[float(x) for x in np.ravel(P)])


def test_stereo_geometry_of_raw_images_maps_centres_to_the_rectified_image():
    """A point seen through a known plumb_bob lens, K, R and P (distorted with OpenCV's
    projectPoints, not the project's model) comes back on its rectified projection
    within 0.02 px, corners of the sensor included; ideal camera_info (D = 0, R = I,
    P[:, :3] = K, or only P) keeps the rectified path.
    """
    import cv2
    K = np.array([[1040.0, 0.0, 643.2], [0.0, 1041.5, 356.1], [0.0, 0.0, 1.0]])
    D = np.array([-0.30, 0.10, 0.0008, -0.0005, -0.015])
    R = cv2.Rodrigues(np.radians([0.05, -0.12, 0.03]))[0]
    P = np.array([[1010.0, 0.0, 640.0, 0.0], [0.0, 1010.0, 360.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
    Pr = P.copy()
    Pr[0, 3] = -1010.0 * 0.12
    g = conversions.stereo_geometry(_raw_info(K, D, R, P), _raw_info(K, D, R, Pr))
    assert g.raw_cameras is not None and (g.fx, g.cx, g.baseline_m) == (1010.0, 640.0,
                                                                         pytest.approx(0.12))
    left, _ = g.camera_models()
    # rays of the unrectified optical frame over the raw sensor, corners 20 px in
    uv = np.array([[u, v] for u in (20.0, 330.0, 640.0, 950.0, 1260.0)
                   for v in (20.0, 190.0, 360.0, 530.0, 700.0)])
    rays = cv2.undistortPoints(uv.reshape(-1, 1, 2), K, D,
                               criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS,
                                         200, 1e-12)).reshape(-1, 2)
    X = np.column_stack([rays, np.ones(len(rays))]) * 4.0
    raw = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, D)[0].reshape(-1, 2)
    rect_truth = (X @ R.T) @ P[:, :3].T
    rect_truth = rect_truth[:, :2] / rect_truth[:, 2:3]
    assert np.abs(raw - uv).max() < 1e-3                 # the rays do reach those pixels
    assert np.abs(rect_truth - raw).max() > 20.0          # the lens matters there
    np.testing.assert_allclose(left.rectify_points(raw), rect_truth, atol=0.02)
    ideal = conversions.stereo_geometry(
        _raw_info(P[:, :3], np.zeros(5), np.eye(3), P), _raw_info(P[:, :3], np.zeros(5),
                                                                    np.eye(3), Pr))
    assert ideal.raw_cameras is None and ideal.camera_models() is None
    with pytest.raises(ValueError, match='R'):
        conversions.stereo_geometry(_raw_info(K, D, 2.0 * R, P), _raw_info(K, D, R, Pr))
