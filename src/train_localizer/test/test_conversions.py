"""Message conversions of the localizer."""
import math

import numpy as np
import pytest

pytest.importorskip('rclpy')

from sensor_msgs.msg import CameraInfo, Imu, PointCloud2, PointField  # noqa: E402

from train_localizer import conversions  # noqa: E402
from train_localizer.core.reports import PoseEstimate  # noqa: E402


def test_stamps_round_trip_exactly():
    ns = 1_704_067_200_123_456_789
    assert conversions.stamp_to_ns(conversions.ns_to_stamp(ns)) == ns


def test_cloud_to_records_reads_both_endians_and_refuses_bad_clouds():
    for big, order in ((False, '<'), (True, '>')):
        data = np.array([(1.5, 7)], dtype=[('a', order + 'f8'), ('b', order + 'u4')])
        msg = PointCloud2(height=1, width=1, point_step=12, is_bigendian=big,
                          fields=[PointField(name='a', offset=0, datatype=8, count=1),
                                  PointField(name='b', offset=8, datatype=6, count=1)],
                          data=data.tobytes())
        rec = conversions.cloud_to_records(msg)
        assert rec['a'][0] == 1.5 and rec['b'][0] == 7
    msg.data = msg.data[:5]
    with pytest.raises(ValueError, match='point cloud data'):
        conversions.cloud_to_records(msg)
    msg.fields[0].datatype = 99
    with pytest.raises(ValueError, match='datatype'):
        conversions.cloud_to_records(msg)
    with pytest.raises(ValueError, match='missing fields u_right'):
        conversions.require_fields(np.zeros(1, dtype=[('u_left', 'f8')]), ('u_left', 'u_right'),
                                   'spots/pairs')


def test_imu_without_orientation_or_covariance():
    msg = Imu()
    msg.orientation.w = 1.0
    msg.orientation_covariance[0] = -1.0
    assert conversions.imu_from_msg(msg).quat_xyzw is None
    msg.orientation_covariance = [0.0] * 9
    sample = conversions.imu_from_msg(msg)
    assert sample.quat_xyzw is not None and sample.attitude_cov_rad2 is None


def test_camera_info_gives_intrinsics_and_baseline():
    left, right = CameraInfo(), CameraInfo()
    left.p = [1040.0, 0.0, 639.5, 0.0, 0.0, 1040.0, 359.5, 0.0, 0.0, 0.0, 1.0, 0.0]
    right.p = list(left.p)
    right.p[3] = -1040.0 * 0.12
    assert conversions.intrinsics_from_camera_info(left, right) == pytest.approx(
        (1040.0, 1040.0, 639.5, 359.5, 0.12))
    right.p[3] = 10.0
    with pytest.raises(ValueError, match='baseline'):
        conversions.intrinsics_from_camera_info(left, right)


def test_pose_messages_carry_stamp_covariance_and_body_speed():
    yaw = 0.1
    est = PoseEstimate(stamp_ns=1_704_067_200_020_000_000, position_m=np.array([12.0, 0.0, 0.0]),
                       position_cov_m2=np.diag([1e-4, 1.6e-5, 1.6e-5]), speed_mps=10.0,
                       speed_var=1e-3,
                       quat_xyzw=np.array([0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)]),
                       attitude_cov_rad2=np.eye(3) * 1e-6, angular_velocity_rps=np.zeros(3),
                       kind='grid')
    ps, pwc, odom = conversions.pose_messages(est, 'map', 'base_link')
    assert conversions.stamp_to_ns(ps.header.stamp) == est.stamp_ns
    assert ps.pose.position.x == 12.0 and pwc.pose.covariance[0] == 1e-4
    assert pwc.pose.covariance[21] == 1e-6
    assert odom.child_frame_id == 'base_link'
    assert odom.twist.twist.linear.x == pytest.approx(10.0 * math.cos(yaw))
    assert odom.twist.twist.linear.y == pytest.approx(-10.0 * math.sin(yaw))
