"""An imu/data attitude that is wrong while claiming to be right never makes a pose
confidently wrong: a gross one (the platform cannot be there) is ignored at once, a
moderate one is shown wrong by the first lamp whose range and direction it cannot
reconcile, and the localizer carries on with the track's attitude meanwhile.
"""
import dataclasses
import functools
import math

import numpy as np
import pytest

from train_localizer.core.fix import RigGeometry
from train_localizer.core.localizer import Localizer, LocalizerConfig
from vlc_common.core.camera import StereoRig
from vlc_common.core.lamp_map import straight_tunnel_map
from vlc_common.core.rotations import quat_from_rpy, quat_multiply
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration
from vlc_stereo_camera.core.upstream import (
    SensorErrors,
    SensorSimulator,
    event_stream,
    from_stamp_ns,
)
from vlc_stereo_camera.core.upstream import feed_localizer as feed

RIG = StereoRig()
LAMPS = straight_tunnel_map()
DEG = math.pi / 180.0
CLAIMED_SIGMA_RAD = 0.05 * DEG


@functools.lru_cache(maxsize=2)
def simulate(speed_kmh=60.0, t_end_s=6.0, seed=4):
    profile = MotionProfile('constant', start_chainage_m=3.0, speed_mps=speed_kmh / 3.6)
    traj = Trajectory(profile, Vibration(seed=seed))
    sim = SensorSimulator(traj, RIG, LAMPS, SensorErrors(), np.random.default_rng(seed))
    return traj, event_stream(sim, 0.0, t_end_s)


def corrupt(events, rpy_error_rad, after_s):
    """imu/data after ``after_s`` off by ``rpy_error_rad`` while claiming 0.05° σ."""
    error = quat_from_rpy(*rpy_error_rad)
    out = []
    for arrival, kind, payload in events:
        if kind == 'imu' and arrival >= after_s and payload.quat_xyzw is not None:
            payload = dataclasses.replace(
                payload, quat_xyzw=quat_multiply(error, payload.quat_xyzw),
                attitude_cov_rad2=np.eye(3) * CLAIMED_SIGMA_RAD ** 2)
        out.append((arrival, kind, payload))
    return out


def scores(poses, traj):
    t = np.array([from_stamp_ns(p.stamp_ns) for p in poses])
    err = np.array([p.chainage_m for p in poses]) - traj.sample(t).position_m[:, 0]
    sigma = np.array([p.chainage_sigma_m for p in poses])
    wrong = int(np.sum((np.abs(err) > 0.5) & (3.0 * sigma < 0.5)))
    return wrong, float(np.mean(np.abs(err) <= 3.0 * sigma)), float(np.max(np.abs(err)))


def make():
    return Localizer(LAMPS, LocalizerConfig(geometry=RigGeometry.from_stereo_rig(RIG)))


@pytest.mark.parametrize('rpy_deg, kind', [
    ((-31.0, -20.0, -2.0), 'implausible'),    # a diverged compensator (seen live)
    ((0.0, 0.0, 25.0), 'implausible'),
    ((2.0, 3.0, -3.0), 'fallback'),           # wrong by degrees, claiming 0.05°
    ((0.0, -1.5, 0.0), 'fallback'),
])
def test_a_wrong_attitude_claiming_to_be_right_is_caught(rpy_deg, kind):
    traj, events = simulate()
    loc = make()
    poses, fixes, logs = feed(loc, corrupt(events, np.radians(rpy_deg), after_s=2.0))
    wrong, inside, worst = scores(poses, traj)
    assert wrong == 0
    assert inside >= 0.997
    assert worst < 0.1
    c = loc.monitor.counters
    if kind == 'implausible':
        assert c.imu_attitude_implausible > 1000
    else:
        assert c.fixes_attitude_fallback > 0
        assert any(e.code == 'attitude_distrusted' for e in logs)
    # still tracking: fixes accepted to the end
    assert max(f.measurement_ns for f in fixes if f.status == 'accepted') > \
        max(p.stamp_ns for p in poses) - 200_000_000


def test_a_right_attitude_is_never_distrusted():
    traj, events = simulate()
    loc = make()
    poses, _, _ = feed(loc, events)
    c = loc.monitor.counters
    assert c.imu_attitude_implausible == 0 and c.fixes_attitude_fallback == 0
    wrong, inside, worst = scores(poses, traj)
    assert wrong == 0 and worst < 0.03


def one_wrong_match(events, frame_index, dv_px):
    """A frame hook: the first confirmed lamp of one frame matched ``dv_px`` rows off in
    both images (the pair of a spot cut by the image edge, seen once: a wrong stereo
    match whose range and direction disagree under the IMU attitude, and agree under
    the wide uncertainty of no attitude).
    """
    target = [p[0] for _, kind, p in events if kind == 'frame'][frame_index]

    def hook(stamp, observations, truth):
        if stamp != target:
            return observations
        out, done = [], False
        for obs in observations:
            if obs.uid is not None and not done:
                obs = dataclasses.replace(obs, uv_left=obs.uv_left + [0.0, dv_px],
                                          uv_right=obs.uv_right + [0.0, dv_px])
                done = True
            out.append(obs)
        return out
    return target, hook


@pytest.mark.parametrize('dv_px', [15.0, 30.0])
def test_one_wrong_match_does_not_distrust_a_right_attitude(dv_px):
    traj, events = simulate()
    target, hook = one_wrong_match(events, 100, dv_px)
    codes = {}
    for evidence_s in (0.0, 0.5):      # 0: one lamp was enough (before)
        loc = Localizer(LAMPS, LocalizerConfig(geometry=RigGeometry.from_stereo_rig(RIG),
                                               attitude_evidence_s=evidence_s))
        poses, fixes, logs = feed(loc, events, frame_hook=hook)
        codes[evidence_s] = {e.code for e in logs}
        wrong, inside, _ = scores(poses, traj)
        assert wrong == 0 and inside >= 0.997
    # one lamp alone distrusted the attitude; now it takes a second
    assert 'attitude_distrusted' in codes[0.0]
    assert 'attitude_distrusted' not in codes[0.5] and 'attitude_suspect' in codes[0.5]
    assert loc.monitor.counters.fixes_attitude_fallback == 0
    # the wrong match's fix (stamped at its rows' exposure, within the frame) is rejected
    in_frame = [f.status for f in fixes if 0 <= f.measurement_ns - target < 34_000_000]
    assert 'rejected_geometry' in in_frame
    assert [f.status for f in fixes].count('rejected_geometry') == 1


def test_attitude_evidence_must_be_finite_and_not_negative():
    with pytest.raises(ValueError, match='attitude_evidence_s'):
        LocalizerConfig(geometry=RigGeometry.from_stereo_rig(RIG), attitude_evidence_s=-1.0)
    LocalizerConfig(geometry=RigGeometry.from_stereo_rig(RIG), attitude_evidence_s=0.0)
