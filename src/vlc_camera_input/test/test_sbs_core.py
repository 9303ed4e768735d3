"""The SBS core without ROS: splitting, every encoding a UVC driver publishes back to the
grey halves, JPEG decoding and its failures, rectification, the readout.
"""
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from vlc_camera_input.conversions import image_to_grey
from vlc_camera_input.core import sbs
from vlc_camera_input.core.rectify import Rectifier, rectified_camera_info
from vlc_common.core.camera import CameraModel
from vlc_common.images import ImageError

W, H = 64, 40


def grey_pair(seed=1):
    """Two seeded grey camera images with a bright striped disc each (a lamp spot)."""
    rng = np.random.default_rng(seed)
    images = []
    for shift in (0, -6):
        image = rng.integers(0, 40, size=(H, W), dtype=np.uint8)
        v, u = np.mgrid[0:H, 0:W]
        disc = (u - 30 - shift) ** 2 + (v - 20) ** 2 < 64
        image[disc & (v % 4 < 2)] = 250
        images.append(image)
    return images


def msg(array, encoding):
    """An Image-like message of ``array`` (H, W[, C]) in ``encoding``."""
    array = np.ascontiguousarray(array)
    h, w = array.shape[:2]
    row_bytes = array[0].nbytes
    return SimpleNamespace(encoding=encoding, height=h, width=w, step=row_bytes,
                           is_bigendian=0, data=array.tobytes())


def encode(grey, encoding):
    """Grey (H, W) → an image of ``encoding`` whose luma is ``grey`` (as a camera with a
    grey scene gives: equal R, G, B; Y = grey and neutral chroma 128).
    """
    if encoding == 'mono8':
        return grey
    if encoding == 'mono16':
        return grey.astype(np.uint16) << 8
    if encoding in ('bgr8', 'rgb8'):
        return np.repeat(grey[:, :, None], 3, axis=2)
    chroma = np.full_like(grey, 128)
    if encoding in ('yuyv', 'yuv422_yuy2'):
        return np.stack([grey, chroma], axis=2)          # Y0 U Y1 V
    if encoding in ('uyvy', 'yuv422'):
        return np.stack([chroma, grey], axis=2)          # U Y0 V Y1
    raise ValueError(encoding)


def test_split_returns_the_halves_and_swaps():
    left, right = grey_pair()
    frame = np.hstack([left, right])
    a, b = sbs.split(frame, (W, H))
    assert np.array_equal(a, left) and np.array_equal(b, right)
    assert a.flags.c_contiguous and b.flags.c_contiguous
    a, b = sbs.split(frame, (W, H), swap=True)
    assert np.array_equal(a, right) and np.array_equal(b, left)


def test_split_refuses_an_odd_width_and_another_resolution():
    with pytest.raises(sbs.SbsError) as err:
        sbs.split(np.zeros((H, 2 * W + 1), np.uint8))
    assert err.value.kind == 'odd_width' and 'odd width 129' in str(err.value)
    with pytest.raises(sbs.SbsError) as err:
        sbs.split(np.zeros((H, 2 * W), np.uint8), (W, H + 2))
    assert err.value.kind == 'size'
    assert 'SBS frame 128x40 px is not two 64x42 px cameras' in str(err.value)
    assert 'expected 128x42' in str(err.value)
    with pytest.raises(sbs.SbsError) as err:
        sbs.split(np.zeros((H, 2 * W), np.uint8), (W + 8, H))
    assert err.value.kind == 'size'


@pytest.mark.parametrize('encoding', ['mono8', 'mono16', 'bgr8', 'rgb8', 'yuyv',
                                      'yuv422_yuy2', 'uyvy', 'yuv422'])
def test_every_driver_encoding_gives_back_the_grey_halves_exactly(encoding):
    left, right = grey_pair(seed=3)
    frame = encode(np.hstack([left, right]), encoding)
    grey = image_to_grey(msg(frame, encoding))
    a, b = sbs.split(grey, (W, H))
    assert np.array_equal(a, left) and np.array_equal(b, right)


def test_an_unknown_encoding_is_an_image_error():
    with pytest.raises(ImageError) as err:
        image_to_grey(msg(np.zeros((H, 2 * W), np.uint8), 'bayer_rggb8'))
    assert err.value.kind == 'encoding'


