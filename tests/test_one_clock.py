"""The rig has one simulated clock: started one by one with their defaults (as with
``ros2 run``) on a machine loaded by two busy processes, the IMU never publishes a
sample that the camera's ``/clock`` has not reached, however far the camera falls behind
real time.
"""
import subprocess
import sys
import time

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import Imu  # noqa: E402

from vlc_common.stamps import stamp_to_ns  # noqa: E402

pytestmark = pytest.mark.graph

RIG = {'speed_kmh': 120.0, 'start_chainage_m': 3.0}
#: The probe may receive an IMU sample before the /clock tick that released it (two
#: publishers, two processes): one tick late is normal, a loaded machine adds some.
TOLERANCE_NS = 100_000_000


def test_imu_never_runs_ahead_of_the_cameras_clock_on_a_loaded_machine(launch):
    busy = [subprocess.Popen([sys.executable, '-c', 'while True: pass'])
            for _ in range(2)]
    try:
        imu = launch('vlc_stereo_camera', 'adis16488_node', RIG)
        time.sleep(1.0)
        camera = launch('vlc_stereo_camera', 'stereo_camera_node', RIG)
        ctx = rclpy.Context()
        rclpy.init(context=ctx)
        node = rclpy.create_node('clock_probe', context=ctx)
        newest_clock = [None]
        ahead, samples = [], []

        def on_clock(msg):
            newest_clock[0] = max(newest_clock[0] or 0, stamp_to_ns(msg.clock))

        def on_imu(msg):
            samples.append(stamp_to_ns(msg.header.stamp))
            if newest_clock[0] is not None:
                ahead.append(samples[-1] - newest_clock[0])

        node.create_subscription(Clock, '/clock', on_clock, 100)
        executor = SingleThreadedExecutor(context=ctx)
        executor.add_node(node)
        try:
            # The probe discovers the two publishers in any order: it listens to the IMU
            # only once it has a clock to compare its samples with.
            deadline = time.monotonic() + 20.0
            while newest_clock[0] is None and time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.05)
                assert camera.poll() is None, launch.output(camera)
            node.create_subscription(
                Imu, 'imu/data_raw', on_imu,
                QoSProfile(depth=2000, reliability=ReliabilityPolicy.BEST_EFFORT))
            deadline = time.monotonic() + 15.0
            while time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.05)
                assert imu.poll() is None, launch.output(imu)
                assert camera.poll() is None, launch.output(camera)
        finally:
            executor.shutdown()
            node.destroy_node()
            rclpy.try_shutdown(context=ctx)
    finally:
        for proc in busy:
            proc.kill()
            proc.wait()
    assert len(samples) > 400, launch.output(imu)
    assert newest_clock[0] is not None, launch.output(camera)
    # no sample published before /clock reached it
    assert max(ahead) <= TOLERANCE_NS, f'IMU {max(ahead) * 1e-9:.3f} s ahead of /clock'
    assert len(ahead) == len(samples)
    assert np.all(np.diff(samples) > 0)
