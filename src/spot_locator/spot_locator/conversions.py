"""Messages ↔ arrays for the spot locator (the only module that knows both).

``spots/pairs`` layout (sensor_msgs/PointCloud2, one point per matched lamp spot pair,
header = the stereo images' header, little endian, ``height`` 1, ``point_step`` 112):

=====================================  =======  ======  =====================================
field                                  type     offset  meaning
=====================================  =======  ======  =====================================
``u_left``, ``v_left``                 float64  0, 8    projected lamp-disc centre, left, px
``u_right``, ``v_right``               float64  16, 24  same in the right image, px
``disparity``                          float64  32      u_left − u_right, px (> 0)
``stamp_offset_s``                     float64  40      measurement instant − header stamp, s:
                                                        exposure mid-time of the spot's
                                                        centre row
``sigma_u_left``, ``sigma_v_left``     float32  48, 52  1σ of u_left, v_left, px
``sigma_u_right``, ``sigma_v_right``   float32  56, 60  1σ of u_right, v_right, px
``sigma_disparity``                    float32  64      1σ of the disparity, px
``circularity_left``,                  float32  68, 72  α = 4πS/L² (paper eq. 10) of each spot
``circularity_right``
``ecc_du_left``, ``ecc_dv_left``       float32  76, 80  eccentricity offset removed, left, px
``ecc_du_right``, ``ecc_dv_right``     float32  84, 88  same, right, px
``blur_px``                            float32  92      predicted exposure blur length, px
``row_min``, ``row_max``               uint32   96, 100 first/last image row the left spot
                                                        covers (lit rows after closing)
``flags``                              uint32   104     bits 0–1 method (0 centroid,
                                                        1 ellipse, 2 fused, 3 chord); 2 Wiener
                                                        applied; 3 eccentricity removed with
                                                        the nominal normal; 4 … with the
                                                        measured normal; 5 centre row from
                                                        the chord widths; 6 rolling-shutter
                                                        model applied; 7 a spot cut by the
                                                        top or bottom image edge
=====================================  =======  ======  =====================================
"""

import cv2
import numpy as np
from vlc_stereo_camera.pointcloud import cloud_to_records, records_to_cloud  # noqa: F401

from .core.locator import StereoGeometry

PAIR_DTYPE = np.dtype({
    'names': ['u_left', 'v_left', 'u_right', 'v_right', 'disparity', 'stamp_offset_s',
              'sigma_u_left', 'sigma_v_left', 'sigma_u_right', 'sigma_v_right',
              'sigma_disparity', 'circularity_left', 'circularity_right', 'ecc_du_left',
              'ecc_dv_left', 'ecc_du_right', 'ecc_dv_right', 'blur_px', 'row_min',
              'row_max', 'flags'],
    'formats': ['<f8'] * 6 + ['<f4'] * 12 + ['<u4'] * 3,
    'offsets': [0, 8, 16, 24, 32, 40] + [48 + 4 * i for i in range(12)] + [96, 100, 104],
    'itemsize': 112,
})


_CHANNELS = {'mono8': (np.uint8, 1), 'mono16': ('<u2', 1), '8UC1': (np.uint8, 1),
             '16UC1': ('<u2', 1), 'rgb8': (np.uint8, 3), 'bgr8': (np.uint8, 3)}


def image_to_array(msg):
    """sensor_msgs/Image → (H, W) mono array (uint8 or uint16).

    mono8/8UC1 and mono16/16UC1 are returned as they are; rgb8 and bgr8 are converted to
    grey (ITU-R BT.601 weights). Raises ValueError on an unknown encoding and on empty or
    truncated data.
    """
    if msg.encoding not in _CHANNELS:
        raise ValueError(f'unsupported image encoding {msg.encoding!r}')
    dtype, channels = _CHANNELS[msg.encoding]
    dtype = np.dtype(dtype)
    if msg.is_bigendian and dtype.itemsize > 1:
        dtype = dtype.newbyteorder('>')
    row_bytes = msg.width * channels * dtype.itemsize
    if msg.height == 0 or msg.width == 0:
        raise ValueError('empty image')
    if msg.step < row_bytes:
        raise ValueError(f'step {msg.step} B < width {msg.width} x {channels} x '
                         f'{dtype.itemsize} B')
    buf = np.frombuffer(msg.data, dtype=np.uint8)
    if buf.size < msg.step * msg.height:
        raise ValueError(f'image data {buf.size} B < {msg.height} rows x {msg.step} B')
    rows = buf[:msg.step * msg.height].reshape(msg.height, msg.step)[:, :row_bytes]
    img = np.ascontiguousarray(rows).view(dtype).reshape(msg.height, msg.width, channels)
    if channels == 1:
        return img[:, :, 0]
    code = cv2.COLOR_RGB2GRAY if msg.encoding == 'rgb8' else cv2.COLOR_BGR2GRAY
    return cv2.cvtColor(img, code)


def stereo_geometry(left_info, right_info):
    """Rectified stereo geometry from the two CameraInfo messages.

    Uses the projection matrices P (rectified): fx = P[0,0], fy = P[1,1], cx = P[0,2],
    cy = P[1,2], baseline = −P_right[0,3] / fx. Raises ValueError if they do not
    describe a rectified pair with a positive baseline.
    """
    pl = np.asarray(left_info.p, float).reshape(3, 4)
    pr = np.asarray(right_info.p, float).reshape(3, 4)
    fx, fy = pl[0, 0], pl[1, 1]
    if not (fx > 0 and fy > 0):
        raise ValueError('camera_info P has no positive focal length')
    if not np.allclose(pl[:, :3], pr[:, :3], rtol=1e-6, atol=1e-6):
        raise ValueError('left and right camera_info P differ: not a rectified pair')
    baseline = (pl[0, 3] - pr[0, 3]) / fx
    if not baseline > 0:
        raise ValueError(f'stereo baseline {baseline} m is not positive')
    if (left_info.width, left_info.height) != (right_info.width, right_info.height):
        raise ValueError('left and right camera_info sizes differ')
    return StereoGeometry(fx=fx, fy=fy, cx=pl[0, 2], cy=pl[1, 2], baseline_m=baseline,
                          width=int(left_info.width), height=int(left_info.height))


def pairs_to_records(pairs):
    """List of :class:`~spot_locator.core.locator.SpotPair` → structured PAIR_DTYPE array."""
    rec = np.zeros(len(pairs), dtype=PAIR_DTYPE)
    for i, p in enumerate(pairs):
        rec[i] = (p.uv_left[0], p.uv_left[1], p.uv_right[0], p.uv_right[1], p.disparity,
                  p.stamp_offset_s, p.sigma_left[0], p.sigma_left[1], p.sigma_right[0],
                  p.sigma_right[1], p.sigma_disparity, p.circularity_left,
                  p.circularity_right, p.offset_left[0], p.offset_left[1],
                  p.offset_right[0], p.offset_right[1], p.blur_px, p.row_min, p.row_max,
                  p.flags)
    return rec


