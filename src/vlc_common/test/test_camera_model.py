"""Calibrated camera model (core/camera.py): distortion, rectification, CameraInfo.

The lens is a 3.9 mm M12 lens on the rig's 1280×720 sensor with 3.75 µm pixels
(fx = 1040 px, a pinhole horizontal field of view of 63.2°, 64° nominal; the barrel
distortion widens the raw image to 73°), with the distortion of such lenses: k1 ≈ −0.3,
k2 ≈ 0.1, small p1, p2, k3, and a principal point a few pixels off centre.
"""
import array
import types

import cv2
import numpy as np
import pytest

from vlc_common.core import rotations as geo
from vlc_common.core.camera import (
    CameraModel,
    CameraModelError,
    StereoCameraModel,
    StereoRig,
    distortion_model_of,
)
from vlc_common.core.lamp_map import straight_tunnel_map

K_LEFT = np.array([[1040.0, 0.0, 643.2], [0.0, 1041.5, 356.1], [0.0, 0.0, 1.0]])
D_LEFT = np.array([-0.30, 0.10, 0.0008, -0.0005, -0.015])
K_RIGHT = np.array([[1043.0, 0.0, 636.9], [0.0, 1044.1, 362.4], [0.0, 0.0, 1.0]])
D_RIGHT = np.array([-0.29, 0.095, -0.0006, 0.0004, -0.012])
SIZE = (1280, 720)


def _raw_grid(step_px=10.0):
    """Raw pixels covering the whole sensor, edges and corners included (px)."""
    u = np.append(np.arange(-0.5, SIZE[0] - 0.5, step_px), SIZE[0] - 0.5)
    v = np.append(np.arange(-0.5, SIZE[1] - 0.5, step_px), SIZE[1] - 0.5)
    uu, vv = np.meshgrid(u, v)
    return np.column_stack([uu.ravel(), vv.ravel()])


def _points_seen_everywhere(camera, rng, step_px=10.0):
    """3-D points (N, 3) of the optical frame whose raw images cover the whole sensor."""
    rays = camera.undistort_normalized(_raw_grid(step_px))
    depth = rng.uniform(1.0, 12.0, len(rays))
    return np.column_stack([rays * depth[:, None], depth])


def test_projection_is_opencvs():
    rng = np.random.default_rng(3)
    points = rng.uniform([-2, -1, 1], [2, 1, 4], size=(300, 3))
    for D in (D_LEFT, np.array([-0.2, 0.05, 0.001, -0.002, 0.01, 0.02, 0.003, 0.001])):
        model, D = distortion_model_of(D)
        camera = CameraModel(*SIZE, K_LEFT, D, distortion_model=model)
        expected, _ = cv2.projectPoints(points.reshape(-1, 1, 3), np.zeros(3), np.zeros(3),
                                        K_LEFT, D)
        uv, z = camera.project(points)
        np.testing.assert_allclose(uv, expected.reshape(-1, 2), atol=1e-9)
        np.testing.assert_array_equal(z, points[:, 2])
    assert np.all(np.isnan(camera.project([[0.1, 0.2, -1.0]])[0]))


def test_undistortion_of_a_strong_m12_lens_within_0_02_px_over_the_whole_image():
    rng = np.random.default_rng(7)
    camera = CameraModel(*SIZE, K_LEFT, D_LEFT)
    pinhole = CameraModel(*SIZE, K_LEFT)
    points = _points_seen_everywhere(camera, rng)
    uv_raw, _ = camera.project(points)
    # the points do fill the sensor to its corners
    assert uv_raw.min(axis=0) == pytest.approx([-0.5, -0.5], abs=1e-3)
    assert uv_raw.max(axis=0) == pytest.approx([1279.5, 719.5], abs=1e-3)
    truth, _ = pinhole.project(points)
    error = np.linalg.norm(camera.rectify_points(uv_raw) - truth, axis=1)
    assert error.max() < 0.02
    # why the iterations matter: OpenCV's default 5 steps (image_geometry as is) miss
    # the corners of this lens by more than 0.1 px
    default = cv2.undistortPoints(uv_raw.reshape(-1, 1, 2), K_LEFT, D_LEFT, P=K_LEFT)
    assert np.linalg.norm(default.reshape(-1, 2) - truth, axis=1).max() > 0.1
    # the inverse, for renderers: rectified → raw
    np.testing.assert_allclose(camera.unrectify_points(truth), uv_raw, atol=0.02)


