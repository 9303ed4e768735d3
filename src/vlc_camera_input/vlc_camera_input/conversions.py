"""Messages ↔ arrays for the SBS splitter: camera frames in, mono8 images and
camera_info out.
"""
import array

import numpy as np
from sensor_msgs.msg import Image

from vlc_camera_input.core.sbs import decode_compressed
from vlc_common.camera_info import camera_info_msg  # noqa: F401 (here for its callers)
from vlc_common.images import ImageError, image_to_array

__all__ = ['ImageError', 'camera_info_msg', 'compressed_to_grey',
           'image_msg', 'image_to_grey']


def image_to_grey(msg):
    """sensor_msgs/Image (any encoding of :mod:`vlc_common.images`) → (H, W) uint8 grey;
    raises :class:`~vlc_common.images.ImageError`.
    """
    return image_to_array(msg, mono8=True)


def compressed_to_grey(msg):
    """sensor_msgs/CompressedImage (JPEG, PNG) → (H, W) uint8 grey; raises
    :class:`~vlc_camera_input.core.sbs.SbsError`.
    """
    return decode_compressed(msg.data, msg.format)


def image_msg(image, header):
    """(H, W) uint8 array → sensor_msgs/Image mono8 with ``header`` (one copy)."""
    image = np.ascontiguousarray(image)
    if image.dtype != np.uint8 or image.ndim != 2:
        raise ValueError(f'mono8 needs a 2-D uint8 array, got {image.dtype} {image.shape}')
    msg = Image(header=header, height=image.shape[0], width=image.shape[1],
                encoding='mono8', is_bigendian=0, step=image.shape[1])
    data = array.array('B')
    data.frombytes(image.data)
    msg.data = data
    return msg
