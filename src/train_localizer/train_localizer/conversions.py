"""Messages ↔ core records for the localizer (the only module that knows both).

Inputs:

* ``spots/pairs``, ``vlc/lamps`` (sensor_msgs/PointCloud2) → numpy structured arrays with
  the messages' own named fields (:func:`cloud_to_records`); the field meanings are the
  producers' (docs/arch/spot_locator.md, docs/arch/vlc_decoder.md) and are read in
  :mod:`train_localizer.core.join`;
* ``imu/data`` (sensor_msgs/Imu) → :class:`~vlc_common.core.observation.ImuSample`;
* ``stereo/*/camera_info`` → rectified intrinsics and baseline; with raw images (D ≠ 0,
  R ≠ I) the left camera's rectification rotation and raw → rectified pixel map.

Outputs: a :class:`~train_localizer.core.reports.PoseEstimate` → PoseStamped,
PoseWithCovarianceStamped and Odometry; the integrity status → DiagnosticStatus.
"""
import math

from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
import numpy as np

from vlc_common.camera_info import CameraInfoKeeper, raw_camera_model
from vlc_common.core.observation import ImuSample
from vlc_common.core.records import LAMP_DTYPE, PAIR_DTYPE
from vlc_common.diagnostics import diagnostic_status  # noqa: F401 (here for the nodes)
from vlc_common.pointcloud import cloud_to_records  # noqa: F401 (re-exported)
from vlc_common.stamps import ns_to_stamp, stamp_to_ns  # noqa: F401 (re-exported)


def require_fields(records, names, topic):
    """Raise ValueError naming the missing fields of a record array."""
    have = set(records.dtype.names or ())
    missing = [n for n in names if n not in have]
    if missing and records.size:
        raise ValueError(f'{topic}: missing fields {", ".join(missing)}')


#: Largest attitude variance taken from ``imu/data`` per axis, rad² (a 1σ of 180°: an
#: attitude known no better is unknown; larger values, after a long IMU gap or from a
#: bad message, would only make the fix's normal equations singular).
MAX_ATTITUDE_VAR_RAD2 = math.pi ** 2

#: The records each cloud topic must carry, and their documented layouts.
CLOUD_LAYOUTS = {'spots/pairs': PAIR_DTYPE, 'vlc/lamps': LAMP_DTYPE}


def records_from_cloud(msg, topic, required=()):
    """A ``spots/pairs`` or ``vlc/lamps`` cloud → structured array, read with the topic's
    documented layout (:func:`vlc_common.pointcloud.cloud_to_records`): ValueError, naming
    the topic and the problem, for a cloud that is not what it says or not the layout.
    """
    try:
        return cloud_to_records(msg, CLOUD_LAYOUTS.get(topic), required)
    except ValueError as exc:
        raise ValueError(f'{topic}: {exc}') from exc


def _bounded_covariance(cov):
    """Symmetric part of ``cov`` with its eigenvalues clipped to [0, MAX_ATTITUDE_VAR_RAD2]."""
    sym = 0.5 * (cov + cov.T)
    # Positive definite with its largest eigenvalue in bounds settles it without eigh
    # (a tenth of the time, at 400 Hz): leading minors positive (Sylvester), the smallest
    # eigenvalue ≥ det/trace² above 1e-9 of the trace (far above eigh's rounding), all
    # eigenvalues ≤ the trace ≤ the bound.
    (a, b, c), (_, d, e), (_, _, f) = sym.tolist()
    trace = a + d + f
    det = a * (d * f - e * e) - b * (b * f - c * e) + c * (b * e - c * d)
    if (trace <= MAX_ATTITUDE_VAR_RAD2 and a > 0.0 and a * d - b * b > 0.0
            and det > 1e-9 * trace * trace * trace):
        return sym
    values, vectors = np.linalg.eigh(sym)
    if np.all((values >= 0.0) & (values <= MAX_ATTITUDE_VAR_RAD2)):
        return sym
    return (vectors * np.clip(values, 0.0, MAX_ATTITUDE_VAR_RAD2)) @ vectors.T


