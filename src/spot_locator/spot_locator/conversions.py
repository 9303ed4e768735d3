"""Messages ↔ arrays for the spot locator (the only module that knows both).

``spots/pairs`` layout: :data:`vlc_common.core.records.PAIR_DTYPE`.
"""

import numpy as np

from spot_locator.core.locator import StereoGeometry
from vlc_common.camera_info import raw_camera_model
from vlc_common.core.camera import CameraModel
from vlc_common.core.records import PAIR_DTYPE  # noqa: F401 (re-exported)
from vlc_common.images import image_to_array  # noqa: F401 (re-exported)
from vlc_common.pointcloud import cloud_to_records, records_to_cloud  # noqa: F401


def stereo_geometry(left_info, right_info):
    """Rectified stereo geometry from the two CameraInfo messages.

    Uses the projection matrices P (rectified): fx = P[0,0], fy = P[1,1], cx = P[0,2],
    cy = P[1,2], baseline = −P_right[0,3] / fx. Raises ValueError if they do not
    describe a rectified pair with a positive baseline, or a camera's K, D, R, P are not
    a valid camera model. When either camera is not already rectified (D ≠ 0, R ≠ I or
    P[:, :3] ≠ K) the images are taken as raw and ``raw_cameras`` carries both
    cameras' calibration (:class:`~spot_locator.core.locator.StereoGeometry`); an
    all-zero R (an uncalibrated driver's) counts as the identity.
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
    raw = [_raw_camera(info) for info in (left_info, right_info)]
    raw_cameras = None if raw[0] is None and raw[1] is None else tuple(
        _raw_camera(info, force=True) for info in (left_info, right_info))
    return StereoGeometry(fx=fx, fy=fy, cx=pl[0, 2], cy=pl[1, 2], baseline_m=baseline,
                          width=int(left_info.width), height=int(left_info.height),
                          raw_cameras=raw_cameras)


def _raw_camera(info, force=False):
    """(K, D, R, P, distortion_model) of a camera whose images are raw, as flat tuples
    of floats (:func:`vlc_common.camera_info.raw_camera_model`); None for a rectified
    one unless ``force`` (then its own K, D = 0, R = I, or K = P[:, :3] without a K).
    Raises ValueError (CameraModelError) for an invalid model.
    """
    model = raw_camera_model(info)
    if model is None:
        if not force:
            return None
        P = np.asarray(info.p, float).reshape(3, 4)
        K = np.asarray(info.k, float).reshape(3, 3)
        model = CameraModel(int(info.width), int(info.height), K if np.any(K) else P[:, :3],
                            None, None, P)
    return (tuple(model.K.ravel()), tuple(model.D), tuple(model.R.ravel()),
            tuple(model.P.ravel()), model.distortion_model)


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


