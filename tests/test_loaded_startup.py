"""The graph started as a new user would, on a busy machine, never publishes a confident
wrong position.

The six nodes are started one after another with their defaults (the installed
executables, as ``ros2 run`` starts them) beside two busy-loop processes on this
two-core machine. Every ``train/pose_with_covariance`` is compared with the rig's
``/ground_truth/pose`` at its stamp: none may be more than 0.5 m off while claiming a
3σ under 0.5 m, and the published covariance must hold the errors.
"""
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402

from vlc_common.stamps import stamp_to_ns  # noqa: E402

pytestmark = pytest.mark.graph

NODES = [('vlc_stereo_camera', 'stereo_camera_node'), ('vlc_stereo_camera', 'adis16488_node'),
         ('vlc_decoder', 'vlc_decoder_node'), ('spot_locator', 'spot_locator_node'),
         ('imu_compensator', 'imu_compensator_node'), ('train_localizer', 'train_localizer_node')]
RUN_S = 25.0
WRONG_M = 0.5


def test_nodes_started_one_by_one_on_a_loaded_machine_are_never_confidently_wrong(launch):
    busy = [subprocess.Popen([sys.executable, '-c', 'while True: pass']) for _ in range(2)]
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node('startup_probe', context=ctx)
    truth, poses = [], []
    lock = threading.Lock()

    def on_truth(msg):
        p = msg.pose.position
        with lock:
            truth.append((stamp_to_ns(msg.header.stamp), p.x, p.y, p.z))

    def on_pose(msg):
        p = msg.pose.pose.position
        cov = np.asarray(msg.pose.covariance, dtype=float).reshape(6, 6)[:3, :3]
        with lock:
            poses.append((stamp_to_ns(msg.header.stamp), np.array([p.x, p.y, p.z]), cov))

    reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    node.create_subscription(PoseStamped, '/ground_truth/pose', on_truth, reliable)
    node.create_subscription(PoseWithCovarianceStamped, '/train/pose_with_covariance', on_pose,
                             reliable)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    procs = []
    try:
        for package, executable in NODES:
            procs.append(launch(package, executable))
            deadline = time.monotonic() + 1.0
            while time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.05)
        deadline = time.monotonic() + RUN_S
        while time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
            for proc in procs:
                assert proc.poll() is None, launch.output(proc)
    finally:
        for proc in busy:
            proc.kill()
            proc.wait()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    for proc in reversed(procs):
        assert launch.stop(proc) == 0, launch.output(proc)
    localizer_log = launch.output(procs[-1])
    assert len(poses) > 200, localizer_log
    t_truth = np.array([t for t, *_ in truth], dtype=float)
    order = np.argsort(t_truth)
    xyz_truth = np.array([xyz for _, *xyz in truth])[order]
    t_truth = t_truth[order]
    stamps = np.array([t for t, _, _ in poses], dtype=float)
    covered = (stamps >= t_truth[0]) & (stamps <= t_truth[-1])
    assert covered.mean() > 0.95
    est = np.array([p for _, p, _ in poses])[covered]
    cov = np.array([c for _, _, c in poses])[covered]
    ref = np.column_stack([np.interp(stamps[covered], t_truth, xyz_truth[:, k])
                           for k in range(3)])
    diff = est - ref
    err = np.linalg.norm(diff, axis=1)
    sigma_max = np.sqrt(np.linalg.eigvalsh(cov)[:, -1])
    wrong = (err > WRONG_M) & (3.0 * sigma_max < WRONG_M)
    sigma_axes = np.sqrt(np.diagonal(cov, axis1=1, axis2=2))
    inside_axes = np.abs(diff) <= 3.0 * sigma_axes
    inside = np.mean(np.all(inside_axes, axis=1))
    outside = np.flatnonzero(~np.all(inside_axes, axis=1))
    t0 = stamps[covered][0]
    worst = '\n'.join(f'  t {(stamps[covered][k] - t0) * 1e-9:7.3f} s error {diff[k].round(4)} '
                      f'sigma {sigma_axes[k].round(4)}' for k in outside[:15])
    summary = (f'{wrong.sum()} confidently wrong of {err.size}; max error {err.max():.3f} m; '
               f'{100 * inside:.2f} % within 3 sigma (per axis '
               f'{np.round(100 * inside_axes.mean(axis=0), 2)} %)\n{worst}\n'
               f'{localizer_log[-3000:]}')
    assert wrong.sum() == 0, summary
    assert inside >= 0.99, summary
