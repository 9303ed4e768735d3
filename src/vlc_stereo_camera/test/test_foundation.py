"""Pure-core tests of the rig's foundation: protocol encoder, lamp map, geometry,
camera model and trajectory/vibration (no rclpy)."""
import numpy as np
import pytest

from vlc_stereo_camera.core import geometry as geo
from vlc_stereo_camera.core.camera import CameraIntrinsics, StereoRig
from vlc_stereo_camera.core.lamp_map import Lamp, LampMap, straight_tunnel_map
from vlc_stereo_camera.core.trajectory import (GRAVITY_MPS2, MotionProfile, Trajectory,
                                               Vibration, VibrationConfig)
from vlc_stereo_camera.core.vlc_protocol import LampWaveform, crc8, packet_chips, uid_of


# --- protocol (VLC_PROTOCOL.md) -------------------------------------------------------
def test_crc8_check_value_and_worked_example():
    assert crc8(b'123456789') == 0xF4
    assert crc8(bytes([0x10, 0x2A])) == 0x81


def test_worked_example_chips():
    # VLC_PROTOCOL.md: line 1, lamp 42 -> data bits 0001 0000 0010 1010 1000 0001
    bits = '000100000010101010000001'
    expected = '111000' + ''.join('10' if b == '1' else '01' for b in bits)
    assert uid_of(1, 42) == 0x102A
    assert ''.join(map(str, packet_chips(0x102A))) == expected
    assert len(expected) == 54


def test_uid_range_checked():
    with pytest.raises(ValueError):
        uid_of(16, 0)
    with pytest.raises(ValueError):
        packet_chips(0x10000)


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


# --- lamp map -------------------------------------------------------------------------
def test_lamp_map_roundtrip_and_lookup(tmp_path):
    lamp_map = straight_tunnel_map(count=5)
    path = tmp_path / 'map.yaml'
    lamp_map.save(path)
    loaded = LampMap.load(path)
    assert [lamp.uid for lamp in loaded.lamps] == [lamp.uid for lamp in lamp_map.lamps]
    np.testing.assert_allclose(loaded.positions, lamp_map.positions)
    assert loaded.by_uid(uid_of(1, 3)).position_m[0] == pytest.approx(30.0)
    assert loaded.by_uid(0x7FFF) is None
    assert [lamp.lamp_id for lamp in loaded.near(25.0, ahead_m=20.0)] == [3, 4]


def test_lamp_map_rejects_inconsistent_uid_and_duplicates():
    with pytest.raises(ValueError):
        Lamp(uid=5, line_id=1, lamp_id=5, position_m=[0, 0, 0])
    lamp = Lamp(uid=uid_of(1, 1), line_id=1, lamp_id=1, position_m=[0, 0, 0])
    with pytest.raises(ValueError):
        LampMap([lamp, lamp])


def test_shipped_lamp_map_geometry():
    from vlc_stereo_camera.core.lamp_map import default_lamp_map_path
    lamp_map = LampMap.load(default_lamp_map_path())
    rig = StereoRig()
    cam = rig.cam_positions_base()[0]
    np.testing.assert_allclose(np.diff(lamp_map.positions[:, 0]), 10.0)
    # EVALUATION.md geometry: 1.7 m lateral, 1.5 m below the camera
    np.testing.assert_allclose(lamp_map.positions[:, 1] - cam[1], 1.7)
    np.testing.assert_allclose(cam[2] - lamp_map.positions[:, 2], 1.5)


# --- geometry -------------------------------------------------------------------------
def test_rotation_roundtrips():
    rng = np.random.default_rng(4)
    rpy = rng.uniform([-1, -1.2, -3], [1, 1.2, 3], size=(50, 3))
    R = geo.rpy_to_matrix(rpy[:, 0], rpy[:, 1], rpy[:, 2])
    np.testing.assert_allclose(geo.matrix_to_rpy(R), rpy, atol=1e-12)
    q = geo.matrix_to_quat_xyzw(R)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0)
    np.testing.assert_allclose(geo.quat_xyzw_to_matrix(q), R, atol=1e-12)
    # ROS order x, y, z, w: a yaw of 90 degrees is (0, 0, sin 45, cos 45)
    np.testing.assert_allclose(geo.matrix_to_quat_xyzw(geo.rot_z(np.pi / 2)),
                               [0, 0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-12)


# --- camera ---------------------------------------------------------------------------
def test_intrinsics_match_paper():
    k = CameraIntrinsics()
    hfov, vfov = k.fov_deg
    assert hfov == pytest.approx(63.2, abs=1.0)   # paper: 64 deg
    assert vfov == pytest.approx(38.2, abs=1.0)   # paper: 38 deg


def test_mount_is_a_rotation_with_placement_angle():
    rig = StereoRig(pitch_deg=0.0)
    R = rig.R_base_cam
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    axis = R[:, 2]   # optical axis in base_link
    # turned 49 degrees from the left-wall normal (+y) toward the running direction (+x)
    assert np.degrees(np.arctan2(axis[0], axis[1])) == pytest.approx(49.0)
    assert R[2, 1] == pytest.approx(-1.0)   # image down is world down at zero pitch


def test_stereo_projection_disparity_and_epipolar():
    rig = StereoRig()
    lamp_map = straight_tunnel_map(count=3, first_chainage_m=1.0, spacing_m=4.0)
    uv_l, uv_r, z = rig.project(lamp_map.positions, np.zeros(3), np.eye(3))
    np.testing.assert_allclose(uv_l[:, 1], uv_r[:, 1], atol=1e-9)     # rectified rows
    disparity = uv_l[:, 0] - uv_r[:, 0]
    np.testing.assert_allclose(disparity, 1040.0 * 0.12 / z, rtol=1e-12)
    assert np.all(disparity > 0)


def test_visibility_window_of_default_mount():
    """Lamp centres are in both images from 0.44 to 9.55 m along track (pitch 27 deg).

    Pixel u covers [u - 0.5, u + 0.5]: the sensor spans [-0.5, 1279.5] x [-0.5, 719.5].
    """
    rig = StereoRig()
    d = np.arange(0.3, 12.0, 0.01)
    pts = np.stack([d, np.full_like(d, 2.5), np.full_like(d, 1.4)], axis=1)
    uv_l, uv_r, z = rig.project(pts, np.zeros(3), np.eye(3))
    inside = (z > 0)
    for uv in (uv_l, uv_r):
        inside &= ((uv[:, 0] >= -0.5) & (uv[:, 0] <= 1279.5)
                   & (uv[:, 1] >= -0.5) & (uv[:, 1] <= 719.5))
    assert d[inside].min() == pytest.approx(0.44, abs=0.011)
    assert d[inside].max() == pytest.approx(9.55, abs=0.011)
    # 19 of the 20 static test points (0.5 .. 10 m) have their lamp's centre in view;
    # 10.0 m before a lamp is beside the previous one, which no forward view can see.
    points = np.arange(0.5, 10.01, 0.5)
    assert np.sum((points >= d[inside].min()) & (points <= d[inside].max())) == 19


def test_camera_info_layout():
    left, right = StereoRig().camera_info_dicts()
    np.testing.assert_allclose(left['K'], [[1040, 0, 639.5], [0, 1040, 359.5], [0, 0, 1]])
    assert left['P'][0, 3] == 0.0
    assert right['P'][0, 3] == pytest.approx(-1040.0 * 0.12)


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
