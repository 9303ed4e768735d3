"""Single-frame fixes without any filtering, from the records a run bag holds.

The static table shows the method (triangulation, one frame, one lamp) beside the
fused product, so both are seen (``shared/EVALUATION.md``). No node publishes a
per-frame fix, but every bag holds what one needs: ``spots/pairs`` (sub-pixel stereo
centres with their exposure time and uncertainty), ``vlc/lamps`` (the decoder's UID of
each spot) and ``imu/data`` (the compensated attitude). Each spot pair whose spot the
decoder has confirmed (same stamp, left centres within ``match_radius_px``) is
triangulated (paper eq. 12) and placed in ``map`` by the localizer's own core
functions (:func:`train_localizer.core.fix.compute_fix`):

* ``paper``: the paper's chain, eq. 13–14, with the compensated attitude;
* ``constrained``: this project's single-frame fix (track constraint + stereo range).

Fixes are stamped at the spot's exposure mid-time and compared with the truth there.

A run of a drawn rig profile (``realistic``, ``harsh``) is placed with what its receivers
believe (:func:`belief_setup`): the installation's surveyed lamp map, its vehicle file and
its calibration as the localizer takes it from camera_info (rectified intrinsics, the
left R, the calibration's error weights, the decoder's raw positions rectified for the
UID match), not the nominal rig, whose intrinsics are not the camera's.
"""
import math

import numpy as np

from train_localizer.core.fix import (
    FixConfig,
    RigGeometry,
    compute_fix,
    measurement_time_ns,
    triangulate,
)
from vlc_common.core.observation import LampObservation
from vlc_common.core.rotations import quat_slerp, quat_to_matrix
from vlc_evaluation import metrics

CONFIRMED = 2                       # vlc/lamps state: CRC-valid UID in the lamp map
METHODS = ('paper', 'constrained')
ATTITUDE_SIGMA_FLOOR_RAD = np.radians([0.05, 0.05, 0.1])   # localizer default floor
HOLD_S = 1.0 / 30.0                 # static truth held past its last sample (one frame)


def attitude_at(t_s, imu_t, imu_quat, imu_cov):
    """Attitude matrix (3, 3) and covariance (3, 3) at ``t_s`` from imu/data samples.

    Quaternions are interpolated (slerp) between the bracketing samples; outside the
    samples, or without any, identity with a 5° heading σ (the localizer's
    ``attitude_sigma_unknown_deg``).
    """
    unknown = (np.eye(3), np.diag(np.radians([0.5, 0.5, 5.0]) ** 2))
    if imu_t.size == 0 or t_s < imu_t[0] or t_s > imu_t[-1]:
        return unknown
    k = int(np.searchsorted(imu_t, t_s))
    k = min(max(k, 1), imu_t.size - 1)
    span = imu_t[k] - imu_t[k - 1]
    frac = 0.0 if span <= 0.0 else (t_s - imu_t[k - 1]) / span
    q = quat_slerp(imu_quat[k - 1], imu_quat[k], frac)
    cov = np.array(imu_cov[k]) if imu_cov.size else np.zeros((3, 3))
    if not np.all(np.isfinite(cov)) or cov[0, 0] < 0.0:
        cov = np.zeros((3, 3))
    floor = ATTITUDE_SIGMA_FLOOR_RAD ** 2
    cov[np.diag_indices(3)] = np.maximum(np.diag(cov), floor)
    return quat_to_matrix(q), cov


def belief_setup(installation_dir, localizer_params=None):
    """(RigGeometry, LampMap, rectify_left) of a drawn installation's ``belief/`` files
    as the localizer uses them: the vehicle file's mount, the camera_info of
    ``left.yaml``/``right.yaml`` through
    :class:`train_localizer.conversions.CameraInfoIntrinsics`, the calibration error
    weights of the localizer's parameters (``localizer_params``; default: its file), the
    surveyed lamp map; ``rectify_left`` maps the decoder's raw left positions (None for
    rectified camera_info).
    """
    import pathlib

    from train_localizer.conversions import CameraInfoIntrinsics
    from train_localizer.core.join import JoinConfig
    from train_localizer.node_parameters import rig_geometry
    from vlc_common.core.lamp_map import LampMap
    from vlc_common.core.vehicle import load_vehicle
    from vlc_evaluation.localizer_replay import camera_info_messages, load_params
    belief = pathlib.Path(installation_dir) / 'belief'
    p = dict(localizer_params or load_params())
    geometry = rig_geometry(p, load_vehicle(str(belief / 'vehicle.yaml')))
    join = JoinConfig()
    intrinsics = CameraInfoIntrinsics(geometry, True, join)
    for index, msg in enumerate(camera_info_messages([belief / 'left.yaml',
                                                      belief / 'right.yaml'])):
        outcome = intrinsics.update(index, msg)
        if outcome is not None and outcome[0] == 'warn':
            raise ValueError(f'{belief}: camera_info {outcome[1]}')
    return geometry, LampMap.load(str(belief / 'lamp_map.yaml')), join.rectify_left


