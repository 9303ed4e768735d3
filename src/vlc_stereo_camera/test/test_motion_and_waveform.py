"""Pure-core tests of the rig's lamp waveform, train motion and vibration (no rclpy)."""
import numpy as np
import pytest

from vlc_stereo_camera.core.trajectory import (
    GRAVITY_MPS2,
    MotionProfile,
    Trajectory,
    Vibration,
    VibrationConfig,
)
from vlc_stereo_camera.core.transmitter import LampWaveform


def test_waveform_window_mean_is_exact_integral():
    wave = LampWaveform(0x102A, chip_rate_hz=10_000.0, phase_s=1.234e-4, off_level=0.05)
    t0 = np.linspace(0.0, 0.02, 57)
    t1 = t0 + 50e-6
    fine = np.linspace(0.0, 1.0, 20001)
    numeric = np.array([wave.level(a + fine * (b - a)).mean() for a, b in zip(t0, t1)])
    np.testing.assert_allclose(wave.mean_over(t0, t1), numeric, atol=2e-3)
    # a whole packet averages to (header 3 on + 24 on) / 54 of full drive
    period = 54 / 10_000.0
    mean = wave.mean_over(np.array([0.3]), np.array([0.3 + period]))[0]
    assert mean == pytest.approx((27 + 27 * 0.05) / 54, abs=1e-9)


# --- trajectory and vibration ---------------------------------------------------------
def test_motion_profiles():
    acb = MotionProfile('accel_cruise_brake', start_chainage_m=5.0, speed_mps=10.0,
                        accel_mps2=1.0, brake_mps2=2.0, dwell_s=2.0, cruise_s=3.0)
    s, v, a = acb.evaluate(np.array([0.0, 2.0, 7.0, 12.0, 14.0, 17.0, 20.0]))
    np.testing.assert_allclose(v, [0, 0, 5, 10, 10, 6, 0])
    np.testing.assert_allclose(s[-1], 5.0 + 50.0 + 30.0 + 25.0)
    s, v, _ = MotionProfile('constant', start_chainage_m=1.0, speed_mps=2.0).evaluate(3.0)
    assert s[0] == 7.0 and v[0] == 2.0
    with pytest.raises(ValueError):
        MotionProfile('teleport')


def test_vibration_heading_bounds_and_determinism():
    traj = Trajectory(MotionProfile('constant', speed_mps=100 / 3.6), Vibration(seed=7))
    t = np.arange(0.0, 300.0, 0.002)
    yaw = np.degrees(traj.sample(t).rpy_rad[:, 2])
    assert yaw.min() >= -5.0 and yaw.max() <= 7.5
    assert yaw.max() - yaw.min() > 8.0      # the disturbance is really there
    again = Trajectory(MotionProfile('constant', speed_mps=100 / 3.6), Vibration(seed=7))
    np.testing.assert_array_equal(again.sample(t[:100]).rpy_rad, traj.sample(t[:100]).rpy_rad)
    other = Trajectory(MotionProfile('constant', speed_mps=100 / 3.6), Vibration(seed=8))
    assert not np.allclose(other.sample(t[:100]).rpy_rad, traj.sample(t[:100]).rpy_rad)


def test_trajectory_derivatives_are_consistent():
    traj = Trajectory(MotionProfile('accel_cruise_brake', speed_mps=25.0), Vibration(seed=3))
    t = np.array([3.0, 9.3, 20.0, 40.0, 61.0])
    dt = 1e-5
    lo, mid, hi = traj.sample(t - dt), traj.sample(t), traj.sample(t + dt)
    np.testing.assert_allclose((hi.position_m - lo.position_m) / (2 * dt), mid.velocity_mps,
                               atol=1e-7)
    np.testing.assert_allclose((hi.velocity_mps - lo.velocity_mps) / (2 * dt),
                               mid.acceleration_mps2, atol=1e-6)
    # body rate: R^T dR/dt = [omega]x
    W = np.einsum('nji,njk->nik', mid.R_map_base, (hi.R_map_base - lo.R_map_base) / (2 * dt))
    omega = np.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], axis=1)
    np.testing.assert_allclose(omega, mid.angular_velocity_body_rps, atol=1e-8)


def test_standstill_specific_force_is_gravity():
    traj = Trajectory(MotionProfile('stationary', start_chainage_m=42.0), Vibration(seed=1))
    sample = traj.sample(np.linspace(0.0, 10.0, 11))
    np.testing.assert_allclose(np.linalg.norm(sample.specific_force_body_mps2, axis=1),
                               GRAVITY_MPS2)
    np.testing.assert_allclose(sample.angular_velocity_body_rps, 0.0, atol=1e-15)
    np.testing.assert_allclose(sample.position_m[:, 0], 42.0, atol=0.003)


def test_vibration_can_be_disabled():
    traj = Trajectory(MotionProfile('constant', speed_mps=30.0),
                      Vibration(VibrationConfig(enabled=False)))
    sample = traj.sample(np.linspace(0, 5, 20))
    np.testing.assert_array_equal(sample.rpy_rad, 0.0)
    np.testing.assert_allclose(sample.specific_force_body_mps2, [[0, 0, GRAVITY_MPS2]] * 20)
