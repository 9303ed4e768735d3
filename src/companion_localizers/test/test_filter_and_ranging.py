"""Along-track filter with delayed measurements, stereo ranging, tilt fusion."""
import math

import numpy as np
import pytest

from companion_localizers.core.along_track import (
    H_CHAINAGE,
    H_SPEED,
    AlongTrackFilter,
    FilterSettings,
)
from companion_localizers.core.attitude_prior import fuse_tilt
from companion_localizers.core.ranging import RangingConfig, range_to_lamp
from train_localizer.core.fix import RigGeometry
from vlc_common.core.camera import StereoRig
from vlc_common.core.lamp_map import straight_tunnel_map
from vlc_common.core.observation import LampObservation
from vlc_common.core.rotations import quat_from_rpy, quat_to_rpy
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration
from vlc_stereo_camera.core.upstream import SensorErrors, SensorSimulator

MS = 1_000_000
DEG = math.pi / 180.0


def _run(measurement_order, delayed):
    """Feed 400 Hz IMU and three measurements; ``delayed`` ones arrive 50 ms late."""
    f = AlongTrackFilter()
    meas = {100: (H_CHAINAGE, 1.5, 1e-4), 180: (H_SPEED, 10.0, 0.01), 260: (H_CHAINAGE, 4.0, 1e-4)}
    pending = []
    for k in range(400):
        t = k * 2_500_000
        f.add_imu(t, 0.3 * math.sin(k / 40.0))
        for km in measurement_order:
            if km == k:
                if delayed:
                    pending.append((k + 20, km))
                else:
                    f.add_measurement(km * 2_500_000, *meas[km])
        for _, km in [p for p in pending if p[0] == k]:
            f.add_measurement(km * 2_500_000, *meas[km])
    return f


def test_delayed_measurements_give_exactly_the_in_order_result():
    in_order = _run([100, 180, 260], delayed=False)
    late = _run([100, 180, 260], delayed=True)
    assert late.state.x == pytest.approx(in_order.state.x, abs=1e-9)
    assert late.state.P == pytest.approx(in_order.state.P, abs=1e-12)
    t = 150 * 2_500_000 + 1_000_000
    assert late.state_at(t).x == pytest.approx(in_order.state_at(t).x, abs=1e-9)


def test_chainage_starts_unknown_and_a_measurement_newer_than_the_imu_waits():
    f = AlongTrackFilter(FilterSettings(initial_chainage_var_m2=1e8))
    f.add_imu(0, 0.0)
    assert f.state.P[0, 0] == pytest.approx(1e8)
    f.add_measurement(10 * MS, H_CHAINAGE, 7.0, 1e-4)   # beyond the newest sample
    assert f.state.P[0, 0] > 1e7
    f.add_imu(5 * MS, 0.0)
    assert f.state.P[0, 0] > 1e7
    f.add_imu(20 * MS, 0.0)
    assert f.state_at(10 * MS).x[0] == pytest.approx(7.0, abs=1e-3)


def test_measurements_older_than_the_history_are_dropped_and_counted():
    f = AlongTrackFilter(FilterSettings(history_s=0.1))
    for k in range(200):
        f.add_imu(k * 2_500_000, 0.0)
    assert not f.add_measurement(10 * MS, H_CHAINAGE, 1.0, 1e-4)
    assert f.dropped_old == 1
    assert not f.add_imu(100 * MS, 0.0)                 # not newer than the newest


def test_bias_random_walk_extra_inflates_the_uncertainty():
    plain, leaky = AlongTrackFilter(), AlongTrackFilter()
    for k in range(400):
        plain.add_imu(k * 2_500_000, 0.0)
        leaky.add_imu(k * 2_500_000, 0.0, bias_q_extra=0.01)
    assert leaky.state.P[2, 2] > plain.state.P[2, 2] + 0.009


def _simulated_frame(t0, attitude=True, seed=3):
    traj = Trajectory(MotionProfile('constant', start_chainage_m=33.0, speed_mps=12.0),
                      Vibration(seed=seed))
    sim = SensorSimulator(traj, StereoRig(), straight_tunnel_map(),
                          SensorErrors(pixel_sigma_px=0.05), np.random.default_rng(seed))
    return traj, sim.frame(t0, noise=False)


