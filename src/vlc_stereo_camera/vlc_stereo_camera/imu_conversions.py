"""IMU arrays → sensor_msgs/Imu, and the simulated clock's stamps."""
from fractions import Fraction

from builtin_interfaces.msg import Time
from sensor_msgs.msg import Imu

NS_PER_S = 1_000_000_000


def epoch_to_ns(epoch_s):
    """Simulated-clock epoch in integer nanoseconds (whole seconds kept exact)."""
    whole = int(epoch_s // 1)
    return whole * NS_PER_S + int(round((epoch_s - whole) * NS_PER_S))


def sample_stamp_ns(epoch_ns, index, rate_hz):
    """Stamp of sample ``index`` of a sensor at ``rate_hz``: epoch + index / rate, in ns.

    Computed in exact rational arithmetic and rounded to the nanosecond once, so stamps
    never accumulate a period's rounding error (at 400 Hz they are exactly 2 500 000 ns
    apart, at 2460 Hz 406 504 or 406 505 ns).
    """
    return epoch_ns + round(int(index) * Fraction(NS_PER_S) / Fraction(rate_hz))


def ns_to_time(stamp_ns):
    """builtin_interfaces/Time from integer nanoseconds."""
    sec, nanosec = divmod(int(stamp_ns), NS_PER_S)
    return Time(sec=sec, nanosec=nanosec)


def time_to_ns(stamp):
    """Integer nanoseconds of a builtin_interfaces/Time."""
    return stamp.sec * NS_PER_S + stamp.nanosec


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
    sec, nanosec = divmod(int(stamp_ns), NS_PER_S)
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    av, la = msg.angular_velocity, msg.linear_acceleration
    av.x, av.y, av.z = float(omega[0]), float(omega[1]), float(omega[2])
    la.x, la.y, la.z = float(f[0]), float(f[1]), float(f[2])
    return msg


def imu_arrays(msg):
    """(stamp_ns, omega (3,), f (3,)) of a sensor_msgs/Imu, plain floats."""
    av, la = msg.angular_velocity, msg.linear_acceleration
    return time_to_ns(msg.header.stamp), (av.x, av.y, av.z), (la.x, la.y, la.z)