def imu_from_msg(msg):
    """sensor_msgs/Imu → ImuSample.

    ``orientation_covariance[0] == −1`` (REP-145: no orientation) → no attitude; an
    all-zero covariance (unknown) → attitude without covariance; a covariance with
    NaN/inf → the sample's attitude is not finite (the localizer skips it as it skips a
    NaN quaternion); variances beyond :data:`MAX_ATTITUDE_VAR_RAD2` are clipped to it.
    """
    cov = np.asarray(msg.orientation_covariance, dtype=float).reshape(3, 3)
    q = None
    att_cov = None
    if cov[0, 0] != -1.0:
        o = msg.orientation
        q = np.array([o.x, o.y, o.z, o.w])
        if not np.all(np.isfinite(cov)):
            q = np.full(4, np.nan)
        elif np.any(cov != 0.0):
            att_cov = _bounded_covariance(cov)
    a, w = msg.linear_acceleration, msg.angular_velocity
    return ImuSample(stamp_ns=stamp_to_ns(msg.header.stamp), accel_mps2=[a.x, a.y, a.z],
                     gyro_rps=[w.x, w.y, w.z], quat_xyzw=q, attitude_cov_rad2=att_cov)


def intrinsics_from_camera_info(left, right):
    """(fx, fy, cx, cy, baseline_m) of a rectified pair from its CameraInfo messages.

    Uses the projection matrices P; baseline = (P_left[0,3] − P_right[0,3]) / fx.
    Raises ValueError if they do not describe a rectified pair with a positive baseline.
    """
    pl = np.asarray(left.p, float).reshape(3, 4)
    pr = np.asarray(right.p, float).reshape(3, 4)
    fx, fy = pl[0, 0], pl[1, 1]
    if not (fx > 0.0 and fy > 0.0):
        raise ValueError('camera_info P has no positive focal length')
    if not np.allclose(pl[:, :3], pr[:, :3], rtol=1e-6, atol=1e-6):
        raise ValueError('left and right camera_info P differ: not a rectified pair')
    baseline = (pl[0, 3] - pr[0, 3]) / fx
    if not baseline > 0.0:
        raise ValueError(f'stereo baseline {baseline} m is not positive')
    return float(fx), float(fy), float(pl[0, 2]), float(pl[1, 2]), float(baseline)


class CameraInfoIntrinsics:
    """The left and right camera_info of a rectified pair, written into a RigGeometry.

    ``update(index, msg)`` offers message ``msg`` of camera ``index`` (0 left, 1 right)
    to a :class:`vlc_common.camera_info.CameraInfoKeeper`, which keeps the last good one
    of each camera (an invalid one is refused, a different valid one taken only once
    confirmed); once both are kept their intrinsics and baseline replace the geometry's.
    Returns a line to log when the geometry changed or a message or the pair is unusable
    (``(level, text)``, level ``info`` or ``warn``), else None. ``source`` says where
    the intrinsics came from: ``parameters`` until a usable pair arrived, then
    ``camera_info``.

    Raw images (the left camera_info has D ≠ 0 or R ≠ I): the spot pairs are in the
    rectified frame, which is the left optical frame turned by the left R, so the
    geometry's camera axes become R_base_cam(mount)·Rᵀ; and ``join_config.rectify_left``
    (when a join config is given) maps the decoder's raw left-image positions to
    rectified pixels for the join.
    """

    def __init__(self, geometry, enabled=True, join_config=None):
        self.geometry = geometry
        self.enabled = enabled
        self.keeper = CameraInfoKeeper()
        self.source = 'parameters'
        self.join_config = join_config
        self.left_model = None
        self._R_base_cam_mount = np.array(geometry.R_base_cam, float)

    @property
    def infos(self):
        """The kept left and right camera_info (None until one came)."""
        return self.keeper.current

    def offer(self, index, msg, info, warn):
        """:meth:`update`, and what it says handed to ``warn(text)`` (a warning) or
        ``info(text)``.
        """
        said = self.update(index, msg)
        if said is not None:
            (warn if said[0] == 'warn' else info)(said[1])

    def update(self, index, msg):
        if not self.enabled:
            return None
        outcome, reason = self.keeper.update(index, msg)
        if outcome == CameraInfoKeeper.SAME:
            # every change of either side came as KEPT and was applied then (30 Hz per
            # camera: re-deriving the models per message cost ~0.5 ms each)
            return None
        side = ('left', 'right')[index]
        if outcome == CameraInfoKeeper.REFUSED:
            return 'warn', f'{side} camera_info refused, the last good one kept: {reason}'
        if outcome == CameraInfoKeeper.PENDING:
            return 'warn', f'{side} camera_info {reason}'
        both = self.keeper.both()
        if both is None:
            return None
        try:
            fx, fy, cx, cy, baseline = intrinsics_from_camera_info(*both)
            left_model = raw_camera_model(both[0])
            raw_camera_model(both[1])
        except ValueError as exc:
            return 'warn', f'camera_info ignored: {exc}'
        g = self.geometry
        self.source = 'camera_info'
        R_base_cam = (self._R_base_cam_mount if left_model is None
                      else self._R_base_cam_mount @ left_model.R.T)
        self.left_model = left_model
        if self.join_config is not None:
            self.join_config.rectify_left = (None if left_model is None
                                             else left_model.rectify_points)
        # a calibration's systematic error applies to raw images (RigGeometry)
        g.raw_images = left_model is not None
        if ((g.fx, g.fy, g.cx, g.cy, g.baseline_m) == (fx, fy, cx, cy, baseline)
                and np.array_equal(g.R_base_cam, R_base_cam)):
            return None
        g.fx, g.fy, g.cx, g.cy, g.baseline_m = fx, fy, cx, cy, baseline
        g.R_base_cam = R_base_cam
        raw = '' if left_model is None else ', raw images (rectified through D, R, P)'
        return 'info', (f'intrinsics from camera_info: fx {fx:.2f} fy {fy:.2f} cx {cx:.2f} '
                        f'cy {cy:.2f} px, baseline {baseline:.4f} m{raw}')