def test_rectified_rows_agree_for_a_right_camera_rotated_by_0_2_deg():
    rng = np.random.default_rng(11)
    R = geo.rot_z(np.radians(0.08)) @ geo.rot_y(np.radians(0.2)) @ geo.rot_x(np.radians(-0.1))
    T = -R @ np.array([0.12, 0.002, -0.001])                 # right camera 12 cm right
    stereo = StereoCameraModel.from_stereo_extrinsics(K_LEFT, D_LEFT, K_RIGHT, D_RIGHT,
                                                      SIZE, R, T, alpha=0.0)
    assert stereo.baseline_m == pytest.approx(np.linalg.norm(T), rel=1e-9)
    R_back, T_back = stereo.extrinsics()
    np.testing.assert_allclose(R_back, R, atol=1e-12)
    np.testing.assert_allclose(T_back, T, atol=1e-12)

    points = _points_seen_everywhere(stereo.left, rng)
    uv_l, uv_r, _ = stereo.project_raw(points)
    in_right = np.all((uv_r >= -0.5) & (uv_r <= np.array(SIZE) - 0.5), axis=1)
    assert in_right.mean() > 0.9
    rect_l, rect_r = stereo.rectify_points(uv_l[in_right], uv_r[in_right])
    assert np.abs(rect_l[:, 1] - rect_r[:, 1]).max() < 0.02
    # without the rectification rotation the rows differ by pixels: the test can fail
    unrotated = [CameraModel(*SIZE, K, D, P=cam.P) for K, D, cam in
                 ((K_LEFT, D_LEFT, stereo.left), (K_RIGHT, D_RIGHT, stereo.right))]
    rows = [cam.rectify_points(uv)[:, 1] for cam, uv in
            zip(unrotated, (uv_l[in_right], uv_r[in_right]))]
    assert np.abs(rows[0] - rows[1]).max() > 1.0
    # disparity gives the depth: triangulation in the left rectified frame
    truth = points[in_right] @ stereo.left.R.T
    xyz = stereo.triangulate(rect_l, rect_r)
    np.testing.assert_allclose(xyz, truth, rtol=1e-5)
    uv_rect_l, uv_rect_r, depth = stereo.project_rectified(truth)
    np.testing.assert_allclose(uv_rect_l, rect_l, atol=0.02)
    np.testing.assert_allclose(uv_rect_r, rect_r, atol=0.02)
    np.testing.assert_array_equal(depth, truth[:, 2])


def test_ideal_pair_is_the_pinhole_rig():
    rig = StereoRig()
    stereo = StereoCameraModel.from_rig(rig)
    for mine, rigs in zip(stereo.camera_info_dicts(), rig.camera_info_dicts()):
        assert mine.keys() == rigs.keys()
        for key, value in rigs.items():
            np.testing.assert_array_equal(mine[key], value)
    assert stereo.left.is_ideal and stereo.right.is_ideal
    assert stereo.baseline_m == pytest.approx(rig.baseline_m, rel=1e-15)
    lamps = straight_tunnel_map(count=3, first_chainage_m=1.0, spacing_m=4.0).positions
    uv_l, uv_r, z = rig.project(lamps, np.zeros(3), np.eye(3))
    p_cam = rig.to_camera(lamps, np.zeros(3), np.eye(3), 0)
    mine_l, mine_r, mine_z = stereo.project_rectified(p_cam)
    np.testing.assert_allclose(mine_l, uv_l, atol=1e-9)
    np.testing.assert_allclose(mine_r, uv_r, atol=1e-9)
    np.testing.assert_allclose(stereo.rectify_points(uv_l, uv_r)[1], uv_r, atol=0)
    np.testing.assert_allclose(stereo.triangulate(uv_l, uv_r), p_cam, rtol=1e-12)


