"""Reads one recorded run (a rosbag2 bag) into arrays and scores it against truth.

A run bag holds at least ``/ground_truth/pose`` and ``/train/pose``; with
``/train/pose_with_covariance`` the covariance consistency is scored, with ``/imu/data``
the heading compensation (estimated vs true yaw, and the uncompensated disturbance).
The per-lamp records (``/vlc/lamps``, ``/spots/pairs``, ``/ground_truth/spots``) and
``/diagnostics`` are kept per frame for the raw triangulation, lamp identification,
latency and graph-health figures. Stamps are header stamps (the time a pose
describes), never bag receive times.
"""
from dataclasses import dataclass, field
import pathlib

import numpy as np

from vlc_bags.bagio import open_bag
from vlc_common.core.rotations import matrix_to_rpy, quat_to_matrix
from vlc_common.pointcloud import cloud_to_records
from vlc_common.stamps import stamp_to_ns, stamp_to_s
from vlc_evaluation import metrics

GROUND_TRUTH = '/ground_truth/pose'
POSE = '/train/pose'
POSE_COV = '/train/pose_with_covariance'
IMU = '/imu/data'
LAMPS = '/vlc/lamps'
PAIRS = '/spots/pairs'
TRUTH_SPOTS = '/ground_truth/spots'
DIAGNOSTICS = '/diagnostics'
CLOUD_TOPICS = {LAMPS: 'lamps', PAIRS: 'pairs', TRUTH_SPOTS: 'truth_spots'}


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
    imu_cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    # {stamp_ns: structured array} per record topic (fields: docs/ARCHITECTURE.md)
    lamps: dict = field(default_factory=dict)
    pairs: dict = field(default_factory=dict)
    truth_spots: dict = field(default_factory=dict)
    # {status name: [{key: value}, ...]} in bag order
    diagnostics: dict = field(default_factory=dict)
    bag_path: pathlib.Path = None


def load_run(bag_path):
    """Read the evaluation topics of a bag into a :class:`RunData`."""
    cols = {k: [] for k in ('tt', 'tx', 'tq', 'pt', 'px', 'ct', 'cx', 'cc', 'it', 'iq',
                            'ic')}
    clouds = {name: {} for name in CLOUD_TOPICS.values()}
    diagnostics = {}
    topics = [GROUND_TRUTH, POSE, POSE_COV, IMU, DIAGNOSTICS] + list(CLOUD_TOPICS)
    for topic, _, _, msg in open_bag(bag_path, topics=topics):
        if topic in CLOUD_TOPICS:
            try:
                clouds[CLOUD_TOPICS[topic]][stamp_to_ns(msg.header.stamp)] = cloud_to_records(msg)
            except ValueError:
                continue
        elif topic == DIAGNOSTICS:
            for status in msg.status:
                diagnostics.setdefault(status.name, []).append(
                    {kv.key: kv.value for kv in status.values})
        elif topic == GROUND_TRUTH:
            cols['tt'].append(stamp_to_s(msg.header.stamp))
            cols['tx'].append(_xyz(msg.pose.position))
            cols['tq'].append(_quat(msg.pose.orientation))
        elif topic == POSE:
            cols['pt'].append(stamp_to_s(msg.header.stamp))
            cols['px'].append(_xyz(msg.pose.position))
        elif topic == POSE_COV:
            cols['ct'].append(stamp_to_s(msg.header.stamp))
            cols['cx'].append(_xyz(msg.pose.pose.position))
            cols['cc'].append(np.asarray(msg.pose.covariance, dtype=float).reshape(6, 6)[:3, :3])
        elif topic == IMU:
            cols['it'].append(stamp_to_s(msg.header.stamp))
            cols['iq'].append(_quat(msg.orientation))
            cols['ic'].append(np.asarray(msg.orientation_covariance, dtype=float).reshape(3, 3))

    def arr(key, shape):
        return np.asarray(cols[key], dtype=float).reshape(shape)

    def sort(t, *others):
        order = np.argsort(t, kind='stable')
        return (t[order],) + tuple(o[order] for o in others)

    truth_t, truth_xyz, truth_quat = sort(arr('tt', (-1,)), arr('tx', (-1, 3)), arr('tq', (-1, 4)))
    pose_t, pose_xyz = sort(arr('pt', (-1,)), arr('px', (-1, 3)))
    cov_t, cov_mean, cov_xyz = sort(arr('ct', (-1,)), arr('cx', (-1, 3)), arr('cc', (-1, 3, 3)))
    imu_t, imu_quat, imu_cov = sort(arr('it', (-1,)), arr('iq', (-1, 4)), arr('ic', (-1, 3, 3)))
    return RunData(truth_t, truth_xyz, truth_quat, pose_t, pose_xyz, cov_t, cov_xyz, cov_mean,
                   imu_t, imu_quat, imu_cov, lamps=clouds['lamps'], pairs=clouds['pairs'],
                   truth_spots=clouds['truth_spots'], diagnostics=diagnostics,
                   bag_path=pathlib.Path(bag_path))


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
    yaw_est = matrix_to_rpy(quat_to_matrix(run.imu_quat[inside]))[:, 2]
    yaw_true_samples = np.unwrap(matrix_to_rpy(quat_to_matrix(run.truth_quat))[:, 2])
    yaw_true = np.interp(t, run.truth_t, yaw_true_samples)
    err = np.angle(np.exp(1j * (yaw_est - yaw_true)))
    return t, np.degrees(err), np.degrees(yaw_true)


