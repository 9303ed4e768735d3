"""Checkerboard renderer (core/checkerboard.py): corners where the camera model puts them.

A board rendered through a strongly distorting lens is found by OpenCV's detector, and
the sub-pixel corners agree with the model's projection of the true corners without a
bias: the renderer and the camera model share one pixel convention and one distortion.
"""
import cv2
import numpy as np
import pytest

from vlc_common.core import rotations as geo
from vlc_common.core.camera import CameraModel, StereoCameraModel
from vlc_stereo_camera.core.checkerboard import (
    BoardImageConfig,
    BoardRenderer,
    Checkerboard,
    StereoBoardRenderer,
    calibration_poses,
)

K1 = np.array([[1040.0, 0.0, 643.2], [0.0, 1041.5, 356.1], [0.0, 0.0, 1.0]])
D1 = np.array([-0.30, 0.10, 0.0008, -0.0005, -0.015])
K2 = np.array([[1043.0, 0.0, 636.9], [0.0, 1044.1, 362.4], [0.0, 0.0, 1.0]])
D2 = np.array([-0.29, 0.095, -0.0006, 0.0004, -0.012])
BOARD = Checkerboard((9, 6), 0.04)


def _detect(image, pattern=(9, 6)):
    ok, corners = cv2.findChessboardCorners(image, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH
                                            | cv2.CALIB_CB_NORMALIZE_IMAGE)
    assert ok
    corners = cv2.cornerSubPix(image, corners, (8, 8), (-1, -1),
                               (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-4))
    return corners.reshape(-1, 2)


def _in_truth_order(found, truth):
    # OpenCV may start from either end of the board
    return found if (np.linalg.norm(found[0] - truth[0])
                     < np.linalg.norm(found[0] - truth[-1])) else found[::-1]


def test_board_geometry():
    points = BOARD.object_points()
    assert points.shape == (54, 3)
    np.testing.assert_allclose(points[:2, :2], [[0.04, 0.04], [0.08, 0.04]])
    np.testing.assert_allclose(BOARD.centre_m, [0.2, 0.14, 0.0])
    table = BOARD.label_brightness(0.0, 1.0, 0.5)
    s = np.array([0.01, 0.05, -0.01, -0.05, 0.41, 0.47])        # square 0, 1, margin,
    q = np.full_like(s, 0.01)                                   # background, 10, beyond
    np.testing.assert_array_equal(table[BOARD.cell_label(s, q)], [0, 1, 1, 0.5, 1, 0.5])
    with pytest.raises(ValueError):
        Checkerboard((1, 6), 0.04)


def test_rendered_corners_are_where_the_distorted_camera_projects_them():
    rng = np.random.default_rng(5)
    camera = CameraModel(1280, 720, K1, D1)
    renderer = BoardRenderer(camera, BOARD)
    errors = []
    # into the corners of the image, where the lens bends the board's lines the most
    poses = calibration_poses(renderer, 5, rng)
    for pose in poses:
        assert renderer.visible(*pose)
        truth = renderer.corners(*pose)
        found = _in_truth_order(_detect(renderer.render(*pose, rng)), truth)
        errors.append(found - truth)
    errors = np.concatenate(errors)
    assert np.abs(errors.mean(axis=0)).max() < 0.02           # no bias
    assert np.sqrt(np.mean(np.sum(errors ** 2, axis=1))) < 0.1
    # an ideal camera would put the corners elsewhere by pixels: the distortion is drawn
    pinhole = BoardRenderer(CameraModel(1280, 720, K1), BOARD)
    assert np.abs(pinhole.corners(*poses[0]) - renderer.corners(*poses[0])).max() > 20.0


def test_stereo_poses_are_in_view_of_both_cameras_and_spread():
    R = geo.rot_y(np.radians(0.2))
    stereo = StereoCameraModel.from_stereo_extrinsics(K1, D1, K2, D2, (1280, 720), R,
                                                      -R @ [0.12, 0.0, 0.0])
    renderer = StereoBoardRenderer(stereo, BOARD, BoardImageConfig(noise_dn=0.0))
    poses = calibration_poses(renderer, 9, np.random.default_rng(2))
    assert all(all(renderer.visible(*pose)) for pose in poses)
    corners = np.concatenate([renderer.corners(*pose)[0] for pose in poses])
    # the corners cover most of the left image (the right camera, 12 cm to the right,
    # keeps boards seen by both from its left edge)
    span = (corners.max(axis=0) - corners.min(axis=0)) / [1280, 720]
    assert np.all(span > 0.75)
    # boards seen by one camera: each image covered to within 150 px of its edges
    single = calibration_poses(renderer, 18, np.random.default_rng(2), in_both=False)
    for side in (0, 1):
        seen = [renderer.corners(*pose)[side] for pose in single
                if renderer.visible(*pose)[side]]
        assert len(seen) >= 9
        uv = np.concatenate(seen)
        assert np.all(uv.min(axis=0) < 150) and np.all(uv.max(axis=0) > [1130, 570])
    R_lb, t_lb = poses[4]                                        # the central pose
    left, right = renderer.render(R_lb, t_lb, np.random.default_rng(0))
    uv_l, uv_r = renderer.corners(R_lb, t_lb)
    for image, truth in ((left, uv_l), (right, uv_r)):
        found = _in_truth_order(_detect(image), truth)
        assert np.abs(found - truth).max() < 0.2
    R_rb, t_rb = renderer.right_pose(R_lb, t_lb)
    x_left = BOARD.object_points() @ R_lb.T + t_lb
    R_rl, T_rl = stereo.extrinsics()
    np.testing.assert_allclose(BOARD.object_points() @ R_rb.T + t_rb, x_left @ R_rl.T + T_rl,
                               atol=1e-12)
