"""Replay a recorded bag's inputs through a companion localizer core, without ROS.

A bag recorded from the graph (the evaluation records ``/imu/data``, ``/vlc/lamps``,
``/spots/pairs`` and ``/ground_truth/pose``; with the photodiode also
``/photodiode/rssi``) is read in its recorded (receive) order and fed to the core the
node would run, with the same joins and waits. The poses come out as arrays, with the
CPU time of every update, so a method can be scored and timed on recorded data from the
real decoder and spot locator — repeatably, and on a quiet core.
"""
from dataclasses import dataclass, field
import math
import time

import numpy as np

from companion_localizers.conversions import rssi_readings
from companion_localizers.core.attitude_prior import fuse_tilt
from companion_localizers.core.rssi import trilaterate
from imu_compensator.core.attitude_buffer import AttitudeBuffer
from train_localizer.conversions import imu_from_msg, stamp_to_ns
from train_localizer.core.join import FrameJoiner, JoinConfig
from vlc_bags.bagio import open_bag
from vlc_common.core.rotations import quat_to_matrix
from vlc_common.pointcloud import cloud_to_records

NS_PER_S = 1_000_000_000
FRAME_TOPICS = ('/imu/data', '/vlc/lamps', '/spots/pairs')


@dataclass
class Replay:
    """Poses and CPU times of one replay.

    Attributes
    ----------
    t_s : ndarray (N,)
        Pose stamps, s.
    xyz : ndarray (N, 3)
        Positions, m.
    update_ms : list of float
        CPU time per measurement update (a frame, or a photodiode sample), ms.
    imu_ms : list of float
        CPU time per IMU sample, ms.
    core : object
        The core after the replay (counters, flags, landmarks).
    """

    t_s: np.ndarray
    xyz: np.ndarray
    update_ms: list = field(default_factory=list)
    imu_ms: list = field(default_factory=list)
    core: object = None


def replay_frames(bag_path, core, join=None):
    """Feed ``/imu/data``, ``/vlc/lamps`` and ``/spots/pairs`` to an ImuDrivenLocalizer,
    joined as the node joins them (``join``: JoinConfig; the nodes' defaults if None).
    """
    joiner = FrameJoiner(join or JoinConfig(timeout_s=1.0, max_pending=40))
    stamps, xyz, update_ms, imu_ms = [], [], [], []

    def frames(ready):
        for stamp_ns, observations in ready:
            start = time.thread_time()
            core.add_frame(stamp_ns, observations)
            update_ms.append(1e3 * (time.thread_time() - start))

    for topic, _, bag_ns, msg in open_bag(bag_path, topics=list(FRAME_TOPICS)):
        now_s = bag_ns / NS_PER_S
        if topic == '/imu/data':
            start = time.thread_time()
            estimates = core.add_imu(imu_from_msg(msg))
            imu_ms.append(1e3 * (time.thread_time() - start))
            for est in estimates:
                stamps.append(est.stamp_ns / NS_PER_S)
                xyz.append(est.position_m)
        elif topic == '/spots/pairs':
            frames(joiner.add_spots(stamp_to_ns(msg.header.stamp), cloud_to_records(msg),
                                    now_s))
        else:
            frames(joiner.add_lamps(stamp_to_ns(msg.header.stamp), cloud_to_records(msg),
                                    now_s))
        frames(joiner.flush(now_s))
    return Replay(np.asarray(stamps), np.asarray(xyz, dtype=float).reshape(-1, 3), update_ms,
                  imu_ms, core)


def replay_rssi(bag_path, config, lamp_map, use_imu_attitude=True,
                tilt_prior_sigma_rad=(0.3 * math.pi / 180.0, 0.3 * math.pi / 180.0),
                unknown_sigma_rad=(0.3 * math.pi / 180.0, 0.3 * math.pi / 180.0,
                                   4.0 * math.pi / 180.0)):
    """Trilaterate every ``/photodiode/rssi`` sample of a bag as the node does: attitude
    from ``/imu/data`` (tilt fused with the track's) once recorded past the sample's
    stamp, speed and first start from the last two fixes.
    """
    attitude = AttitudeBuffer(horizon_s=2.0, max_gap_s=0.1, max_extrapolation_s=0.05)
    pending = []
    stamps, xyz, update_ms = [], [], []
    fixes = []

    def solve(stamp_ns, records):
        start = time.thread_time()
        t_s = stamp_ns / NS_PER_S
        q = attitude.at(t_s) if use_imu_attitude else None
        cov = (attitude.covariance_at(t_s) if q is not None
               else np.diag(np.square(unknown_sigma_rad)))
        R = quat_to_matrix(q) if q is not None else np.eye(3)
        speed, predicted = 0.0, None
        if len(fixes) >= 2 and 0 < fixes[-1][0] - fixes[-2][0] <= 0.2 * NS_PER_S:
            speed = (fixes[-1][1] - fixes[-2][1]) / ((fixes[-1][0] - fixes[-2][0]) / NS_PER_S)
        if fixes:
            predicted = fixes[-1][1] + speed * (stamp_ns - fixes[-1][0]) / NS_PER_S
        readings, _ = rssi_readings(records, lamp_map)
        fix = trilaterate(readings, R, config, speed, cov, predicted)
        update_ms.append(1e3 * (time.thread_time() - start))
        if fix.ok:
            fixes.append((stamp_ns, float(fix.position_m[0])))
            stamps.append(t_s)
            xyz.append(fix.position_m)

    for topic, _, _, msg in open_bag(bag_path, topics=['/imu/data', '/photodiode/rssi']):
        if topic == '/imu/data':
            sample = imu_from_msg(msg)
            if sample.quat_xyzw is not None and sample.is_finite():
                attitude.push(sample.stamp_ns / NS_PER_S, *fuse_tilt(
                    sample.quat_xyzw, sample.attitude_cov_rad2, tilt_prior_sigma_rad,
                    config.attitude_sigma_rad[:2]))
            while pending and (not use_imu_attitude
                               or attitude.newest_s >= pending[0][0] / NS_PER_S):
                solve(*pending.pop(0))
        else:
            pending.append((stamp_to_ns(msg.header.stamp), cloud_to_records(msg)))
    for item in pending:
        solve(*item)
    return Replay(np.asarray(stamps), np.asarray(xyz, dtype=float).reshape(-1, 3), update_ms,
                  [], None)


def summary_ms(values):
    """(median, 95th percentile, max) of a list of milliseconds (NaN when empty)."""
    if not values:
        return math.nan, math.nan, math.nan
    arr = np.asarray(values)
    return float(np.median(arr)), float(np.percentile(arr, 95)), float(arr.max())
