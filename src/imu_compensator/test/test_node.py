"""imu_compensator_node in-process: outputs, stamps, bad input, diagnostics, parameters.

Every test runs the node and a probe node in their own rclpy Context on an isolated DDS
domain (``ros_env``).
"""
import math
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.exceptions import ParameterException
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Imu

from imu_compensator.imu_compensator_node import ImuCompensatorNode
from vlc_common.core.vehicle import ImuMount, VehicleMount

pytestmark = pytest.mark.ros

EPOCH_NS = 1704067200 * 10 ** 9
PERIOD_NS = 2_500_000


def raw(stamp_ns, gyro=(0.0, 0.0, 0.0), accel=(0.0, 0.0, 9.80665), frame='imu_link'):
    msg = Imu()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp_ns), 10 ** 9)
    msg.header.frame_id = frame
    msg.orientation_covariance[0] = -1.0
    msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = gyro
    msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z = accel
    for i in (0, 4, 8):
        msg.angular_velocity_covariance[i] = 2.3e-6
        msg.linear_acceleration_covariance[i] = 9.3e-5
    return msg


@pytest.fixture
def ctx(ros_env):
    context = Context()
    rclpy.init(context=context)
    yield context
    rclpy.shutdown(context=context)


class Harness:
    def __init__(self, ctx, **params):
        overrides = [Parameter('diagnostics_period_s', value=0.1)] + [
            Parameter(k, value=v) for k, v in params.items()]
        self.node = ImuCompensatorNode(context=ctx, parameter_overrides=overrides)
        self.probe = Node('probe', context=ctx)
        self.pub = self.probe.create_publisher(Imu, 'imu/data_raw', qos_profile_sensor_data)
        self.out, self.diags = [], []
        self.probe.create_subscription(Imu, 'imu/data', self.out.append,
                                       qos_profile_sensor_data)
        self.probe.create_subscription(DiagnosticArray, 'diagnostics', self.diags.append, 50)
        self.executor = SingleThreadedExecutor(context=ctx)
        self.executor.add_node(self.node)
        self.executor.add_node(self.probe)
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and (
                self.pub.get_subscription_count() == 0
                or self.node.count_subscribers('imu/data') == 0):
            self.executor.spin_once(timeout_sec=0.05)

    def send(self, msgs):
        """Publish one by one, spinning in between (best-effort QoS: do not flood)."""
        for msg in msgs:
            self.pub.publish(msg)
            for _ in range(3):
                self.executor.spin_once(timeout_sec=0.002)

    def spin_until(self, predicate, timeout=5.0):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not predicate():
            self.executor.spin_once(timeout_sec=0.02)
        return predicate()

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        self.probe.destroy_node()


def stamp_ns(msg):
    return msg.header.stamp.sec * 10 ** 9 + msg.header.stamp.nanosec