def _fill_pose(pose_msg, est):
    p, q = est.position_m, est.quat_xyzw
    pose_msg.position.x, pose_msg.position.y, pose_msg.position.z = (float(v) for v in p)
    (pose_msg.orientation.x, pose_msg.orientation.y, pose_msg.orientation.z,
     pose_msg.orientation.w) = (float(v) for v in q)


def attitude_aid_message(aid, map_frame):
    """AttitudeAid → PoseWithCovarianceStamped for the compensator's ``attitude_aiding``.

    The orientation carries the attitude the lamp shows; the rotation block of the
    covariance (rows/columns 3-5, about map x, y, z) its 3×3 covariance. The position
    is the fix's chainage on the track; its variances are marked unknown (1e6), since
    only the attitude is offered.
    """
    msg = PoseWithCovarianceStamped()
    msg.header.stamp = ns_to_stamp(aid.stamp_ns)
    msg.header.frame_id = map_frame
    msg.pose.pose.position.x = float(aid.chainage_m)
    q = msg.pose.pose.orientation
    q.x, q.y, q.z, q.w = (float(v) for v in aid.quat_xyzw)
    cov = np.diag([1e6, 1e6, 1e6, 0.0, 0.0, 0.0])
    cov[3:, 3:] = aid.cov_rad2
    msg.pose.covariance = cov.reshape(-1).tolist()
    return msg


def pose_covariance_6x6(est):
    """Row-major 6×6 (x, y, z, rot x, rot y, rot z) covariance of a PoseEstimate."""
    cov = np.zeros((6, 6))
    cov[:3, :3] = est.position_cov_m2
    cov[3:, 3:] = est.attitude_cov_rad2
    return cov


def pose_messages(est, map_frame, base_frame):
    """PoseStamped, PoseWithCovarianceStamped and Odometry of one PoseEstimate.

    All stamped with the instant the estimate describes. The odometry twist is in
    ``base_frame`` axes (nav_msgs convention): the along-track speed rotated by the
    attitude, and the IMU's angular rate; a raw fix (no speed) gets a twist covariance
    of 1e6 on the linear axes.
    """
    stamp = ns_to_stamp(est.stamp_ns)
    ps = PoseStamped()
    ps.header.stamp, ps.header.frame_id = stamp, map_frame
    _fill_pose(ps.pose, est)
    pwc = PoseWithCovarianceStamped()
    pwc.header.stamp, pwc.header.frame_id = stamp, map_frame
    _fill_pose(pwc.pose.pose, est)
    cov = pose_covariance_6x6(est)
    pwc.pose.covariance = [float(v) for v in cov.ravel()]
    odom = Odometry()
    odom.header.stamp, odom.header.frame_id = stamp, map_frame
    odom.child_frame_id = base_frame
    _fill_pose(odom.pose.pose, est)
    odom.pose.covariance = pwc.pose.covariance
    x, y, z, w = est.quat_xyzw
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    speed_known = math.isfinite(est.speed_mps)
    v_body = R.T @ np.array([est.speed_mps if speed_known else 0.0, 0.0, 0.0])
    t = odom.twist.twist
    t.linear.x, t.linear.y, t.linear.z = (float(v) for v in v_body)
    t.angular.x, t.angular.y, t.angular.z = (float(v) for v in est.angular_velocity_rps)
    tcov = np.zeros((6, 6))
    tcov[0, 0] = est.speed_var if speed_known else 1e6
    tcov[1, 1] = tcov[2, 2] = 1e-4 if speed_known else 1e6
    tcov[3, 3] = tcov[4, 4] = tcov[5, 5] = 1e-4
    odom.twist.covariance = [float(v) for v in tcov.ravel()]
    return ps, pwc, odom
