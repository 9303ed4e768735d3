"""sensor_msgs/Image → arrays: encodings, row padding, byte order, bad input."""
import numpy as np
import pytest
from sensor_msgs.msg import Image

from vlc_common.images import ImageError, image_to_array


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
        np.testing.assert_array_equal(image_to_array(_image(img, enc, step=12)), img)
    img16 = np.random.default_rng(1).integers(0, 65535, (4, 3)).astype('<u2')
    np.testing.assert_array_equal(image_to_array(_image(img16, 'mono16')), img16)
    big = _image(img16.astype('>u2'), '16UC1', bigendian=True)
    np.testing.assert_array_equal(image_to_array(big), img16)


def test_colour_images_are_converted_to_grey():
    grey = np.random.default_rng(2).integers(0, 256, (6, 4), dtype=np.uint8)
    rgb = np.stack([grey] * 3, axis=-1)
    for enc in ('rgb8', 'bgr8'):
        np.testing.assert_array_equal(image_to_array(_image(rgb, enc)), grey)
    red = np.zeros((2, 2, 3), np.uint8)
    red[..., 0] = 200
    assert image_to_array(_image(red, 'rgb8'))[0, 0] == round(0.299 * 200)
    assert image_to_array(_image(red, 'bgr8'))[0, 0] == round(0.114 * 200)


@pytest.mark.parametrize('msg, text', [
    (Image(height=4, width=4, encoding='bayer_rggb8', step=4, data=bytes(16)), 'encoding'),
    (Image(height=0, width=0, encoding='mono8', step=0, data=b''), 'empty'),
    (Image(height=4, width=4, encoding='mono8', step=4, data=bytes(10)), '<'),
    (Image(height=4, width=4, encoding='mono8', step=2, data=bytes(16)), 'step'),
    (Image(height=2, width=2, encoding='rgb8', step=6, data=bytes(11)), '<'),
])
def test_bad_images_raise_value_error(msg, text):
    with pytest.raises(ValueError, match=text):
        image_to_array(msg)


W, H = 64, 48


@pytest.mark.parametrize('fields, kind', [
    # the fault injector's image kinds (vlc_evaluation.fault_kinds), at a small size
    (dict(encoding='rgb8', step=W, data=bytes(W * H)), 'step'),                # mono data
    (dict(encoding='bayer_rggb8', step=W, data=bytes(W * H)), 'encoding'),
    (dict(encoding='nonsense', step=W, data=bytes(W * H)), 'encoding'),
    (dict(width=W + 8, step=W + 8, data=bytes(W * H)), 'truncated'),          # width
    (dict(height=H - 1, step=W, data=bytes(W * H)), 'size'),                  # height
    (dict(step=W - 1, data=bytes(W * H)), 'step'),
    (dict(step=W, data=bytes(W * H // 2)), 'truncated'),
    (dict(width=0, height=0, step=0, data=b''), 'empty'),
], ids=['rgb8_mono_data', 'bayer_rggb8', 'nonsense', 'width_mismatch', 'height_mismatch',
        'step_too_small', 'truncated', 'empty'])
def test_every_inconsistent_image_is_refused_with_its_kind(fields, kind):
    """Data that do not match width, height, step and encoding exactly are refused, never
    read as another image (a height one row short used to be read as a valid image).
    """
    msg = Image(height=H, width=W, encoding='mono8')
    for name, value in fields.items():
        setattr(msg, name, value)
    with pytest.raises(ImageError) as err:
        image_to_array(msg)
    assert err.value.kind == kind


def test_sixteen_bit_images_reduce_to_their_high_byte_for_mono8():
    img16 = np.array([[0x1234, 0xFF01], [0x00FF, 0x8000]], dtype='<u2')
    out = image_to_array(_image(img16, 'mono16'), mono8=True)
    assert out.dtype == np.uint8
    np.testing.assert_array_equal(out, [[0x12, 0xFF], [0x00, 0x80]])


@pytest.mark.parametrize('encoding, luma_byte', [('yuv422', 1), ('uyvy', 1),
                                                  ('yuv422_yuy2', 0), ('yuyv', 0)])
def test_yuv422_images_give_their_luma(encoding, luma_byte):
    """Packed 4:2:2: UYVY carries Y in the odd bytes, YUYV in the even ones."""
    luma = np.random.default_rng(3).integers(0, 256, (3, 4), dtype=np.uint8)
    chroma = np.full_like(luma, 77)
    pairs = np.stack([chroma, luma] if luma_byte else [luma, chroma], axis=-1)
    np.testing.assert_array_equal(image_to_array(_image(pairs, encoding)), luma)


def test_the_problem_is_named():
    with pytest.raises(ImageError) as err:
        image_to_array(Image(height=4, width=4, encoding='mono8', step=4, data=bytes(10)))
    assert err.value.kind == 'truncated'
