"""Messages ↔ arrays: images of every accepted encoding, bad images, the pair cloud."""
import pathlib

import numpy as np
import pytest
from sensor_msgs.msg import CameraInfo, Image, PointField
from std_msgs.msg import Header
import yaml

from spot_locator import conversions
from spot_locator.core.locator import SpotPair, StereoGeometry
from spot_locator.spot_locator_node import NODE_PARAMETERS


def _image(arr, encoding, step=None, bigendian=False):
    arr = np.ascontiguousarray(arr)
    h, w = arr.shape[:2]
    row = arr.reshape(h, -1).view(np.uint8)
    step = row.shape[1] if step is None else step
    buf = np.zeros((h, step), np.uint8)
    buf[:, :row.shape[1]] = row
    return Image(height=h, width=w, encoding=encoding, step=step,
                 is_bigendian=int(bigendian), data=buf.tobytes())


def test_mono_images_round_trip_with_row_padding():
    img = np.random.default_rng(0).integers(0, 256, (5, 7), dtype=np.uint8)
    for enc in ('mono8', '8UC1'):
        np.testing.assert_array_equal(conversions.image_to_array(_image(img, enc, step=12)), img)
    img16 = np.random.default_rng(1).integers(0, 65535, (4, 3)).astype('<u2')
    np.testing.assert_array_equal(conversions.image_to_array(_image(img16, 'mono16')), img16)
    big = _image(img16.astype('>u2'), '16UC1', bigendian=True)
    np.testing.assert_array_equal(conversions.image_to_array(big), img16)


def test_colour_images_are_converted_to_grey():
    grey = np.random.default_rng(2).integers(0, 256, (6, 4), dtype=np.uint8)
    rgb = np.stack([grey] * 3, axis=-1)
    for enc in ('rgb8', 'bgr8'):
        np.testing.assert_array_equal(conversions.image_to_array(_image(rgb, enc)), grey)
    red = np.zeros((2, 2, 3), np.uint8)
    red[..., 0] = 200
    assert conversions.image_to_array(_image(red, 'rgb8'))[0, 0] == round(0.299 * 200)
    assert conversions.image_to_array(_image(red, 'bgr8'))[0, 0] == round(0.114 * 200)


@pytest.mark.parametrize('msg, text', [
    (Image(height=4, width=4, encoding='yuv422', step=8, data=bytes(32)), 'encoding'),
    (Image(height=0, width=0, encoding='mono8', step=0, data=b''), 'empty'),
    (Image(height=4, width=4, encoding='mono8', step=4, data=bytes(10)), '<'),
    (Image(height=4, width=4, encoding='mono8', step=2, data=bytes(16)), 'step'),
    (Image(height=2, width=2, encoding='rgb8', step=6, data=bytes(11)), '<'),
])
def test_bad_images_raise_value_error(msg, text):
    with pytest.raises(ValueError, match=text):
        conversions.image_to_array(msg)


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