def test_output_is_stamped_with_the_sample_time_and_bad_input_is_skipped(ctx):
    h = Harness(ctx)
    try:
        good = [raw(EPOCH_NS + k * PERIOD_NS, gyro=(0.002, -0.001, 0.0005)) for k in range(20)]
        last = EPOCH_NS + 19 * PERIOD_NS
        bad = [raw(last + PERIOD_NS, gyro=(math.nan, 0.0, 0.0)),       # non-finite
               raw(last + PERIOD_NS, accel=(0.0, math.inf, 9.8)),      # non-finite
               raw(last),                                              # duplicate
               raw(last - 10 * PERIOD_NS)]                             # out of order
        after = [raw(last + PERIOD_NS),
                 raw(last - 5 * 10 ** 9),                              # back 5 s: reset
                 raw(last - 5 * 10 ** 9 + PERIOD_NS),
                 raw(last - 5 * 10 ** 9 + PERIOD_NS + 300_000_000),   # 0.3 s gap
                 raw(last - 5 * 10 ** 9 + 2 * PERIOD_NS + 300_000_000)]
        h.send(good + bad + after)
        expected = [stamp_ns(m) for m in good + after]
        assert h.spin_until(lambda: len(h.out) >= len(expected))
        assert [stamp_ns(m) for m in h.out] == expected
        for msg in h.out:
            q = np.array([msg.orientation.x, msg.orientation.y, msg.orientation.z,
                          msg.orientation.w])
            assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-9)
            assert msg.header.frame_id == 'base_link'
            cov = np.array(msg.orientation_covariance).reshape(3, 3)
            assert np.all(np.diag(cov) > 0.0) and np.allclose(cov, cov.T)
            assert msg.angular_velocity_covariance[0] > 2.3e-6
            assert msg.linear_acceleration_covariance[0] == pytest.approx(9.3e-5)
        s = h.node.compensator.stats
        assert (s.nonfinite, s.duplicate, s.out_of_order, s.resets, s.gaps) == (2, 1, 1, 1, 1)
        assert h.spin_until(lambda: any(
            {kv.key: kv.value for kv in d.status[0].values}.get('resets') == '1'
            for d in h.diags))
        values = {kv.key: kv.value for kv in h.diags[-1].status[0].values}
        for key in ('gyro_bias_deg_h', 'gyro_bias_std_deg_h', 'zero_velocity', 'sample_rate_hz',
                    'samples_dropped', 'gaps', 'resets'):
            assert key in values
        assert values['samples_dropped'] == '4'
    finally:
        h.close()


def test_a_lone_1970_or_future_sample_neither_resets_nor_propagates_the_filter(ctx):
    """Samples stamped 1970 (sec 0), a year ahead and 5 s back, each alone between real
    ones: dropped and counted, no reset, no gap; the attitude and its covariance go on
    as if they had never come.
    """
    h = Harness(ctx)
    try:
        good = [raw(EPOCH_NS + k * PERIOD_NS, gyro=(0.002, -0.001, 0.0005)) for k in range(60)]
        lone = [raw(0), raw(EPOCH_NS + 365 * 86400 * 10 ** 9), raw(EPOCH_NS - 5 * 10 ** 9)]
        mixed = good[:20] + [lone[0]] + good[20:40] + [lone[1]] + good[40:50] + [lone[2]] \
            + good[50:]
        h.send(mixed)
        assert h.spin_until(lambda: len(h.out) >= len(good))
        assert [stamp_ns(m) for m in h.out] == [stamp_ns(m) for m in good]
        s = h.node.compensator.stats
        assert (s.resets, s.gaps, s.dropped) == (0, 0, 0)
        assert h.node._guard.stats.outliers == 3
        heading_var = h.out[-1].orientation_covariance[8]
        # the cold start's (5 deg)^2, not blown up by a propagation across decades
        assert 0.0 < heading_var < 0.01
        assert h.spin_until(lambda: any(
            {kv.key: kv.value for kv in d.status[0].values}.get('dropped_stamp_outliers')
            == '3' for d in h.diags))
        values = {kv.key: kv.value for kv in h.diags[-1].status[0].values}
        assert values['samples_dropped'] == '3' and values['resets'] == '0'
    finally:
        h.close()


def aid(stamp_ns, quat, cov3=None, yaw_var=0.0):
    msg = PoseWithCovarianceStamped()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp_ns), 10 ** 9)
    msg.header.frame_id = 'map'
    o = msg.pose.pose.orientation
    o.x, o.y, o.z, o.w = (float(v) for v in quat)
    cov = np.diag([1e6, 1e6, 1e6, 0.0, 0.0, yaw_var])
    if cov3 is not None:
        cov[3:, 3:] = cov3
    msg.pose.covariance = cov.ravel().tolist()
    return msg


