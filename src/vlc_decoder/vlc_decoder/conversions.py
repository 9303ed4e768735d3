r"""Messages ↔ arrays for the decoder node: images in, lamp records and diagnostics out.

``vlc/lamps`` layout: :data:`vlc_common.core.records.LAMP_DTYPE`.
"""
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np

from vlc_common.core.records import (  # noqa: F401
    FLAG_CONTENT_ALIGNED,
    FLAG_LEFT,
    FLAG_LEFT_CUT,
    FLAG_READ_LEFT,
    FLAG_READ_RIGHT,
    FLAG_RIGHT,
    FLAG_RIGHT_CUT,
    LAMP_DTYPE,
)
from vlc_common.pointcloud import records_to_cloud  # noqa: F401 (re-exported)

# encoding → (channels, bytes per channel, OpenCV conversion to gray or None)
_ENCODINGS = {
    'mono8': (1, 1, None), '8UC1': (1, 1, None),
    'mono16': (1, 2, None), '16UC1': (1, 2, None),
    'rgb8': (3, 1, 'rgb'), 'bgr8': (3, 1, 'bgr'),
    'rgba8': (4, 1, 'rgba'), 'bgra8': (4, 1, 'bgra'),
}


class ImageError(ValueError):
    """An image message the decoder cannot use: ``kind`` names the problem, the text
    says why.
    """

    def __init__(self, kind, text):
        super().__init__(text)
        self.kind = kind


def image_to_mono8(msg):
    """sensor_msgs/Image → (H, W) uint8 gray array (a view when already mono8).

    Colour images are converted with the ITU-R BT.601 luma weights; 16-bit images keep
    their 8 most significant bits. Raises ImageError for an unknown encoding, an empty,
    truncated or inconsistent image.
    """
    if msg.encoding not in _ENCODINGS:
        raise ImageError('encoding', f'unsupported encoding {msg.encoding!r}')
    channels, depth, colour = _ENCODINGS[msg.encoding]
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    if height == 0 or width == 0:
        raise ImageError('empty', f'empty image ({width}x{height})')
    if step < width * channels * depth:
        raise ImageError('step', f'step {step} < {width} px x {channels * depth} bytes')
    data = np.frombuffer(msg.data, dtype=np.uint8)
    if data.size < step * height:
        raise ImageError('truncated',
                         f'truncated image: {data.size} bytes < step {step} x {height} rows')
    rows = data[:step * height].reshape(height, step)[:, :width * channels * depth]
    if depth == 2:
        order = '>u2' if msg.is_bigendian else '<u2'
        return (rows.view(order).reshape(height, width) >> 8).astype(np.uint8)
    if colour is None:
        return rows
    pixels = rows.reshape(height, width, channels).astype(np.float32)
    r_index = 0 if colour.startswith('rgb') else 2
    gray = (0.299 * pixels[..., r_index] + 0.587 * pixels[..., 1]
            + 0.114 * pixels[..., 2 - r_index])
    return np.clip(np.rint(gray), 0, 255).astype(np.uint8)


def _spot_fields(spot):
    if spot is None:
        return (np.nan,) * 6
    u0, v0, u1, v1 = spot.bbox
    return (spot.u, spot.v, u0, v0, u1, v1)


def records_to_array(records, row_time_s, exposure_s):
    """LampRecords → structured array of ``LAMP_DTYPE`` (one element per record)."""
    out = np.zeros(len(records), dtype=LAMP_DTYPE)
    for i, rec in enumerate(records):
        pos = rec.position_m if rec.position_m is not None else (np.nan,) * 3
        flags = 0
        if rec.left is not None:
            flags |= FLAG_LEFT | (FLAG_LEFT_CUT if rec.left.cut else 0)
        if rec.right is not None:
            flags |= FLAG_RIGHT | (FLAG_RIGHT_CUT if rec.right.cut else 0)
        if rec.source.startswith(('left', 'both')):
            flags |= FLAG_READ_LEFT
        if rec.source.startswith(('right', 'both')):
            flags |= FLAG_READ_RIGHT
        if rec.content_aligned:
            flags |= FLAG_CONTENT_ALIGNED
        out[i] = (pos[0], pos[1], pos[2], rec.track_id, max(rec.uid, 0) if rec.state >= 2
                  else 0, rec.state, rec.chips_seen, rec.bits_known, flags,
                  rec.mid_row * row_time_s + 0.5 * exposure_s,
                  *_spot_fields(rec.left), *_spot_fields(rec.right),
                  rec.data_word, rec.data_mask)
    return out


def cloud_to_array(msg):
    """A ``vlc/lamps`` PointCloud2 (written with ``records_to_cloud``) → LAMP_DTYPE array."""
    names = {f.name: f for f in msg.fields}
    if msg.point_step != LAMP_DTYPE.itemsize or set(names) != set(LAMP_DTYPE.names):
        raise ValueError('not a vlc/lamps cloud')
    return np.frombuffer(bytes(msg.data), dtype=LAMP_DTYPE, count=msg.width * msg.height)


def diagnostics(stamp, name, hardware_id, level, message, values):
    """A DiagnosticArray with one status; ``values`` a dict of key → value (str()'d)."""
    array = DiagnosticArray()
    array.header.stamp = stamp
    status = DiagnosticStatus(level=level, name=name, message=message,
                              hardware_id=hardware_id)
    status.values = [KeyValue(key=str(k), value=str(v)) for k, v in values.items()]
    array.status = [status]
    return array
