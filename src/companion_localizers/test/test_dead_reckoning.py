"""Landmark + IMU dead reckoning (companion method 2) on simulated runs."""
import numpy as np
import pytest

from companion_localizers.core.dead_reckoning import (
    DeadReckoning,
    DeadReckoningConfig,
    ImageStillConfig,
    ImageStillness,
)
from vlc_common.core.observation import ImuSample
from vlc_stereo_camera.core.upstream import LAMPS, run_core


def test_acceleration_input_is_the_20_sample_moving_average():
    dr = DeadReckoning(DeadReckoningConfig(), LAMPS)
    values = np.arange(50.0)
    out = [dr.accel_input(v) for v in values]
    assert out[4] == pytest.approx(np.mean(values[:5]))
    assert out[30] == pytest.approx(np.mean(values[11:31]))


@pytest.mark.parametrize('speed_kmh', [20.0, 60.0, 120.0])
def test_constant_speed_run_stays_at_metre_level(speed_kmh):
    dr = DeadReckoning(DeadReckoningConfig(), LAMPS)
    err, _, events = run_core(dr, speed_kmh, t_end_s=4.0 if speed_kmh > 30 else 6.0)
    assert len(err) > 100
    assert err.max() < 1.0 and err.mean() < 0.3
    # One landmark per lamp passed (UIDs confirmed), each a reset of the integration.
    uids = [e.uid for e in events]
    assert len(uids) == len(set(uids)) >= 3
    assert dr.counters.frames > 100


def test_stop_and_go_uses_zero_velocity_and_stays_at_metre_level():
    dr = DeadReckoning(DeadReckoningConfig(), LAMPS)
    # Stand 1 s, 3 m/s^2 to 30 km/h (2.8 s), cruise 1 s, brake (2.8 s), stand 1.4 s.
    err, stamps, _ = run_core(dr, 30.0, t_end_s=9.0, profile='accel_cruise_brake',
                              dwell_s=1.0, cruise_s=1.0, accel_mps2=3.0, brake_mps2=3.0)
    # The lamp spots stand still at the start (speed still unknown) and at the end.
    assert dr.counters.zero_velocity_updates > 10
    assert err.max() < 1.0
    standing = err[stamps > 8.0]
    assert standing.size and standing.max() < 0.3


def test_sparser_landmarks_drift_more_but_stay_bounded():
    dense = DeadReckoning(DeadReckoningConfig(), LAMPS)
    sparse = DeadReckoning(DeadReckoningConfig(landmark_stride=4), LAMPS)
    err_d, _, ev_d = run_core(dense, 100.0, t_end_s=5.0, seed=2)
    err_s, _, ev_s = run_core(sparse, 100.0, t_end_s=5.0, seed=2)
    assert len(ev_s) < len(ev_d)
    assert all(LAMPS.lamps.index(LAMPS.by_uid(e.uid)) % 4 == 0 for e in ev_s)
    assert err_s.mean() > err_d.mean()
    assert err_s.max() < 3.0


def test_image_stillness_needs_every_spot_to_stay_put():
    still = ImageStillness(ImageStillConfig(window_s=0.3, max_motion_px=0.5, min_frames=5))
    for k in range(12):
        result = still.push(k * 33_333_333, [[600.0 + 0.1 * (k % 2), 300.0]])
    assert result and still.still_at(11 * 33_333_333 + 10_000_000)
    moving = ImageStillness()
    for k in range(12):
        result = moving.push(k * 33_333_333, [[600.0 + 2.0 * k, 300.0]])
    assert not result
    assert not ImageStillness().push(0, [])


def test_unknown_uids_and_bad_input_are_skipped():
    dr = DeadReckoning(DeadReckoningConfig(), LAMPS)

    frames = []

    def forge(stamp, observations, truth):
        frames.append(stamp)
        for obs in observations:
            if obs.uid is not None:
                obs.uid = 0x7123                  # a CRC-valid UID absent from the map
        if observations and len(frames) % 5 == 0:
            observations[0].uv_left = np.array([np.nan, 1.0])

    err, _, events = run_core(dr, 60.0, t_end_s=3.0, observe=forge)
    assert events == [] and err.size == 0         # no landmark: no position
    assert dr.unknown_uids > 0 and dr.counters.bad_observations > 0
    assert dr.add_imu(ImuSample(0, [np.nan, 0.0, 9.8])) == []
    assert dr.counters.imu_rejected == 1


def test_invalid_configuration_is_refused():
    with pytest.raises(ValueError):
        DeadReckoningConfig(window_samples=0)
    with pytest.raises(ValueError):
        DeadReckoningConfig(max_sigma_m=0.0)