def confirmed_uid(pair, lamp_records, match_radius_px, rectify_left=None):
    """UID of the confirmed decoder record nearest to ``pair`` (left centres), or None.

    ``rectify_left``: maps the decoder's raw left positions (N, 2) to the pairs'
    rectified pixels (raw images).
    """
    if lamp_records is None or len(lamp_records) == 0:
        return None
    ok = lamp_records['state'] == CONFIRMED
    if not np.any(ok):
        return None
    recs = lamp_records[ok]
    left = np.column_stack([recs['left_u'], recs['left_v']]).astype(float)
    if rectify_left is not None:
        finite = np.all(np.isfinite(left), axis=1)
        if np.any(finite):
            left[finite] = rectify_left(left[finite])
    d = np.hypot(left[:, 0] - pair['u_left'], left[:, 1] - pair['v_left'])
    d = np.where(np.isfinite(d), d, np.hypot(recs['right_u'] - pair['u_right'],
                                             recs['right_v'] - pair['v_right']))
    if not np.any(np.isfinite(d)):
        return None
    best = int(np.nanargmin(d))
    return int(recs['uid'][best]) if d[best] <= match_radius_px else None


def raw_fixes(run, lamp_map, method='paper', geometry=None, config=None,
              match_radius_px=12.0, rectify_left=None):
    """Every single-frame fix of a run.

    Returns a dict of arrays: ``t_s`` (measurement instants, s), ``position_m`` (N, 3),
    ``uid`` (N,), ``range_m`` (N,).
    """
    geometry = geometry or RigGeometry(row_time_s=30e-6, exposure_s=25e-6)
    config = config or FixConfig(use_range_constraint=(method == 'constrained'))
    rows = {'t_s': [], 'position_m': [], 'uid': [], 'range_m': []}
    for stamp_ns in sorted(run.pairs):
        for pair in run.pairs[stamp_ns]:
            uid = confirmed_uid(pair, run.lamps.get(stamp_ns), match_radius_px,
                                rectify_left)
            lamp = lamp_map.by_uid(uid) if uid is not None else None
            if lamp is None:
                continue
            obs = LampObservation(
                stamp_ns=stamp_ns, uid=uid, uv_left=[pair['u_left'], pair['v_left']],
                uv_right=[pair['u_right'], pair['v_right']],
                sigma_u_px=float(pair['sigma_u_left']), sigma_v_px=float(pair['sigma_v_left']),
                sigma_disparity_px=float(pair['sigma_disparity']),
                exposure_mid_offset_s=float(pair['stamp_offset_s']))
            if not obs.is_finite():
                continue
            p_cam, cov_cam = triangulate(obs, geometry, config.min_disparity_px)
            if p_cam is None:
                continue
            t_s = measurement_time_ns(obs, geometry) * 1e-9
            R, cov_att = attitude_at(t_s, run.imu_t, run.imu_quat, run.imu_cov)
            fix = compute_fix(p_cam, cov_cam, lamp.position_m, R, cov_att, geometry, config)
            if not math.isfinite(fix.chainage_m):
                continue
            rows['t_s'].append(t_s)
            rows['position_m'].append(fix.position_m)
            rows['uid'].append(uid)
            rows['range_m'].append(fix.range_m)
    return {'t_s': np.asarray(rows['t_s'], float),
            'position_m': np.asarray(rows['position_m'], float).reshape(-1, 3),
            'uid': np.asarray(rows['uid'], int), 'range_m': np.asarray(rows['range_m'], float)}


def score_raw_static(run, lamp_map, belief=None):
    """Static protocol, raw: the last single-frame fix of the trial (and every frame).

    Returns ``{method: {'error_m', 'along_m', 'frames', 'every_frame'}}``; ``error_m``
    is None (a miss) when no frame gave a fix. ``belief``: the (geometry, lamp map,
    rectify_left) of :func:`belief_setup` for a drawn installation.
    """
    out = {}
    geometry, rectify_left = None, None
    if belief is not None:
        geometry, lamp_map, rectify_left = belief
    for method in METHODS:
        fixes = raw_fixes(run, lamp_map, method, geometry=geometry, rectify_left=rectify_left)
        # The truth is stamped per frame (row 0) and a fix at its spot's exposure time,
        # up to one readout later: the last frame's fix lies past the last truth
        # sample. The train stands, so the truth is held there for one frame period.
        t = fixes['t_s']
        if run.truth_t.size:
            t = np.where((t > run.truth_t[-1]) & (t <= run.truth_t[-1] + HOLD_S),
                         run.truth_t[-1], t)
        err, along = metrics.pose_errors(t, fixes['position_m'], run.truth_t, run.truth_xyz)
        ok = np.isfinite(err)
        last = np.nonzero(ok)[0]
        out[method] = {
            'error_m': float(err[last[-1]]) if last.size else None,
            'along_m': float(along[last[-1]]) if last.size else None,
            'frames': int(ok.sum()),
            'every_frame': metrics.summarize(err[ok]).as_dict() if ok.any() else None}
    return out