def test_jpeg_at_quality_95_keeps_the_luma_within_a_few_levels():
    left, right = grey_pair(seed=5)
    frame = np.hstack([left, right])
    ok, data = cv2.imencode('.jpg', np.repeat(frame[:, :, None], 3, axis=2),
                            [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    grey = sbs.decode_compressed(data.tobytes(), 'jpeg')
    a, b = sbs.split(grey, (W, H))
    for got, want in ((a, left), (b, right)):
        diff = np.abs(got.astype(int) - want)
        assert diff.mean() < 3.0 and not np.array_equal(got, want)
    # image_transport's format string, and none at all
    assert np.array_equal(sbs.decode_compressed(data, 'bgr8; jpeg compressed bgr8'), grey)
    assert np.array_equal(sbs.decode_compressed(data, ''), grey)


def test_png_is_lossless():
    frame = np.hstack(grey_pair(seed=7))
    ok, data = cv2.imencode('.png', frame)
    assert ok and np.array_equal(sbs.decode_compressed(data, 'png'), frame)


def test_corrupt_truncated_or_foreign_compressed_frames_are_refused():
    frame = np.hstack(grey_pair(seed=9))
    data = cv2.imencode('.jpg', frame, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()
    # zero padding after the end marker (UVC bridges) is a whole frame
    assert sbs.decode_compressed(data + bytes(300), 'jpeg').shape == frame.shape
    cases = {
        'cut short': (data[:len(data) // 2], 'jpeg', 'corrupt', 'no end-of-image marker'),
        'empty': (b'', 'jpeg', 'corrupt', 'empty'),
        'not an image': (b'hello world' * 10, 'jpeg', 'corrupt', 'signature'),
        'headers destroyed': (data[:2] + bytes(200) + data[-2:], 'jpeg', 'corrupt',
                              'does not decode'),
        'other codec': (data, 'h264', 'format', "'h264' is not JPEG or PNG"),
    }
    for name, (payload, fmt, kind, text) in cases.items():
        with pytest.raises(sbs.SbsError) as err:
            sbs.decode_compressed(payload, fmt)
        assert err.value.kind == kind and text in str(err.value), name


def lens_camera():
    K = np.array([[90.0, 0, 33.0], [0, 91.0, 19.0], [0, 0, 1]])
    D = np.array([-0.25, 0.08, 0.001, -0.0005, 0.0])
    a = np.radians(1.0)
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    P = np.array([[85.0, 0, 32.0, 0], [0, 85.0, 20.0, 0], [0, 0, 1, 0]])
    return CameraModel(W, H, K, D, R, P)


def test_rectifier_moves_a_raw_spot_to_its_rectified_position():
    camera = lens_camera()
    raw_uv = np.array([[12.0, 9.0]])
    v, u = np.mgrid[0:H, 0:W]
    image = (200.0 * np.exp(-((u - raw_uv[0, 0]) ** 2 + (v - raw_uv[0, 1]) ** 2) / 2.0))
    rect = Rectifier(camera)(image.astype(np.float32))
    want = camera.rectify_points(raw_uv)[0]
    weights = np.clip(rect - 5.0, 0, None)
    got = np.array([(weights * u).sum(), (weights * v).sum()]) / weights.sum()
    assert np.linalg.norm(got - want) < 0.15, (got, want)
    assert np.linalg.norm(want - raw_uv[0]) > 2.0         # the lens does move it


def test_an_ideal_camera_is_passed_through_and_the_rectified_info_is_ideal():
    K = np.array([[90.0, 0, 31.5], [0, 90.0, 19.5], [0, 0, 1]])
    ideal = CameraModel(W, H, K, np.zeros(5), np.eye(3), np.hstack([K, np.zeros((3, 1))]))
    image = np.hstack(grey_pair())[:, :W]
    assert Rectifier(ideal)(image) is image
    info = rectified_camera_info(lens_camera().to_camera_info())
    assert np.array_equal(info['K'], lens_camera().P[:, :3])
    assert not np.any(info['D']) and np.array_equal(info['R'], np.eye(3))
    CameraModel.from_camera_info(info)                     # a valid camera


def test_readout_is_rows_minus_one_times_row_time_plus_exposure():
    assert sbs.readout_s(720, 30e-6, 25e-6) == pytest.approx(0.021595)