def test_attitude_aiding_full_heading_only_and_malformed(ctx):
    # 0.6° aids on a filter aligned to 0.02°: the gate (next test) would refuse them.
    h = Harness(ctx, aiding_gate_probability=1.0)
    try:
        aid_pub = h.probe.create_publisher(PoseWithCovarianceStamped, 'attitude_aiding', 10)
        h.send([raw(EPOCH_NS + k * PERIOD_NS) for k in range(400)])
        assert h.spin_until(lambda: len(h.out) >= 350)
        t_aid = EPOCH_NS + 300 * PERIOD_NS
        half = 0.5 * 0.01
        # sees roll only: roll +0.01
        msgs = [aid(t_aid, [math.sin(half), 0.0, 0.0, math.cos(half)], np.diag([1e-11, 1, 1])),
                # heading only (the rotation block is not positive definite): yaw +0.01
                aid(t_aid, [0.0, 0.0, math.sin(half), math.cos(half)], yaw_var=1e-11),
                aid(t_aid, [0.0, 0.0, 0.0, 0.0], np.eye(3) * 1e-8)]   # zero quaternion
        deadline = time.monotonic() + 5.0
        while aid_pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            h.executor.spin_once(timeout_sec=0.02)
        for msg in msgs:
            aid_pub.publish(msg)
        s = h.node.compensator.stats
        assert h.spin_until(lambda: s.aiding_used + s.aiding_rejected >= 3)
        assert (s.aiding_used, s.aiding_rejected) == (2, 1)
        roll, _, yaw = h.node.compensator.filter.rpy_rad
        assert roll == pytest.approx(0.01, abs=1e-3) and yaw == pytest.approx(0.01, abs=1e-3)
        assert h.spin_until(lambda: any(
            {kv.key: kv.value for kv in d.status[0].values}.get('attitude_aiding_used') == '2'
            for d in h.diags))
    finally:
        h.close()


def test_inconsistent_aiding_is_rejected_counted_and_reported(ctx):
    h = Harness(ctx)
    try:
        aid_pub = h.probe.create_publisher(PoseWithCovarianceStamped, 'attitude_aiding', 10)
        h.send([raw(EPOCH_NS + k * PERIOD_NS) for k in range(400)])
        assert h.spin_until(lambda: len(h.out) >= 350)
        deadline = time.monotonic() + 5.0
        while aid_pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            h.executor.spin_once(timeout_sec=0.02)
        rpy_before = h.node.compensator.filter.rpy_rad
        # The aligned filter is sure of its attitude to 0.02°: an aid 0.6° away in roll
        # that claims 0.0002° is inconsistent with it.
        half = 0.5 * 0.01
        aid_pub.publish(aid(EPOCH_NS + 300 * PERIOD_NS, [math.sin(half), 0.0, 0.0, math.cos(half)],
                            np.diag([1e-11, 1, 1])))
        s = h.node.compensator.stats
        assert h.spin_until(lambda: s.aiding_rejected >= 1)
        assert (s.aiding_used, s.aiding_inconsistent) == (0, 1)
        np.testing.assert_array_equal(h.node.compensator.filter.rpy_rad, rpy_before)

        def reported(d):
            values = {kv.key: kv.value for kv in d.status[0].values}
            return values.get('attitude_aiding_inconsistent') == '1' \
                and d.status[0].message.startswith('attitude aiding inconsistent')
        assert h.spin_until(lambda: any(reported(d) for d in h.diags))
        values = {kv.key: kv.value for kv in h.diags[-1].status[0].values}
        for key in ('attitude_aiding_resets', 'attitude_aiding_reinitialisations'):
            assert values[key] == '0'
    finally:
        h.close()


def odometry(stamp_ns, speed, var=1e-4):
    msg = Odometry()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp_ns), 10 ** 9)
    msg.header.frame_id, msg.child_frame_id = 'map', 'base_link'
    msg.twist.twist.linear.x = float(speed)
    cov = [0.0] * 36
    cov[0] = var
    msg.twist.covariance = cov
    return msg


