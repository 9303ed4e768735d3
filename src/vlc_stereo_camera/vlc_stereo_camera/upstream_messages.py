"""The messages the perception nodes would publish for the observations of
:class:`~vlc_stereo_camera.core.upstream.SensorSimulator`: ``imu/data``, ``spots/pairs``
and ``vlc/lamps`` in the layouts of :mod:`vlc_common.core.records`, for tests and replays
of the localizer without images.
"""
import math

import numpy as np
from sensor_msgs.msg import Imu

from vlc_common.core.records import LAMP_DTYPE, PAIR_DTYPE
from vlc_common.pointcloud import records_to_cloud
from vlc_common.stamps import header

CAMERA_FRAME = 'camera_left_optical_frame'


def imu_msg(sample, frame_id='base_link'):
    """``imu/data`` of an :class:`~vlc_common.core.observation.ImuSample` (with attitude)."""
    msg = Imu(header=header(sample.stamp_ns, frame_id))
    a, w, q = sample.accel_mps2, sample.gyro_rps, sample.quat_xyzw
    msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z = map(float, a)
    msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = map(float, w)
    msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w = map(float, q)
    msg.orientation_covariance = [float(v) for v in sample.attitude_cov_rad2.ravel()]
    return msg


def spots_msg(stamp_ns, observations, frame_id=CAMERA_FRAME):
    """``spots/pairs`` of one frame's observations (independent left/right errors)."""
    rec = np.zeros(len(observations), dtype=PAIR_DTYPE)
    for i, o in enumerate(observations):
        rec[i]['u_left'], rec[i]['v_left'] = o.uv_left
        rec[i]['u_right'], rec[i]['v_right'] = o.uv_right
        rec[i]['disparity'] = o.disparity_px
        rec[i]['stamp_offset_s'] = math.nan
        for f in ('sigma_u_left', 'sigma_v_left', 'sigma_u_right', 'sigma_v_right'):
            rec[i][f] = o.sigma_u_px
        rec[i]['sigma_disparity'] = math.sqrt(2.0) * o.sigma_u_px
    return records_to_cloud(rec, header(stamp_ns, frame_id))


def lamps_msg(stamp_ns, observations, frame_id=CAMERA_FRAME):
    """``vlc/lamps`` of one frame's observations: confirmed (state 2) where the UID is
    known, partial (1) otherwise; the decoder's centre is coarser than the spot
    locator's (+0.6, −0.4 px in the left image).
    """
    rec = np.zeros(len(observations), dtype=LAMP_DTYPE)
    for i, o in enumerate(observations):
        rec[i]['track_id'] = i + 1
        rec[i]['uid'] = o.uid or 0
        rec[i]['state'] = 2 if o.uid is not None else 1
        rec[i]['t_offset_s'] = math.nan
        rec[i]['left_u'], rec[i]['left_v'] = o.uv_left[0] + 0.6, o.uv_left[1] - 0.4
        rec[i]['right_u'], rec[i]['right_v'] = o.uv_right
    return records_to_cloud(rec, header(stamp_ns, frame_id))
