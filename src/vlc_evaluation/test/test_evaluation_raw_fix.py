"""Raw single-frame fixes from recorded records: exact for exact centres, identity rules."""
import numpy as np
import pytest

from vlc_common.core.camera import StereoRig
from vlc_common.core.lamp_map import LampMap, default_lamp_map_path
from vlc_common.core.rotations import matrix_to_quat_xyzw, rpy_to_matrix
from vlc_evaluation import raw_fix
from vlc_evaluation.bag_eval import RunData

EPOCH_NS = 1_704_067_200_000_000_000
PAIR_DTYPE = np.dtype([('u_left', '<f8'), ('v_left', '<f8'), ('u_right', '<f8'),
                       ('v_right', '<f8'), ('stamp_offset_s', '<f8'), ('sigma_u_left', '<f4'),
                       ('sigma_v_left', '<f4'), ('sigma_disparity', '<f4')])
LAMP_DTYPE = np.dtype([('uid', '<u4'), ('state', '<u4'), ('left_u', '<f4'), ('left_v', '<f4'),
                       ('right_u', '<f4'), ('right_v', '<f4')])


def _run(base_xyz, rpy, lamp_uid=0x1005, state=2, uid_offset_px=0.0, frames=5):
    """A standing train seeing one lamp with exact centres; IMU attitude = truth."""
    lamp_map = LampMap.load(default_lamp_map_path())
    lamp = lamp_map.by_uid(0x1005)
    R = rpy_to_matrix(*rpy)
    uv_l, uv_r, _ = StereoRig().project(lamp.position_m[None], np.asarray(base_xyz), R)
    pairs, lamps, t = {}, {}, []
    for k in range(frames):
        stamp = EPOCH_NS + k * 33_333_333
        t.append(stamp * 1e-9)
        pairs[stamp] = np.array([(uv_l[0, 0], uv_l[0, 1], uv_r[0, 0], uv_r[0, 1],
                                  uv_l[0, 1] * 30e-6 + 12.5e-6, 0.05, 0.05, 0.07)],
                                dtype=PAIR_DTYPE)
        lamps[stamp] = np.array([(lamp_uid, state, uv_l[0, 0] + uid_offset_px, uv_l[0, 1],
                                  uv_r[0, 0] + uid_offset_px, uv_r[0, 1])], dtype=LAMP_DTYPE)
    t = np.array(t)
    truth = np.tile(base_xyz, (frames, 1))
    quat = np.tile(matrix_to_quat_xyzw(R), (frames, 1))
    imu_t = np.arange(t[0] - 0.1, t[-1] + 0.1, 0.0025)
    run = RunData(truth_t=t, truth_xyz=truth, truth_quat=quat, pose_t=np.zeros(0),
                  pose_xyz=np.zeros((0, 3)), imu_t=imu_t,
                  imu_quat=np.tile(matrix_to_quat_xyzw(R), (imu_t.size, 1)),
                  imu_cov=np.tile(np.diag(np.radians([0.05, 0.05, 0.1]) ** 2), (imu_t.size, 1, 1)),
                  pairs=pairs, lamps=lamps)
    return run, lamp_map


@pytest.mark.parametrize('method', raw_fix.METHODS)
def test_exact_centres_give_the_true_position(method):
    base = np.array([45.0, 0.002, -0.001])
    run, lamp_map = _run(base, rpy=np.radians([0.3, -0.2, 2.0]))
    fixes = raw_fix.raw_fixes(run, lamp_map, method)
    assert fixes['t_s'].size == 5 and set(fixes['uid']) == {0x1005}
    err = np.linalg.norm(fixes['position_m'] - base, axis=1)
    # the constrained fix puts y, z on the track (nominal 0): mm offsets allowed there
    assert np.all(np.abs(fixes['position_m'][:, 0] - base[0]) < 1e-3)
    assert np.all(err < (1e-3 if method == 'paper' else 4e-3))


def test_score_static_uses_the_last_frame_and_counts_frames():
    run, lamp_map = _run(np.array([45.0, 0.0, 0.0]), rpy=np.zeros(3))
    scores = raw_fix.score_raw_static(run, lamp_map)
    for method in raw_fix.METHODS:
        assert scores[method]['frames'] == 5
        assert scores[method]['error_m'] < 1e-3
        assert scores[method]['every_frame']['count'] == 5


def test_no_fix_without_a_confirmed_uid_on_the_spot():
    for kwargs in ({'state': 1}, {'uid_offset_px': 40.0}, {'lamp_uid': 0x1FFF}):
        run, lamp_map = _run(np.array([45.0, 0.0, 0.0]), rpy=np.zeros(3), **kwargs)
        assert raw_fix.raw_fixes(run, lamp_map)['t_s'].size == 0, kwargs
        assert raw_fix.score_raw_static(run, lamp_map)['paper']['error_m'] is None


def test_attitude_interpolates_and_falls_back_to_identity():
    t = np.array([0.0, 1.0])
    q = np.array([matrix_to_quat_xyzw(rpy_to_matrix(0, 0, 0.0)),
                  matrix_to_quat_xyzw(rpy_to_matrix(0, 0, 0.2))])
    cov = np.zeros((2, 3, 3))
    R, c = raw_fix.attitude_at(0.5, t, q, cov)
    np.testing.assert_allclose(R, rpy_to_matrix(0, 0, 0.1), atol=1e-12)
    np.testing.assert_allclose(np.diag(c), raw_fix.ATTITUDE_SIGMA_FLOOR_RAD ** 2)
    R, c = raw_fix.attitude_at(2.0, t, q, cov)
    np.testing.assert_allclose(R, np.eye(3))
    assert c[2, 2] == pytest.approx(np.radians(5.0) ** 2)


def test_a_drawn_installation_is_placed_with_the_receivers_belief(tmp_path):
    # Raw single-frame rows of a realistic run: the belief calibration as the localizer
    # takes it from camera_info (P's focal length, the left R, the calibration's error
    # weights, the decoder's raw positions rectified), the measured mount, the survey;
    # not the nominal rig (fx 1040 where the belief's P has ~1003).
    from vlc_common.core.vehicle import load_vehicle
    from vlc_stereo_camera.core.installation import draw_installation
    inst = draw_installation('realistic', 1, load_vehicle(''),
                             LampMap.load(default_lamp_map_path()))
    inst.write(tmp_path)
    geometry, lamp_map, rectify_left = raw_fix.belief_setup(tmp_path)
    left = inst.calibration.left
    assert geometry.fx == left.P[0, 0] and geometry.cx == left.P[0, 2]
    assert geometry.raw_images and min(geometry.calibration_sigma_px) > 0.0
    np.testing.assert_allclose(geometry.R_base_cam,
                               inst.vehicle_belief.camera.R_base_cam @ left.R.T)
    uv = np.array([[100.0, 80.0], [1200.0, 650.0]])
    np.testing.assert_allclose(rectify_left(uv), left.rectify_points(uv))
    lamp = lamp_map.by_uid(0x1005)
    np.testing.assert_allclose(lamp.position_m, inst.lamp_map_belief.by_uid(0x1005).position_m,
                               atol=1e-5)