def test_range_gives_the_lamp_chainage_ahead_of_base_link_exactly():
    geometry = RigGeometry(exposure_s=50e-6)
    lamps = straight_tunnel_map()
    for t0 in (0.0, 0.2, 0.4):
        traj, (stamp, observations, truth) = _simulated_frame(t0)
        assert observations
        for obs, tr in zip(observations, truth):
            obs.exposure_mid_offset_s = tr['t_s'] - t0
            # With the platform's true lateral/vertical offset (vibration, mm) as the track
            # offset, the range-only along-track distance is exact.
            cfg = RangingConfig(track_offset_yz_m=tuple(tr['base_position_m'][1:]))
            rng = range_to_lamp(obs, geometry, tr['R_map_base'],
                                lamps.by_uid(tr['uid']).position_m[1:], cfg)
            expected = lamps.by_uid(tr['uid']).position_m[0] - tr['base_position_m'][0]
            assert rng.ahead_m == pytest.approx(expected, abs=1e-5)
            assert rng.range_m == pytest.approx(np.linalg.norm(tr['p_cam']), abs=1e-6)
            assert rng.ahead_var_m2 > 0.0


def test_a_lamp_nearly_abeam_or_too_far_is_not_ranged():
    geometry = RigGeometry()
    far = LampObservation(0, None, (700.0, 300.0), (699.0, 300.0))        # 1 px disparity
    assert range_to_lamp(far, geometry, np.eye(3), (2.5, 1.4), RangingConfig()) is None
    # A range shorter than the lamp's lateral/vertical offset from the camera.
    z = 1040.0 * 0.12 / 60.0
    near = LampObservation(0, None, (639.5, 359.5), (579.5, 359.5))
    assert z < math.hypot(1.7, 1.5)
    assert range_to_lamp(near, geometry, np.eye(3), (2.5, 1.4), RangingConfig()) is None
    nan = LampObservation(0, None, (math.nan, 300.0), (600.0, 300.0))
    assert range_to_lamp(nan, geometry, np.eye(3), (2.5, 1.4), RangingConfig()) is None


def test_tilt_fusion_pulls_an_uncertain_pitch_to_the_track_and_keeps_the_heading():
    q = quat_from_rpy(0.3 * DEG, 2.0 * DEG, 5.0 * DEG)
    cov = np.diag(np.square([0.3 * DEG, 1.0 * DEG, 4.0 * DEG]))
    fused, fcov = fuse_tilt(q, cov, (0.3 * DEG, 0.3 * DEG))
    roll, pitch, yaw = quat_to_rpy(fused)
    gain_p = 0.3 ** 2 / (0.3 ** 2 + 1.0 ** 2)
    assert pitch == pytest.approx(gain_p * 2.0 * DEG, rel=1e-6)
    assert roll == pytest.approx(0.5 * 0.3 * DEG, rel=1e-6)
    assert yaw == pytest.approx(5.0 * DEG, rel=1e-9)
    assert fcov[1, 1] == pytest.approx(gain_p * (1.0 * DEG) ** 2)
    assert fcov[2, 2] == pytest.approx((4.0 * DEG) ** 2)
    # A converged filter (sigma << vibration) is kept as it is; (0, 0) disables.
    sharp, _ = fuse_tilt(q, np.diag(np.square([1e-4, 1e-4, 1e-3])), (0.3 * DEG, 0.3 * DEG))
    assert quat_to_rpy(sharp)[1] == pytest.approx(2.0 * DEG, rel=1e-3)
    same, _ = fuse_tilt(q, cov, (0.0, 0.0))
    assert same == pytest.approx(q)
    no_cov, c = fuse_tilt(q, None, (0.3 * DEG, 0.3 * DEG))
    assert np.all(np.isfinite(c)) and abs(quat_to_rpy(no_cov)[1]) < 2.0 * DEG
