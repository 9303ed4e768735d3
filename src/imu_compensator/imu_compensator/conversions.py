"""sensor_msgs/Imu and geometry_msgs messages ↔ the arrays of ``imu_compensator.core``.

Consumers of ``imu/data`` (the localizer) can use :func:`imu_attitude` to feed an
:class:`~imu_compensator.core.attitude_buffer.AttitudeBuffer`::

    t_s, quat, cov = imu_attitude(msg)
    buffer.push(t_s, quat, cov)
    q = buffer.at(exposure_mid_time_s)
"""
import math

import numpy as np

from vlc_common.stamps import stamp_to_ns, stamp_to_s  # noqa: F401 (stamp_to_ns re-exported)


def imu_sample(msg):
    """(t_s, gyro (3,) rad/s, specific force (3,) m/s²) of a sensor_msgs/Imu."""
    av, la = msg.angular_velocity, msg.linear_acceleration
    return (stamp_to_s(msg.header.stamp), np.array([av.x, av.y, av.z]),
            np.array([la.x, la.y, la.z]))


def odometry_speed(msg):
    """(t_s, speed m/s, its variance or None) of a nav_msgs/Odometry.

    The speed is the magnitude of ``twist.twist.linear`` (train_localizer: the
    along-track speed rotated into ``base_link``); its variance ``twist.covariance[0]``,
    None when not positive (not stated). Values are not checked here (see
    :meth:`~imu_compensator.core.compensator.AttitudeCompensator.odometry`).
    """
    v = msg.twist.twist.linear
    speed = math.sqrt(float(v.x) ** 2 + float(v.y) ** 2 + float(v.z) ** 2)
    var = float(msg.twist.covariance[0])
    return stamp_to_s(msg.header.stamp), speed, (var if not var <= 0.0 else None)


def imu_attitude(msg):
    """(t_s, quat_xyzw (4,), covariance (3, 3) rad² or None) of an ``imu/data`` message.

    The covariance is None when the message marks it unknown (REP-145:
    ``orientation_covariance[0] == -1``).
    """
    o = msg.orientation
    cov = np.array(msg.orientation_covariance, dtype=float).reshape(3, 3)
    return (stamp_to_s(msg.header.stamp), np.array([o.x, o.y, o.z, o.w]),
            None if cov[0, 0] == -1.0 else cov)


def _covariance(values):
    """3×3 covariance of a message field, or None when unknown (−1) or all zero."""
    cov = np.array(values, dtype=float).reshape(3, 3)
    if cov[0, 0] < 0.0 or not np.any(cov) or not np.all(np.isfinite(cov)):
        return None
    return cov


#: {(field bytes, mount bytes): covariance in base_link or None}: a driver states the
#: same raw covariances in every message, so they are read and rotated once.
_IN_BASE = {}


def _covariance_in_base(values, r_base_imu):
    """:func:`_covariance` of a raw message field rotated into ``base_link`` (a fresh
    array each call), memoised on the field's and the mount's values.
    """
    key = (np.asarray(values, dtype=float).tobytes(),
           None if r_base_imu is None else r_base_imu.tobytes())
    cov = _IN_BASE.get(key, False)
    if cov is False:
        cov = _covariance(values)
        if cov is not None and r_base_imu is not None:
            cov = r_base_imu @ cov @ r_base_imu.T
        if len(_IN_BASE) > 64:
            _IN_BASE.clear()
        _IN_BASE[key] = cov
    return None if cov is None else cov.copy()


