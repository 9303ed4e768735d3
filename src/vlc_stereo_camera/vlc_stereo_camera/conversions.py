"""Messages ↔ arrays for the synthetic stereo camera (the only module that knows both).

``ground_truth/spots`` layout (sensor_msgs/PointCloud2, one point per lamp whose spot
has pixels in at least one image, header = the image header, little endian,
``point_step`` 96 bytes, ``height`` 1):

======================  =======  ======  ==================================================
field                   type     offset  meaning
======================  =======  ======  ==================================================
``uid``                 uint32   0       lamp UID (line_id << 12 | lamp_id)
``in_left``             uint32   4       1 if the projected disc centre lies in the left image
``in_right``            uint32   8       1 if it lies in the right image
``row_first``           uint32   12      first image row the disc covers (either image)
``row_last``            uint32   16      last image row the disc covers (either image)
``u_left``, ``v_left``  float64  24, 32  disc centre projected in the left image, px
``u_right``,            float64  40, 48  same in the right image, px (v_right = v_left)
``v_right``
``depth_m``             float64  56      left optical z of the disc centre, m
``range_m``             float64  64      distance left optical centre → disc centre, m
``along_track_m``       float64  72      lamp chainage − base_link x in map, m
``t_offset_s``          float64  80      truth instant − header stamp, s (exposure mid-time
                                         of the row where the centre projects)
``viewing_angle_deg``   float64  88      angle between line of sight and disc normal, deg
======================  =======  ======  ==================================================
"""
import array

from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
import numpy as np
from sensor_msgs.msg import Image

from vlc_common.camera_info import camera_info_msg  # noqa: F401 (here for its callers)
from vlc_common.pointcloud import cloud_to_records, records_to_cloud  # noqa: F401 (re-exported)
from vlc_common.stamps import header, ns_to_stamp  # noqa: F401 (re-exported)

SPOT_DTYPE = np.dtype({
    'names': ['uid', 'in_left', 'in_right', 'row_first', 'row_last', 'u_left', 'v_left',
              'u_right', 'v_right', 'depth_m', 'range_m', 'along_track_m', 't_offset_s',
              'viewing_angle_deg'],
    'formats': ['<u4'] * 5 + ['<f8'] * 9,
    'offsets': [0, 4, 8, 12, 16, 24, 32, 40, 48, 56, 64, 72, 80, 88],
    'itemsize': 96,
})



def stamp_ns(epoch_s, t_rel_s=0.0):
    """Integer nanoseconds of ``epoch_s + t_rel_s`` without float rounding of the epoch."""
    whole = int(np.floor(epoch_s))
    return whole * 1_000_000_000 + int(round((epoch_s - whole + t_rel_s) * 1e9))


def image_msg(image, hdr):
    """(H, W) uint8 array → sensor_msgs/Image mono8 (one memcpy, no per-byte Python)."""
    image = np.ascontiguousarray(image)
    if image.dtype != np.uint8 or image.ndim != 2:
        raise ValueError(f'mono8 needs a 2-D uint8 array, got {image.dtype} {image.shape}')
    msg = Image(header=hdr, height=image.shape[0], width=image.shape[1], encoding='mono8',
                is_bigendian=0, step=image.shape[1])
    data = array.array('B')
    data.frombytes(image.data)
    msg.data = data
    return msg


def image_to_array(msg):
    """sensor_msgs/Image mono8 → (H, W) uint8 view; ValueError on anything else."""
    if msg.encoding != 'mono8':
        raise ValueError(f'expected mono8, got {msg.encoding!r}')
    buf = np.frombuffer(msg.data, dtype=np.uint8)
    if msg.step < msg.width or buf.size < msg.step * msg.height or msg.height == 0:
        raise ValueError(f'image data {buf.size} B does not fit {msg.height}x{msg.step}')
    return buf[:msg.step * msg.height].reshape(msg.height, msg.step)[:, :msg.width]


def pose_msg(position_m, quat_xyzw, hdr):
    msg = PoseStamped(header=hdr)
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(v) for v in
                                                                      position_m)
    (msg.pose.orientation.x, msg.pose.orientation.y, msg.pose.orientation.z,
     msg.pose.orientation.w) = (float(v) for v in quat_xyzw)
    return msg


def odometry_msg(frame, hdr, child_frame_id):
    """Ground-truth nav_msgs/Odometry of base_link: pose in ``hdr.frame_id``, twist in
    ``child_frame_id`` axes (covariances zero: exact truth).
    """
    msg = Odometry(header=hdr, child_frame_id=child_frame_id)
    msg.pose.pose = pose_msg(frame.base_position_m, frame.base_quat_xyzw, hdr).pose
    v, w = frame.base_velocity_body_mps, frame.base_angular_velocity_body_rps
    msg.twist.twist.linear.x, msg.twist.twist.linear.y, msg.twist.twist.linear.z = (
        float(x) for x in v)
    msg.twist.twist.angular.x, msg.twist.twist.angular.y, msg.twist.twist.angular.z = (
        float(x) for x in w)
    return msg


def truth_records(truth, t0_s):
    """List of LampTruth → structured array of SPOT_DTYPE (one row per lamp)."""
    rec = np.zeros(len(truth), dtype=SPOT_DTYPE)
    for i, lamp in enumerate(truth):
        rows = [r for r in (lamp.rows_left, lamp.rows_right) if r is not None]
        rec[i] = (lamp.uid, lamp.in_left, lamp.in_right, min(r[0] for r in rows),
                  max(r[1] for r in rows), lamp.uv_left[0], lamp.uv_left[1],
                  lamp.uv_right[0], lamp.uv_right[1], lamp.depth_m, lamp.range_m,
                  lamp.along_track_m, lamp.t_centre_s - t0_s, lamp.viewing_angle_deg)
    return rec