def test_camera_info_round_trip_shaped_and_message_layout():
    R = geo.rot_y(np.radians(0.3))
    P = np.array([[1021.4, 0, 656.5, -122.6], [0, 1021.4, 359.1, 0], [0, 0, 1, 0]])
    camera = CameraModel(*SIZE, K_RIGHT, D_RIGHT, R, P)
    info = camera.to_camera_info()
    again = CameraModel.from_camera_info(info)
    message = {'width': 1280, 'height': 720, 'distortion_model': 'plumb_bob',
               'd': list(D_RIGHT), 'k': list(K_RIGHT.ravel()), 'r': list(R.ravel()),
               'p': list(P.ravel())}
    from_message = CameraModel.from_camera_info(message)
    # a sensor_msgs/CameraInfo message: lower-case attributes, d an array.array
    msg = types.SimpleNamespace(width=1280, height=720, distortion_model='',
                                d=array.array('d', D_RIGHT), k=K_RIGHT.ravel(),
                                r=R.ravel(), p=P.ravel())
    from_object = CameraModel.from_camera_info(msg)
    assert from_object.distortion_model == 'plumb_bob'
    for other in (again, from_message, from_object):
        for key in ('K', 'D', 'R', 'P'):
            np.testing.assert_array_equal(getattr(other, key), getattr(camera, key))
        assert (other.width, other.height) == SIZE
    assert camera.fx == 1021.4 and camera.cx == 656.5 and not camera.is_ideal


@pytest.mark.parametrize('change, field, words', [
    (dict(width=0), 'width', 'positive integer'),
    (dict(height=720.5), 'height', 'positive integer'),
    (dict(K=np.eye(3)[:2]), 'K', 'expected 3x3'),
    (dict(K=np.diag([1040.0, -1.0, 1.0])), 'K', 'must be > 0'),
    (dict(K=np.array([[1040, 0, 640], [0, 1040, 360], [0, 0, 2.0]])), 'K', 'not a pinhole'),
    (dict(D=[-0.3, 0.1, np.nan, 0, 0]), 'D', 'non-finite'),
    (dict(D=[-0.3, 0.1, 0.0]), 'D', 'expected 5'),
    (dict(R=np.diag([1.0, 1.0, 1.01])), 'R', 'not a rotation'),
    (dict(P=np.zeros((3, 4))), 'P', 'must be > 0'),
    (dict(distortion_model='equidistant'), 'distortion_model', 'not supported'),
])
def test_invalid_camera_fields_are_named(change, field, words):
    fields = dict(width=1280, height=720, K=K_LEFT, D=D_LEFT)
    fields.update(change)
    with pytest.raises(CameraModelError, match=words) as info:
        CameraModel(**fields)
    assert info.value.field == field


def test_invalid_stereo_pairs():
    left = CameraModel(*SIZE, K_LEFT)
    right_p = np.column_stack([K_LEFT, [-0.12 * 1040.0, 0.0, 0.0]])
    StereoCameraModel(left, CameraModel(*SIZE, K_LEFT, P=right_p))      # a valid pair
    with pytest.raises(CameraModelError, match='image sizes differ'):
        StereoCameraModel(left, CameraModel(640, 480, K_LEFT, P=right_p))
    with pytest.raises(CameraModelError, match='not a rectified pair'):
        StereoCameraModel(left, CameraModel(*SIZE, K_RIGHT, P=np.column_stack(
            [K_RIGHT, [-0.12 * 1043.0, 0, 0]])))
    with pytest.raises(CameraModelError, match='baseline of -0.12 m'):
        StereoCameraModel(left, CameraModel(*SIZE, K_LEFT, P=right_p * [1, 1, 1, -1]))
    with pytest.raises(CameraModelError, match='horizontal stereo'):
        StereoCameraModel(left, CameraModel(*SIZE, K_LEFT, P=right_p + [[0] * 4, [0, 0, 0, 5],
                                                                        [0] * 4]))
    with pytest.raises(CameraModelError, match='12 distortion coefficients'):
        distortion_model_of(np.zeros(12))


@pytest.mark.parametrize('angles', [(49.0, 27.0, 0.0), (49.14, 26.52, 0.33), (-20.0, -40.0, 7.5),
                                    (120.0, 10.0, -3.0)])
def test_mount_angles_invert_the_mount_rotation(angles):
    from vlc_common.core.camera import mount_angles, mount_rotation
    back = mount_angles(mount_rotation(*angles))
    np.testing.assert_allclose(back, angles, atol=1e-9)
    # a small turn of the camera about its own axes comes back as a rotation of the mount
    turned = mount_rotation(*angles) @ cv2.Rodrigues(np.array([1e-3, -2e-3, 5e-4]))[0]
    np.testing.assert_allclose(mount_rotation(*mount_angles(turned)), turned, atol=1e-12)