def fill_imu_data(out, header, result, orientation_floor_var_rad2, gyro_white_var,
                  gyro_bias_var, rate_cov_in, accel_cov_in, r_base_imu=None):
    """Write one compensated sample into the reusable message ``out``; returns it.

    Parameters
    ----------
    out : sensor_msgs.msg.Imu
        Message to overwrite (its ``header.frame_id`` is kept: the base frame).
    header : std_msgs.msg.Header
        Header of the raw sample; its stamp is copied (the sample time, never now()).
    result : imu_compensator.core.compensator.SampleResult
        An accepted sample.
    orientation_floor_var_rad2 : ndarray (3,)
        Variance added to the filter's roll, pitch, heading variance (model errors the
        filter does not carry: gyro scale factor, vibration leakage), rad².
    gyro_white_var : float
        Per-sample gyro white-noise variance used when the raw message has none, (rad/s)².
    gyro_bias_var : ndarray (3,)
        Variance of the bias estimate, (rad/s)², added to the rate covariance.
    rate_cov_in, accel_cov_in : sequence of 9 floats
        Covariances of the raw message.
    r_base_imu : ndarray (3, 3), optional
        Mount rotation imu_link → base_link; rotates the raw covariances.
    """
    out.header.stamp = header.stamp
    q = result.quat_xyzw
    o = out.orientation
    o.x, o.y, o.z, o.w = float(q[0]), float(q[1]), float(q[2]), float(q[3])
    # (float64 arrays of 9 go into the message as they are; a list is checked item by
    # item by the generated setter)
    cov = np.array(result.covariance, dtype=float).reshape(9)
    cov[::4] += orientation_floor_var_rad2
    out.orientation_covariance = cov

    w = result.gyro_rps
    av = out.angular_velocity
    av.x, av.y, av.z = float(w[0]), float(w[1]), float(w[2])
    rate_cov = _covariance_in_base(rate_cov_in, r_base_imu)
    if rate_cov is None:
        rate_cov = np.eye(3) * gyro_white_var
    rate_cov = rate_cov.reshape(9)
    rate_cov[::4] += gyro_bias_var
    out.angular_velocity_covariance = rate_cov

    f = result.accel_mps2
    la = out.linear_acceleration
    la.x, la.y, la.z = float(f[0]), float(f[1]), float(f[2])
    acc_cov = _covariance_in_base(accel_cov_in, r_base_imu)
    out.linear_acceleration_covariance = (
        np.array([-1.0] + [0.0] * 8) if acc_cov is None else acc_cov.reshape(9))
    return out


def pose_heading(msg):
    """(t_s, yaw rad, yaw variance rad² or nan) of a PoseWithCovarianceStamped.

    The yaw is that of R = Rz·Ry·Rx of the pose's orientation; the variance is the
    (yaw, yaw) element of the 6×6 covariance (index 35), nan when ≤ 0.
    """
    o = msg.pose.pose.orientation
    x, y, z, w = o.x, o.y, o.z, o.w
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if not (norm > 0.0 and math.isfinite(norm)):
        return stamp_to_s(msg.header.stamp), float('nan'), float('nan')
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    var = float(msg.pose.covariance[35])
    return stamp_to_s(msg.header.stamp), yaw, var if var > 0.0 else float('nan')


def pose_attitude(msg):
    """(t_s, quat_xyzw (4,), covariance (3, 3) rad² or None) of a PoseWithCovarianceStamped.

    The covariance is the rotation block (rows/columns 3-5, about x, y, z) of the 6×6
    covariance; None unless it is finite, symmetric and positive definite — a message
    that only fills covariance[35] (a heading) gives None, see :func:`pose_heading`.
    """
    o = msg.pose.pose.orientation
    cov = np.array(msg.pose.covariance, dtype=float).reshape(6, 6)[3:, 3:]
    ok = (np.all(np.isfinite(cov)) and np.allclose(cov, cov.T, rtol=1e-9, atol=1e-15)
          and np.all(np.linalg.eigvalsh(0.5 * (cov + cov.T)) > 0.0))
    return (stamp_to_s(msg.header.stamp), np.array([o.x, o.y, o.z, o.w], dtype=float),
            0.5 * (cov + cov.T) if ok else None)


def fuse_aiding(compensator, msg, heading_std_rad):
    """Fuse one ``attitude_aiding`` message into an ``AttitudeCompensator``.

    The full attitude when the rotation block of its covariance is usable
    (:func:`pose_attitude`), else only its heading (:func:`pose_heading`), with
    ``heading_std_rad`` when covariance[35] is not positive either.

    Returns
    -------
    (AidingResult, float)
        What was done with it (true when it was applied), and its stamp (s).
    """
    t_s, quat, cov = pose_attitude(msg)
    if cov is not None:
        return compensator.attitude_aiding(t_s, quat, cov), t_s
    t_s, yaw, var = pose_heading(msg)
    if not math.isfinite(var):
        var = heading_std_rad ** 2
    return compensator.heading_aiding(t_s, yaw, var), t_s
