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


# --- malformed input: what the conversions make of the fault injector's kinds ----------

def _imu(cov=None, quat=(0.0, 0.0, 0.0, 1.0)):
    msg = Imu()
    msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w = quat
    msg.linear_acceleration.z = 9.80665
    msg.orientation_covariance = list(np.ravel(np.eye(3) * 1e-6 if cov is None else cov))
    return msg


@pytest.mark.parametrize('change', [
    lambda m: setattr(m.angular_velocity, 'x', math.nan),
    lambda m: setattr(m.angular_velocity, 'y', math.inf),
    lambda m: setattr(m.linear_acceleration, 'z', math.nan),
    lambda m: setattr(m.linear_acceleration, 'x', -math.inf),
    lambda m: setattr(m.orientation, 'w', math.nan),
    lambda m: setattr(m.orientation, 'z', math.inf),
    lambda m: [setattr(m.orientation, a, 0.0) for a in 'xyzw'],
    lambda m: setattr(m, 'orientation_covariance', [math.nan] * 9),
], ids=['nan_gyro', 'inf_gyro', 'nan_accel', 'inf_accel', 'nan_orientation',
        'inf_orientation', 'zero_quaternion', 'nan_covariance'])
def test_non_finite_imu_samples_are_not_finite(change):
    """The localizer core skips (and counts) every sample whose is_finite() is False."""
    msg = _imu()
    assert conversions.imu_from_msg(msg).is_finite()
    change(msg)
    assert not conversions.imu_from_msg(msg).is_finite()


def test_huge_or_negative_attitude_variances_are_bounded():
    """A compensator after a long gap (or a bad message) can send 1e300 rad²; the fix's
    normal equations then became singular and the node died (LinAlgError).
    """
    cov = conversions.imu_from_msg(_imu(np.diag([1e300, -1.0, 1e-6]))).attitude_cov_rad2
    np.testing.assert_allclose(np.diag(cov), [math.pi ** 2, 0.0, 1e-6])
    small = np.diag([1e-6, 2e-6, 3e-6])
    np.testing.assert_array_equal(conversions.imu_from_msg(_imu(small)).attitude_cov_rad2,
                                  small)


def test_a_localizer_fed_an_enormous_attitude_covariance_keeps_fixing():
    from train_localizer.core.localizer import Localizer
    from vlc_stereo_camera.core.upstream import LAMPS, constant_speed_run
    from vlc_stereo_camera.upstream_messages import imu_msg
    _, events = constant_speed_run(60.0, 3.0, seed=23)
    loc = Localizer(LAMPS)
    t0, accepted_after = events[0][0], 0
    for t, kind, payload in events:
        if kind == 'imu':
            msg = imu_msg(payload)
            if 1.0 < t - t0 < 1.5:
                msg.orientation_covariance = list(np.ravel(np.eye(3) * 1e300))
            loc.add_imu(conversions.imu_from_msg(msg))
        else:
            report = loc.add_frame(payload[0], payload[1])
            if t - t0 > 1.5:
                accepted_after += sum(f.status == 'accepted' for f in report.fixes)
    assert loc.initialized and accepted_after > 10


def _clouds(spoil=None, n=1, nan=False):
    """A spots/pairs and a vlc/lamps cloud of ``n`` records in the documented layouts,
    ``spoil(cloud)`` applied to both.
    """
    from vlc_common.core.records import LAMP_DTYPE, PAIR_DTYPE
    from vlc_common.pointcloud import records_to_cloud
    from vlc_common.stamps import header
    out = {}
    for topic, dtype in (('spots/pairs', PAIR_DTYPE), ('vlc/lamps', LAMP_DTYPE)):
        rec = np.ones(n, dtype=dtype)
        if nan:
            for name in dtype.names:
                if rec.dtype[name].kind == 'f':
                    rec[name] = math.nan
        cloud = records_to_cloud(rec, header(10 ** 18, 'camera_left_optical_frame'))
        if spoil is not None:
            spoil(cloud)
        out[topic] = cloud
    return out


