"""Reads one recorded run (a rosbag2 bag) into arrays and scores it against truth.

A run bag holds at least ``/ground_truth/pose`` and ``/train/pose``; with
``/train/pose_with_covariance`` the covariance consistency is scored, with ``/imu/data``
the heading compensation (estimated vs true yaw, and the uncompensated disturbance).
Stamps are header stamps (the time a pose describes), never bag receive times.
"""
from dataclasses import dataclass, field

import numpy as np

from vlc_stereo_camera.core.geometry import matrix_to_rpy, quat_xyzw_to_matrix

from . import metrics
from ..bagtools.bagio import open_bag

GROUND_TRUTH = '/ground_truth/pose'
POSE = '/train/pose'
POSE_COV = '/train/pose_with_covariance'
IMU = '/imu/data'


def _stamp(header):
    return header.stamp.sec + 1e-9 * header.stamp.nanosec


def _xyz(p):
    return [p.x, p.y, p.z]


def _quat(q):
    return [q.x, q.y, q.z, q.w]


@dataclass
class RunData:
    """Arrays of one run: stamps (s), positions (N, 3) in map, quaternions (N, 4) xyzw."""

    truth_t: np.ndarray
    truth_xyz: np.ndarray
    truth_quat: np.ndarray
    pose_t: np.ndarray
    pose_xyz: np.ndarray
    cov_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cov_xyz: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    cov_mean: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    imu_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    imu_quat: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))


def load_run(bag_path):
    """Read the evaluation topics of a bag into a :class:`RunData`."""
    cols = {k: [] for k in ('tt', 'tx', 'tq', 'pt', 'px', 'ct', 'cx', 'cc', 'it', 'iq')}
    for topic, _, _, msg in open_bag(bag_path, topics=[GROUND_TRUTH, POSE, POSE_COV, IMU]):
        if topic == GROUND_TRUTH:
            cols['tt'].append(_stamp(msg.header))
            cols['tx'].append(_xyz(msg.pose.position))
            cols['tq'].append(_quat(msg.pose.orientation))
        elif topic == POSE:
            cols['pt'].append(_stamp(msg.header))
            cols['px'].append(_xyz(msg.pose.position))
        elif topic == POSE_COV:
            cols['ct'].append(_stamp(msg.header))
            cols['cx'].append(_xyz(msg.pose.pose.position))
            cols['cc'].append(np.asarray(msg.pose.covariance, dtype=float).reshape(6, 6)[:3, :3])
        elif topic == IMU:
            cols['it'].append(_stamp(msg.header))
            cols['iq'].append(_quat(msg.orientation))

    def arr(key, shape):
        return np.asarray(cols[key], dtype=float).reshape(shape)

    def sort(t, *others):
        order = np.argsort(t, kind='stable')
        return (t[order],) + tuple(o[order] for o in others)

    truth_t, truth_xyz, truth_quat = sort(arr('tt', (-1,)), arr('tx', (-1, 3)), arr('tq', (-1, 4)))
    pose_t, pose_xyz = sort(arr('pt', (-1,)), arr('px', (-1, 3)))
    cov_t, cov_mean, cov_xyz = sort(arr('ct', (-1,)), arr('cx', (-1, 3)), arr('cc', (-1, 3, 3)))
    imu_t, imu_quat = sort(arr('it', (-1,)), arr('iq', (-1, 4)))
    return RunData(truth_t, truth_xyz, truth_quat, pose_t, pose_xyz, cov_t, cov_xyz, cov_mean,
                   imu_t, imu_quat)


def distance_to_next_lamp(x_m, lamp_chainages):
    """Along-track distance from chainage ``x_m`` (N,) to the next lamp ahead (m)."""
    lamps = np.sort(np.asarray(lamp_chainages, dtype=float))
    k = np.searchsorted(lamps, np.asarray(x_m, dtype=float), side='right')
    ahead = lamps[np.minimum(k, lamps.size - 1)]
    return np.where(k < lamps.size, ahead - x_m, np.nan)


def heading_errors(run):
    """Heading (yaw) of the compensator minus truth, and the true disturbance, in degrees.

    Returns (stamps (M,), error_after (M,), disturbance_before (M,)); the disturbance is
    what an uncompensated system would take as its heading error (it assumes the
    platform is aligned with the track).
    """
    if run.imu_t.size == 0 or run.truth_t.size < 2:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    inside = (run.imu_t >= run.truth_t[0]) & (run.imu_t <= run.truth_t[-1])
    t = run.imu_t[inside]
    yaw_est = matrix_to_rpy(quat_xyzw_to_matrix(run.imu_quat[inside]))[:, 2]
    yaw_true_samples = np.unwrap(matrix_to_rpy(quat_xyzw_to_matrix(run.truth_quat))[:, 2])
    yaw_true = np.interp(t, run.truth_t, yaw_true_samples)
    err = np.angle(np.exp(1j * (yaw_est - yaw_true)))
    return t, np.degrees(err), np.degrees(yaw_true)


def score_run(run, lamp_chainages, settle_s=0.0):
    """Every-pose scores of one run (dict of plain floats and lists, JSON-ready).

    Poses stamped before ``truth_t[0] + settle_s`` are left out (start-up transient).
    """
    keep = run.pose_t >= (run.truth_t[0] + settle_s if run.truth_t.size else np.inf)
    err, along = metrics.pose_errors(run.pose_t[keep], run.pose_xyz[keep], run.truth_t,
                                     run.truth_xyz)
    truth_at = metrics.interpolate_positions(run.pose_t[keep], run.truth_t, run.truth_xyz)
    out = {
        'poses': int(keep.sum()),
        'every_pose': metrics.summarize(err).as_dict(),
        'every_pose_along_track': metrics.summarize(along).as_dict(),
        'distance_to_lamp_m': distance_to_next_lamp(truth_at[:, 0], lamp_chainages).tolist(),
        'error_m': err.tolist(),
    }
    if run.cov_t.size:
        truth_cov = metrics.interpolate_positions(run.cov_t, run.truth_t, run.truth_xyz)
        ok = np.all(np.isfinite(truth_cov), axis=1) & (run.cov_t >= run.truth_t[0] + settle_s)
        out['covariance_3sigma_fraction'] = metrics.covariance_consistency(
            run.cov_mean[ok] - truth_cov[ok], run.cov_xyz[ok])
    t, after, before = heading_errors(run)
    if t.size:
        out['heading_after_deg'] = {'max_abs': float(np.max(np.abs(after))),
                                    'rms': float(np.sqrt(np.mean(after ** 2)))}
        out['heading_before_deg'] = {'min': float(before.min()), 'max': float(before.max())}
    return out
