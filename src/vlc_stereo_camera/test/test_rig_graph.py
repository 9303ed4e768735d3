"""The installed rig (stereo_camera_node + adis16488_node) as separate processes.

Image pairs carry identical stamps on the 30 Hz frame grid, none missing between the
first and last pair received (reliable QoS); IMU samples sit on the 400 Hz grid of the
same epoch (best-effort sensor QoS: a few may drop).
"""
import pathlib
import time

import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image, Imu

INSTALL_LIB = pathlib.Path(__file__).resolve().parents[3] / 'install' / 'lib'

pytestmark = pytest.mark.graph

EPOCH_NS = 1704067200 * 10 ** 9
FRAME_NS = 1e9 / 30.0
IMU_NS = 10 ** 9 // 400


def _ns(stamp):
    return stamp.sec * 10 ** 9 + stamp.nanosec


def test_rig_publishes_stereo_pairs_and_imu_at_configured_rates(launch, ros_env):
    if not (INSTALL_LIB / 'vlc_stereo_camera' / 'adis16488_node').exists():
        pytest.fail('adis16488_node is not installed: run `make build`')
    scenario = {'seed': 3, 'motion_profile': 'constant', 'start_chainage_m': 6.0,
                'speed_kmh': 20.0, 'realtime_factor': 1.0}
    cam = launch('vlc_stereo_camera', 'stereo_camera_node',
                 params={**scenario, 'noise_bank_size': 2})
    imu = launch('vlc_stereo_camera', 'adis16488_node', params={**scenario, 'rate_hz': 400.0})
    ctx = Context()
    rclpy.init(context=ctx)
    node = Node('rig_probe', context=ctx)
    got = {'left': [], 'right': [], 'imu': []}
    reliable = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
    node.create_subscription(Image, 'stereo/left/image_raw',
                             lambda m: got['left'].append(_ns(m.header.stamp)), reliable)
    node.create_subscription(Image, 'stereo/right/image_raw',
                             lambda m: got['right'].append(_ns(m.header.stamp)), reliable)
    # Best effort like qos_profile_sensor_data, but a deep local queue: the IMU node
    # publishes in batches and this one Python thread also takes 2 x 0.9 MB images.
    node.create_subscription(Imu, 'imu/data_raw',
                             lambda m: got['imu'].append(_ns(m.header.stamp)),
                             QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT))
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    try:
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline and (len(got['left']) < 60 or len(got['imu']) < 800):
            executor.spin_once(timeout_sec=0.1)
            assert cam.poll() is None, launch.output(cam)
            assert imu.poll() is None, launch.output(imu)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    assert launch.stop(cam) == 0, launch.output(cam)
    assert launch.stop(imu) == 0, launch.output(imu)

    left, right = np.array(got['left']), np.array(got['right'])
    assert len(left) >= 60, launch.output(cam)
    # identical stamps left/right (pair by stamp: the last pair may be incomplete)
    common = np.intersect1d(left, right)
    assert len(common) >= len(left) - 1 and len(common) >= len(right) - 1
    # 30 Hz grid from the epoch, no gaps
    k = np.round((common - EPOCH_NS) / FRAME_NS).astype(np.int64)
    np.testing.assert_array_equal(common, EPOCH_NS + np.round(k * FRAME_NS).astype(np.int64))
    np.testing.assert_array_equal(np.diff(k), 1)
    # IMU: 400 Hz grid of the same epoch, monotonic, few dropped
    stamps = np.array(got['imu'])
    assert len(stamps) >= 800, launch.output(imu)
    assert np.all((stamps - EPOCH_NS) % IMU_NS == 0)
    steps = np.diff(stamps) // IMU_NS
    assert np.all(steps >= 1) and np.median(steps) == 1
    assert len(stamps) >= 0.9 * (steps.sum() + 1)
    # both sensors run on one simulated clock: their stamp ranges overlap
    assert stamps[0] < common[-1] and common[0] < stamps[-1]