def test_odometry_vetoes_the_standstill_of_an_accelerating_train_and_bad_ones_are_ignored(ctx):
    """A steady 0.5 m/s^2 without vibration: the IMU alone finds it still; train/odometry
    showing the acceleration vetoes that for the samples within odometry_timeout_s of it.
    A non-finite speed and a raw fix's unknown speed (variance 1e6) are not used.
    """
    h = Harness(ctx)
    try:
        odo_pub = h.probe.create_publisher(Odometry, 'train/odometry', 10)
        deadline = time.monotonic() + 5.0
        while odo_pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            h.executor.spin_once(timeout_sec=0.02)
        s = h.node.compensator.stats
        # speeds stamped 0 ... 1.2 s, newest at 1.2 s: IMU samples after 0.7 s are vetoed
        msgs = [odometry(EPOCH_NS + k * 20_000_000, 0.5 * 0.02 * k) for k in range(61)] + [
            odometry(EPOCH_NS + 1_300_000_000, math.nan),
            odometry(EPOCH_NS + 1_300_000_000, 5.0, var=1e6)]
        for n, msg in enumerate(msgs):         # depth 10: one at a time
            odo_pub.publish(msg)
            want = min(n + 1, 62)
            h.spin_until(lambda want=want: s.odometry_used + s.odometry_rejected >= want, 1.0)
        assert h.spin_until(lambda: s.odometry_used + s.odometry_rejected >= 62)
        assert (s.odometry_used, s.odometry_rejected) == (61, 1)
        assert h.node.compensator.odometry_veto.acceleration_mps2 == pytest.approx(0.5)
        h.send([raw(EPOCH_NS + k * PERIOD_NS, accel=(0.5, 0.0, 9.80665)) for k in range(400)])
        assert h.spin_until(lambda: len(h.out) >= 400)
        # window full at sample 200 (0.5 s): still until 0.7 s (280), vetoed after
        assert s.stationary_samples == pytest.approx(80, abs=2)
        assert s.standstill_vetoed == pytest.approx(120, abs=2)

        def reported(d):
            values = {kv.key: kv.value for kv in d.status[0].values}
            return values.get('standstill_vetoed') == str(s.standstill_vetoed) \
                and values.get('odometry_rejected') == '1' \
                and values.get('zero_velocity') == 'false'
        assert h.spin_until(lambda: any(reported(d) for d in h.diags))
    finally:
        h.close()


def test_decimation_and_mount_rotation(ctx, tmp_path):
    # IMU mounted rolled by 90° (vehicle file): its y axis is base_link's z, so gravity on
    # y in imu_link must come out on z in base_link.
    vehicle = VehicleMount()
    vehicle.imu = ImuMount(rpy_rad=[math.pi / 2, 0.0, 0.0])
    vehicle.save(tmp_path / 'vehicle.yaml')
    h = Harness(ctx, publish_decimation=4, vehicle_path=str(tmp_path / 'vehicle.yaml'))
    try:
        h.send([raw(EPOCH_NS + k * PERIOD_NS, accel=(0.0, 9.80665, 0.0)) for k in range(41)])
        # Sample 0 (start) and every 4th accepted sample after it.
        assert h.spin_until(lambda: len(h.out) >= 11)
        assert [(stamp_ns(m) - EPOCH_NS) // PERIOD_NS for m in h.out] == \
            [0] + list(range(4, 41, 4))
        la = h.out[-1].linear_acceleration
        assert (la.x, la.y, la.z) == pytest.approx((0.0, 0.0, 9.80665), abs=1e-9)
    finally:
        h.close()


def test_invalid_parameters_are_refused(ctx):
    with pytest.raises(ParameterException):
        ImuCompensatorNode(context=ctx, parameter_overrides=[
            Parameter('heading_time_constant_s', value=-1.0)])
    with pytest.raises(ValueError):
        ImuCompensatorNode(context=ctx, parameter_overrides=[
            Parameter('vehicle_path', value='/nonexistent/vehicle.yaml')])
    with pytest.raises(ValueError):
        # A pull time constant shorter than its averaging window.
        ImuCompensatorNode(context=ctx, parameter_overrides=[
            Parameter('heading_time_constant_s', value=1.0)])
