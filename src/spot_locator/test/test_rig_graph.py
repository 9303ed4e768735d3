"""The installed spot_locator_node fed by the installed rig (stereo_camera_node).

The rig stands still with a lamp about 4 m ahead; every published spot pair is compared
with the rig's ground truth of the same frame (``ground_truth/spots``: the projected
disc centres at the exposure mid-time of their row).
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
from sensor_msgs.msg import PointCloud2

from spot_locator.conversions import cloud_to_records

INSTALL_LIB = pathlib.Path(__file__).resolve().parents[3] / 'install' / 'lib'

pytestmark = pytest.mark.graph


def _ns(stamp):
    return stamp.sec * 10 ** 9 + stamp.nanosec


def test_installed_node_locates_the_rig_lamps_to_sub_pixel(launch, ros_env):
    for pkg, exe in (('vlc_stereo_camera', 'stereo_camera_node'),
                     ('spot_locator', 'spot_locator_node')):
        if not (INSTALL_LIB / pkg / exe).exists():
            pytest.fail(f'{exe} is not installed: run `make build`')
    rig = launch('vlc_stereo_camera', 'stereo_camera_node',
                 params={'seed': 5, 'motion_profile': 'stationary', 'start_chainage_m': 16.0,
                         'realtime_factor': 1.0, 'noise_bank_size': 2,
                         'publish_clock': False})
    locator = launch('spot_locator', 'spot_locator_node')
    ctx = Context()
    rclpy.init(context=ctx)
    node = Node('spot_probe', context=ctx)
    truth, pairs = {}, {}
    reliable = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
    node.create_subscription(PointCloud2, 'ground_truth/spots',
                             lambda m: truth.__setitem__(_ns(m.header.stamp),
                                                         cloud_to_records(m)), reliable)
    node.create_subscription(PointCloud2, 'spots/pairs',
                             lambda m: pairs.__setitem__(_ns(m.header.stamp),
                                                         cloud_to_records(m)), reliable)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    try:
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline and len(set(truth) & set(pairs)) < 15:
            executor.spin_once(timeout_sec=0.1)
            assert rig.poll() is None, launch.output(rig)
            assert locator.poll() is None, launch.output(locator)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    assert launch.stop(locator) == 0, launch.output(locator)
    assert launch.stop(rig) == 0, launch.output(rig)

    common = sorted(set(truth) & set(pairs))
    assert len(common) >= 15, (len(truth), len(pairs), launch.output(locator))
    du, dd = [], []
    for stamp in common:
        lamps = truth[stamp][(truth[stamp]['in_left'] == 1) & (truth[stamp]['in_right'] == 1)]
        assert len(pairs[stamp]) >= 1
        for p in pairs[stamp]:
            dist = np.hypot(lamps['u_left'] - p['u_left'], lamps['v_left'] - p['v_left'])
            t = lamps[int(np.argmin(dist))]
            assert dist.min() < 2.0
            du.append(p['u_left'] - t['u_left'])
            dd.append(p['disparity'] - (t['u_left'] - t['u_right']))
            # stamped at the exposure mid-time of the centre's row, as the truth
            assert abs(p['stamp_offset_s'] - t['t_offset_s']) < 2 * 30e-6
    assert np.sqrt(np.mean(np.square(du))) < 0.1, du
    assert np.sqrt(np.mean(np.square(dd))) < 0.05, dd
