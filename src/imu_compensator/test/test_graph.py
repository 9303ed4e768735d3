"""The installed imu_compensator_node fed by the installed adis16488_node.

The rig stands still (IMU errors on, turn-on bias included): imu/data must arrive on the
IMU's 2.5 ms sample grid with unit quaternions, and after the static alignment the
attitude must match the rig's ground truth of the same instants.
"""
import pathlib
import time

import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Imu

from vlc_common.core.rotations import quat_to_rpy

INSTALL_LIB = pathlib.Path(__file__).resolve().parents[3] / 'install' / 'lib'
EPOCH_NS = 1704067200 * 10 ** 9
PERIOD_NS = 2_500_000

pytestmark = pytest.mark.graph


def test_installed_nodes_publish_the_attitude_at_the_imu_rate(launch, ros_env):
    for pkg, exe in (('vlc_stereo_camera', 'adis16488_node'),
                     ('imu_compensator', 'imu_compensator_node')):
        if not (INSTALL_LIB / pkg / exe).exists():
            pytest.fail(f'{exe} is not installed: run `make build`')
    from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration

    scenario = {'seed': 1, 'motion_profile': 'stationary', 'start_chainage_m': 5.0}
    compensator = launch('imu_compensator', 'imu_compensator_node')
    imu = launch('vlc_stereo_camera', 'adis16488_node',
                 params=dict(scenario, rate_hz=400.0, realtime_factor=1.0,
                             wait_for_subscribers=1, follow_clock=False))
    ctx = Context()
    rclpy.init(context=ctx)
    node = Node('imu_probe', context=ctx)
    received = []
    node.create_subscription(Imu, 'imu/data', received.append, qos_profile_sensor_data)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    try:
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline and len(received) < 1200:
            executor.spin_once(timeout_sec=0.1)
            assert imu.poll() is None, launch.output(imu)
            assert compensator.poll() is None, launch.output(compensator)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    assert len(received) >= 1200, launch.output(compensator)
    assert launch.stop(compensator) == 0, launch.output(compensator)

    stamps = np.array([m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec
                       for m in received])
    offsets = stamps - EPOCH_NS
    assert np.all(offsets % PERIOD_NS == 0), 'imu/data not stamped with the IMU sample times'
    steps = np.diff(offsets) // PERIOD_NS
    assert np.all(steps >= 1)
    # Best-effort transport may lose the odd sample; nearly every step is one period.
    assert np.mean(steps == 1) > 0.9
    assert all(m.header.frame_id == 'base_link' for m in received)
    quats = np.array([[m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w]
                      for m in received])
    np.testing.assert_allclose(np.linalg.norm(quats, axis=1), 1.0, atol=1e-9)

    truth = Trajectory(MotionProfile(kind='stationary', start_chainage_m=5.0),
                       Vibration(seed=1)).sample(offsets * 1e-9)
    err = (quat_to_rpy(quats) - truth.rpy_rad + np.pi) % (2 * np.pi) - np.pi
    aligned = offsets * 1e-9 >= offsets[0] * 1e-9 + 1.0
    assert np.degrees(np.abs(err[aligned])).max() < 0.05
