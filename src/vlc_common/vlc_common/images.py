"""sensor_msgs/Image → numpy arrays, one definition for every node that reads images.

Encodings (REP-118 / sensor_msgs image_encodings): ``mono8``, ``8UC1``, ``mono16``,
``16UC1`` (kept as they are), ``rgb8``, ``bgr8``, ``rgba8``, ``bgra8`` (converted to grey
with the ITU-R BT.601 luma weights, as OpenCV does), ``yuv422``/``uyvy`` and
``yuv422_yuy2``/``yuyv`` (the luma samples). Big-endian 16-bit data are honoured.
"""
import cv2
import numpy as np

# encoding → (channels, bytes per channel, OpenCV conversion to grey or None)
_ENCODINGS = {
    'mono8': (1, 1, None), '8UC1': (1, 1, None),
    'mono16': (1, 2, None), '16UC1': (1, 2, None),
    'rgb8': (3, 1, cv2.COLOR_RGB2GRAY), 'bgr8': (3, 1, cv2.COLOR_BGR2GRAY),
    'rgba8': (4, 1, cv2.COLOR_RGBA2GRAY), 'bgra8': (4, 1, cv2.COLOR_BGRA2GRAY),
    'yuv422': (2, 1, 'uyvy'), 'uyvy': (2, 1, 'uyvy'),
    'yuv422_yuy2': (2, 1, 'yuyv'), 'yuyv': (2, 1, 'yuyv'),
}
ENCODINGS = tuple(_ENCODINGS)


class ImageError(ValueError):
    """An image message that cannot be used: ``kind`` names the problem (``encoding``,
    ``empty``, ``step``, ``truncated``, ``size``), the text says why.
    """

    def __init__(self, kind, text):
        super().__init__(text)
        self.kind = kind


def image_to_array(msg, mono8=False):
    """sensor_msgs/Image (or anything with its fields) → (H, W) grey array.

    mono images are returned as they are (a view of the message data where possible),
    uint8 or uint16; colour and YUV images as uint8 grey. ``mono8``: 16-bit images keep
    their 8 most significant bits (uint8 out). Raises :class:`ImageError` for an unknown
    encoding, an empty, truncated or inconsistent image: the data must be exactly
    ``height·step`` bytes (sensor_msgs/Image), so a width, height or step that does not
    describe the data is refused rather than read as a different image.
    """
    if msg.encoding not in _ENCODINGS:
        raise ImageError('encoding', f'unsupported image encoding {msg.encoding!r}')
    channels, depth, colour = _ENCODINGS[msg.encoding]
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    if height == 0 or width == 0:
        raise ImageError('empty', f'empty image ({width}x{height})')
    row_bytes = width * channels * depth
    if step < row_bytes:
        raise ImageError('step', f'step {step} B < width {width} x {channels * depth} B')
    data = np.frombuffer(msg.data, dtype=np.uint8)
    if data.size < step * height:
        raise ImageError('truncated',
                         f'truncated image: {data.size} B < {height} rows x {step} B')
    if data.size != step * height:
        raise ImageError('size', f'image data {data.size} B != {height} rows x {step} B')
    rows = data.reshape(height, step)[:, :row_bytes]
    if depth == 2:
        words = np.ascontiguousarray(rows).view('>u2' if msg.is_bigendian else '<u2')
        image = words.reshape(height, width)
        return (image >> 8).astype(np.uint8) if mono8 else image
    if colour is None:
        return np.ascontiguousarray(rows)
    pixels = rows.reshape(height, width, channels)
    if colour == 'uyvy':
        return np.ascontiguousarray(pixels[:, :, 1])
    if colour == 'yuyv':
        return np.ascontiguousarray(pixels[:, :, 0])
    return cv2.cvtColor(np.ascontiguousarray(pixels), colour)
