"""Pure-core tests of the foundation: VLC protocol, lamp map, rotations, camera model."""
import numpy as np
import pytest

from vlc_common.core import rotations as geo
from vlc_common.core.camera import CameraIntrinsics, StereoRig
from vlc_common.core.lamp_map import Lamp, LampMap, straight_tunnel_map
from vlc_common.core.protocol import crc8, packet_chips, uid_of


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
    from vlc_common.core.lamp_map import default_lamp_map_path
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
    np.testing.assert_allclose(geo.quat_to_matrix(q), R, atol=1e-12)
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
