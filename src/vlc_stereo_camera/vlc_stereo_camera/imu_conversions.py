"""IMU arrays ↔ sensor_msgs/Imu."""
from sensor_msgs.msg import Imu

from vlc_common.stamps import stamp_to_ns


def imu_message(stamp_ns, frame_id, omega, f, gyro_variance, accel_variance):
    """One sensor_msgs/Imu without orientation.

    Parameters
    ----------
    stamp_ns : int
        Sample time, ns since the Unix epoch.
    frame_id : str
    omega : sequence of 3 float
        Angular rate, rad/s.
    f : sequence of 3 float
        Specific force (``linear_acceleration``), m/s².
    gyro_variance, accel_variance : float
        Per-axis white-noise variance per sample, (rad/s)² and (m/s²)²; written on the
        covariance diagonals.
    """
    msg = Imu()
    msg.header.frame_id = frame_id
    # REP-145: orientation_covariance[0] = -1 marks the orientation as not provided.
    msg.orientation_covariance[0] = -1.0
    for i in (0, 4, 8):
        msg.angular_velocity_covariance[i] = gyro_variance
        msg.linear_acceleration_covariance[i] = accel_variance
    return set_imu_sample(msg, stamp_ns, omega, f)


def set_imu_sample(msg, stamp_ns, omega, f):
    """Overwrite the stamp, angular rate and specific force of ``msg``; returns it.

    Lets a publisher refill one message per sample instead of building a new one
    (``publish`` serialises the message at once).
    """
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    av, la = msg.angular_velocity, msg.linear_acceleration
    av.x, av.y, av.z = float(omega[0]), float(omega[1]), float(omega[2])
    la.x, la.y, la.z = float(f[0]), float(f[1]), float(f[2])
    return msg


def imu_arrays(msg):
    """(stamp_ns, omega (3,), f (3,)) of a sensor_msgs/Imu, plain floats."""
    av, la = msg.angular_velocity, msg.linear_acceleration
    return stamp_to_ns(msg.header.stamp), (av.x, av.y, av.z), (la.x, la.y, la.z)