def _float64_for_float32(cloud):
    for f in cloud.fields:
        if f.datatype == PointField.FLOAT32:
            f.datatype = PointField.FLOAT64


def _point_step(cloud):
    cloud.point_step -= 8
    cloud.data = bytes(cloud.data)[:cloud.point_step]


REQUIRED = {'spots/pairs': ('u_left', 'v_left', 'u_right', 'v_right'), 'vlc/lamps': ('uid',)}


@pytest.mark.parametrize('spoil', [
    _float64_for_float32,
    lambda c: setattr(c, 'fields', [f for f in c.fields if f.name not in ('u_left', 'uid')]),
    _point_step,
    lambda c: setattr(c, 'width', 2),
    lambda c: setattr(c, 'is_bigendian', True),
], ids=['float64_for_float32', 'missing_field', 'wrong_point_step', 'data_length',
        'bigendian'])
def test_malformed_clouds_are_refused_naming_the_topic(spoil):
    for topic, cloud in _clouds(spoil).items():
        with pytest.raises(ValueError, match=topic):
            conversions.records_from_cloud(cloud, topic, REQUIRED[topic])


def test_empty_and_nan_clouds_read_and_their_records_are_not_fixes():
    from train_localizer.core.join import join_frame
    empty = _clouds(n=0)
    assert conversions.records_from_cloud(empty['spots/pairs'], 'spots/pairs',
                                          REQUIRED['spots/pairs']).size == 0
    nan = {t: conversions.records_from_cloud(c, t, REQUIRED[t])
           for t, c in _clouds(nan=True).items()}
    obs, unmatched = join_frame(10 ** 18, nan['spots/pairs'], nan['vlc/lamps'])
    assert len(obs) == 1 and not obs[0].is_finite() and unmatched == 1


def test_an_absurd_exposure_offset_is_treated_as_unknown():
    """A finite but absurd stamp_offset_s (1e300 s) overflowed the measurement time."""
    from train_localizer.core.fix import RigGeometry, measurement_time_ns
    from train_localizer.core.join import observations_from_spots
    from vlc_common.core.records import PAIR_DTYPE
    rec = np.zeros(1, dtype=PAIR_DTYPE)
    rec['u_left'], rec['v_left'], rec['u_right'], rec['v_right'] = 700.0, 520.0, 680.0, 520.0
    rec['stamp_offset_s'] = 1e300
    [obs] = observations_from_spots(10 ** 18, rec)
    assert math.isnan(obs.exposure_mid_offset_s)
    assert abs(measurement_time_ns(obs, RigGeometry()) - 10 ** 18) < 10 ** 8


def test_the_bounds_check_without_eigh_agrees_with_eigh():
    """Covariances the shortcut passes as they are (positive definite, in bounds) are
    those eigh passes; the others are clipped by eigh as before.
    """
    rng = np.random.default_rng(11)
    for scale in (1e-8, 1e-4, 1.0, 3.0):
        for _ in range(200):
            a = rng.normal(size=(3, 3)) * math.sqrt(scale)
            cov = a @ a.T + np.diag(rng.uniform(0.0, scale, 3))
            values, vectors = np.linalg.eigh(0.5 * (cov + cov.T))
            expected = (0.5 * (cov + cov.T) if np.all((values >= 0.0)
                                                      & (values <= math.pi ** 2))
                        else (vectors * np.clip(values, 0.0, math.pi ** 2)) @ vectors.T)
            np.testing.assert_allclose(conversions._bounded_covariance(cov), expected,
                                       rtol=1e-9, atol=1e-12 * scale)
    singular = np.outer([1.0, 2.0, 3.0], [1.0, 2.0, 3.0]) * 1e-4
    np.testing.assert_allclose(conversions._bounded_covariance(singular), singular,
                               atol=1e-15)
