"""Curvature-array correlation on the rig's trajectory and ADIS16488 model
(``curvature_benchmark.simulate``) and on a recorded bag: every test scores against the truth.
"""
import math

import numpy as np
import pytest

from vlc_common.core.alignment import Alignment
from vlc_evaluation.benchmarks import curvature as bench
from vlc_stereo_camera.core.trajectory import MotionProfile
from vlc_stereo_camera.core.upstream import yaw_rate_on_alignment

DEMO = Alignment.named('curved_demo')


def test_rig_imu_run_is_localised_within_metres():
    """ADIS16488 model (bias, noise, scale) on the rig trajectory with its vibration, a
    tachometer with +3 % scale error and 0.05 m/s noise, 80 km/h over 750 m of curves.
    """
    profile = MotionProfile('constant', start_chainage_m=150.0, speed_mps=80 / 3.6)
    inputs = bench.simulate(DEMO, profile, seed=2, imu_rate_hz=100.0,
                            speed_scale_error=0.03, duration_s=750.0 / (80 / 3.6))
    matches = bench.run(inputs, DEMO)
    score = bench.score(matches, inputs)
    assert score.matches == len(matches) >= 30
    assert score.available >= 5
    assert score.max_m < 5.0
    assert score.ratio_median == pytest.approx(1 / 1.03, abs=0.01)
    # Refusals only while the window still holds a single curve (acquisition).
    assert set(score.statuses) <= {'ok', 'too_short', 'imprecise', 'ambiguous'}


def test_chainage_sigma_covers_the_errors_of_a_rig_run():
    """On a run of the rig's IMU every accepted match is within 3σ of the truth."""
    profile = MotionProfile('constant', start_chainage_m=150.0, speed_mps=80 / 3.6)
    inputs = bench.simulate(DEMO, profile, seed=3, imu_rate_hz=100.0,
                            speed_scale_error=0.03, duration_s=900.0 / (80 / 3.6))
    ok = [m for m in bench.run(inputs, DEMO) if m.match.ok]
    assert len(ok) >= 10
    z = [(m.match.chainage_m - np.interp(m.t_s, inputs.truth_t, inputs.truth_chainage))
         / m.match.chainage_sigma_m for m in ok]
    assert np.max(np.abs(z)) <= 3.0


def test_bag_is_read_and_scored(tmp_path):
    """A rosbag2 bag with /imu/data_raw, /ground_truth/odometry and /ground_truth/pose."""
    from vlc_bags.bagio import write_bag
    from vlc_bags.typesupport import jazzy_typestore

    types = jazzy_typestore().types
    t, w, s = yaw_rate_on_alignment(DEMO, 150.0, 800.0, 20.0, rate_hz=50.0, seed=5, noise_rps=0.002)
    epoch = 1704067200.0

    def header(ts):
        sec = int(math.floor(ts))
        return types['std_msgs/msg/Header'](stamp=types['builtin_interfaces/msg/Time'](
            sec=sec, nanosec=int(round((ts - sec) * 1e9)) % 1_000_000_000), frame_id='map')

    vec = types['geometry_msgs/msg/Vector3']
    msgs = []
    xyz = DEMO.to_map(s)
    for k in range(len(t)):
        ts = epoch + t[k]
        stamp_ns = int(round(ts * 1e9))
        imu = types['sensor_msgs/msg/Imu'](
            header=header(ts), orientation=types['geometry_msgs/msg/Quaternion'](
                x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=np.zeros(9), angular_velocity=vec(x=0.0, y=0.0, z=w[k]),
            angular_velocity_covariance=np.zeros(9), linear_acceleration=vec(x=0.0, y=0.0, z=9.8),
            linear_acceleration_covariance=np.zeros(9))
        msgs.append(('/imu/data_raw', 'sensor_msgs/msg/Imu', stamp_ns, imu))
        if k % 5 == 0:
            pose = types['geometry_msgs/msg/Pose'](
                position=types['geometry_msgs/msg/Point'](x=xyz[k, 0], y=xyz[k, 1], z=0.0),
                orientation=types['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0))
            msgs.append(('/ground_truth/pose', 'geometry_msgs/msg/PoseStamped', stamp_ns,
                         types['geometry_msgs/msg/PoseStamped'](header=header(ts), pose=pose)))
            odom = types['nav_msgs/msg/Odometry'](
                header=header(ts), child_frame_id='base_link',
                pose=types['geometry_msgs/msg/PoseWithCovariance'](pose=pose,
                                                                   covariance=np.zeros(36)),
                twist=types['geometry_msgs/msg/TwistWithCovariance'](
                    twist=types['geometry_msgs/msg/Twist'](linear=vec(x=20.0, y=0.0, z=0.0),
                                                           angular=vec(x=0.0, y=0.0, z=0.0)),
                    covariance=np.zeros(36)))
            msgs.append(('/ground_truth/odometry', 'nav_msgs/msg/Odometry', stamp_ns, odom))
    write_bag(tmp_path / 'run', msgs)
    inputs = bench.load_bag(tmp_path / 'run', DEMO)
    assert inputs.imu_t.size == len(t) and inputs.speed_t.size == inputs.truth_t.size
    np.testing.assert_allclose(inputs.truth_chainage, s[::5], atol=1e-6)
    np.testing.assert_allclose(inputs.speed, 20.0)
    score = bench.score(bench.run(inputs, DEMO), inputs)
    assert score.available >= 3 and score.max_m < 3.0
    # Without the odometry topic the speed comes from the truth poses.
    no_odom = bench.load_bag(tmp_path / 'run', DEMO, speed_topic='/absent')
    np.testing.assert_allclose(no_odom.speed, 20.0, rtol=1e-5)   # float stamps near 1.7e9 s