def score_run(run, lamp_chainages, settle_s=0.0):
    """Every-pose scores of one run (dict of plain floats and lists, JSON-ready).

    Poses and heading samples stamped before ``truth_t[0] + settle_s`` are left out
    (start-up transient).
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
    settled = t >= (run.truth_t[0] + settle_s if run.truth_t.size else np.inf)
    t, after, before = t[settled], after[settled], before[settled]
    if t.size:
        out['heading_after_deg'] = {'max_abs': float(np.max(np.abs(after))),
                                    'rms': float(np.sqrt(np.mean(after ** 2)))}
        out['heading_before_deg'] = {'min': float(before.min()), 'max': float(before.max())}
    return out


def heading_settling_s(run, t_from, bound_deg=0.2):
    """Time from ``t_from`` until |compensated − true heading| stays within ``bound_deg``
    to the end of the run, s (0: within it all along; None: not within it at the end, or
    no heading sample after ``t_from``).
    """
    t, after, _ = heading_errors(run)
    keep = t >= t_from
    t, err = t[keep], np.abs(after[keep])
    if not t.size:
        return None
    out = np.flatnonzero(err > bound_deg)
    if not out.size:
        return 0.0
    if out[-1] == t.size - 1:
        return None
    return float(t[out[-1] + 1] - t_from)


def _diag_values(run, node, key):
    """Numbers under ``key`` in every diagnostics status whose name starts with ``node``."""
    out = []
    for name, entries in run.diagnostics.items():
        if name.split(':')[0].strip().endswith(node):
            for values in entries:
                try:
                    out.append(float(values[key]))
                except (KeyError, ValueError):
                    continue
    return out


def graph_health(run):
    """Signs that a node fell behind during the run, from the nodes' diagnostics.

    A run without them is reproducible from its seed; one with them depends on the
    machine's load (a dropped frame or IMU sample changes the result). Returns counts
    (the nodes' cumulative counters at their last report) and the camera's largest lag
    behind real time (s), plus ``degraded`` (bool).
    """
    def last(node, key):
        values = _diag_values(run, node, key)
        return int(values[-1]) if values else 0

    lag = _diag_values(run, 'stereo_camera_node', 'lag_behind_realtime_s')
    health = {
        'camera_lag_max_s': max(lag) if lag else 0.0,
        # images the spot locator could not pair or use, or skipped to catch up
        'spot_skipped': sum(last('spot_locator_node', k) for k in (
            'bad_image', 'size_mismatch', 'unpaired', 'out_of_order', 'superseded')),
        'imu_samples_skipped': last('adis16488_node', 'samples_skipped'),
        'compensator_gaps': last('imu_compensator_node', 'gaps'),
        'compensator_dropped': last('imu_compensator_node', 'samples_dropped'),
        'decoder_skipped': sum(last('vlc_decoder', k) for k in (
            'skipped_bad_image', 'skipped_size_mismatch', 'skipped_unpaired',
            'skipped_out_of_order', 'skipped_superseded')),
        # perception more than the localizer's history behind the IMU: records dropped
        'localizer_records_too_old': last('train_localizer', 'records_too_old'),
    }
    health['degraded'] = bool(health['camera_lag_max_s'] > 0.1 or any(
        v for k, v in health.items() if k != 'camera_lag_max_s'))
    return health


def severely_degraded(health):
    """A node fell far behind (not one lost sample): camera lag > 0.2 s, or more than
    five frames dropped or skipped, or more than five IMU gaps.
    """
    return bool(health.get('camera_lag_max_s', 0.0) > 0.2 or any(
        health.get(k, 0) > 5 for k in ('spot_skipped', 'decoder_skipped',
                                       'compensator_gaps', 'compensator_dropped',
                                       'imu_samples_skipped', 'localizer_records_too_old')))


def heading_series(run, rate_hz=50.0):
    """Heading error after compensation and the uncompensated disturbance (deg), resampled
    at ``rate_hz`` for a plot: dict of lists ``t_s`` (from the first truth), ``after_deg``,
    ``before_deg``.
    """
    t, after, before = heading_errors(run)
    if t.size < 2:
        return {'t_s': [], 'after_deg': [], 'before_deg': []}
    grid = np.arange(t[0], t[-1], 1.0 / rate_hz)
    return {'t_s': np.round(grid - run.truth_t[0], 4).tolist(),
            'after_deg': np.round(np.interp(grid, t, after), 4).tolist(),
            'before_deg': np.round(np.interp(grid, t, before), 4).tolist()}


# (node, diagnostics key) of each node's own processing-time report, ms
PROCESSING_KEYS = {
    'vlc_decoder': [('vlc_decoder', 'decode_ms_median'), ('vlc_decoder', 'decode_ms_p99'),
                    ('vlc_decoder', 'decode_ms_max')],
    'spot_locator': [('spot_locator_node', 'processing_ms_median'),
                     ('spot_locator_node', 'processing_ms_p99'),
                     ('spot_locator_node', 'processing_ms_max')],
    'train_localizer': [('train_localizer', 'processing_ms_per_fix_median'),
                        ('train_localizer', 'processing_ms_per_fix_p99'),
                        ('train_localizer', 'processing_ms_per_fix_max')],
}


def processing_times(run):
    """Each node's self-reported processing time per frame (ms) at its last report:
    ``{node: [median, p99, max]}`` over the node's last window of frames (None where the
    node did not report one).
    """
    out = {}
    for node, keys in PROCESSING_KEYS.items():
        values = []
        for diag_node, key in keys:
            found = [v for v in _diag_values(run, diag_node, key) if np.isfinite(v)]
            values.append(found[-1] if found else None)
        out[node] = values
    return out
