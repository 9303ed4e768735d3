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
