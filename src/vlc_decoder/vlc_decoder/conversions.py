r"""Messages ↔ arrays for the decoder node: images in, lamp records and diagnostics out.

``vlc/lamps`` layout: :data:`vlc_common.core.records.LAMP_DTYPE`.
"""
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
from vlc_common.images import ImageError, image_to_array  # noqa: F401 (ImageError re-exported)
from vlc_common.pointcloud import records_to_cloud  # noqa: F401 (re-exported)


def image_to_mono8(msg):
    """sensor_msgs/Image → (H, W) uint8 grey (:func:`vlc_common.images.image_to_array`,
    16-bit images reduced to their 8 most significant bits); raises ImageError.
    """
    return image_to_array(msg, mono8=True)


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
