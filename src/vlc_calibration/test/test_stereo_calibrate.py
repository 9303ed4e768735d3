"""``stereo_calibrate`` on checkerboard pairs rendered through a KNOWN lens distortion.

The simulator's checkerboard renderer images a 15×10-corner board of 25 mm squares
through two 3.9 mm M12 lenses (k1 ≈ −0.3, k2 ≈ 0.1, small p1, p2, k3, principal points
off centre) 12 cm apart, the right camera turned by 0.24°. 16 pairs, the board pushed in
turn into the corners, edges and centre of the left and of the right image (then often
cut by the other image: a single-camera view). The command must recover the lenses.
"""
import ast
import pathlib
import subprocess

import cv2
import numpy as np
import pytest

from vlc_calibration.image_pairs import InputError, find_image_pairs
from vlc_calibration.stereo_calibrate import main
from vlc_common.core import rotations as geo
from vlc_common.core.calibration import load_opencv_stereo, load_ros_stereo
from vlc_common.core.camera import StereoCameraModel
from vlc_stereo_camera.core.checkerboard import (
    Checkerboard,
    StereoBoardRenderer,
    calibration_poses,
)

WS = pathlib.Path(__file__).resolve().parents[3]
K1 = np.array([[1040.0, 0.0, 643.2], [0.0, 1041.5, 356.1], [0.0, 0.0, 1.0]])
D1 = np.array([-0.30, 0.10, 0.0008, -0.0005, -0.015])
K2 = np.array([[1043.0, 0.0, 636.9], [0.0, 1044.1, 362.4], [0.0, 0.0, 1.0]])
D2 = np.array([-0.29, 0.095, -0.0006, 0.0004, -0.012])
R = geo.rot_z(np.radians(0.08)) @ geo.rot_y(np.radians(0.2)) @ geo.rot_x(np.radians(-0.1))
T = -R @ np.array([0.12, 0.002, -0.001])
BOARD = Checkerboard((15, 10), 0.025)
PAIRS = 16
# where the distortion is largest: the corners of the sensor and the middles of its edges
EDGE_POINTS = np.array([[-0.5, -0.5], [1279.5, -0.5], [-0.5, 719.5], [1279.5, 719.5],
                        [639.5, -0.5], [639.5, 719.5], [-0.5, 359.5], [1279.5, 359.5]])


@pytest.fixture(scope='module')
def rendered(tmp_path_factory):
    """(folder of left_NN.png/right_NN.png, true pair, [(left seen, right seen)])."""
    truth = StereoCameraModel.from_stereo_extrinsics(K1, D1, K2, D2, (1280, 720), R, T)
    renderer = StereoBoardRenderer(truth, BOARD)
    rng = np.random.default_rng(4)
    poses = calibration_poses(renderer, PAIRS, rng, distance_m=(0.55, 1.0), in_both=False)
    folder = tmp_path_factory.mktemp('checkerboard_pairs')
    for k, pose in enumerate(poses):
        left, right = renderer.render(*pose, rng)
        cv2.imwrite(str(folder / f'left_{k:02d}.png'), left, [cv2.IMWRITE_PNG_COMPRESSION, 1])
        cv2.imwrite(str(folder / f'right_{k:02d}.png'), right,
                    [cv2.IMWRITE_PNG_COMPRESSION, 1])
    return folder, truth, [renderer.visible(*pose) for pose in poses]


def _displacement(camera, uv):
    """Undistortion displacement (N, 2) of raw pixels ``uv`` with the camera's own K, px."""
    return camera.undistort_normalized(uv) @ camera.K[:2, :2].T + camera.K[:2, 2] - uv


def test_calibration_recovers_the_known_lenses(rendered, tmp_path, capsys):
    folder, truth, seen = rendered
    opencv_file = tmp_path / 'stereo.yaml'
    code = main([str(folder), '--size', '15x10', '--square', '0.025', '-o', str(tmp_path),
                 '--camera-name', 'train_0412', '--opencv-file', str(opencv_file)])
    out = capsys.readouterr().out
    assert code == 0, out
    calibration = load_ros_stereo(tmp_path / 'left.yaml', tmp_path / 'right.yaml')
    # each camera has most views, and the views of one camera are counted
    assert calibration.pairs >= 10
    assert f'both {calibration.pairs} (the pairs used' in out
    assert f'over {calibration.pairs} pairs' in out
    assert sum(left and right for left, right in seen) <= calibration.pairs
    for est, true, rms in ((calibration.left, truth.left, calibration.left_rms_px),
                           (calibration.right, truth.right, calibration.right_rms_px)):
        # intrinsics: focal lengths within 0.1 %, principal point within 1 px
        f_est, f_true = est.K[[0, 1], [0, 1]], true.K[[0, 1], [0, 1]]
        assert np.all(np.abs(f_est - f_true) < 1e-3 * f_true)
        assert np.all(np.abs(est.K[:2, 2] - true.K[:2, 2]) < 1.0)
        # distortion: the displacement field where it is largest, within 0.5 px
        error = np.linalg.norm(_displacement(est, EDGE_POINTS)
                               - _displacement(true, EDGE_POINTS), axis=1)
        assert error.max() < 0.5
        assert np.linalg.norm(_displacement(true, EDGE_POINTS), axis=1).max() > 50.0
        assert rms < 0.1
        assert f'RMS {rms:.3f} px' in out
    assert calibration.rms_px < 0.1
    assert calibration.baseline_m == pytest.approx(np.linalg.norm(T), abs=5e-4)
    R_est, _ = calibration.stereo.extrinsics()
    angle = np.degrees(np.arccos(np.clip((np.trace(R_est.T @ R) - 1) / 2, -1, 1)))
    assert angle < 0.05
    assert calibration.camera_name == 'train_0412'
    # the OpenCV file holds the same calibration
    again = load_opencv_stereo(opencv_file)
    for key in ('K', 'D', 'R', 'P'):
        np.testing.assert_allclose(getattr(again.right, key), getattr(calibration.right, key),
                                   rtol=1e-12, atol=1e-12)


def _write(path, image):
    assert cv2.imwrite(str(path), image)


def test_image_pair_layouts(tmp_path):
    rng = np.random.default_rng(0)
    left, right = (rng.integers(0, 255, (48, 64), dtype=np.uint8) for _ in range(2))
    sbs = tmp_path / 'sbs'
    sbs.mkdir()
    _write(sbs / 'view1.png', np.hstack([left, right]))
    (pair,) = find_image_pairs(sbs)
    assert pair.right_path is None
    got_left, got_right = pair.load()
    np.testing.assert_array_equal(got_left, left)
    np.testing.assert_array_equal(got_right, right)
    ros = tmp_path / 'ros'                    # camera_calibration's tarball names
    ros.mkdir()
    for k in range(2):
        _write(ros / f'left-{k:04d}.png', left)
        _write(ros / f'right-{k:04d}.png', right)
    assert [p.name for p in find_image_pairs(ros)] == ['left-0000.png/right-0000.png',
                                                      'left-0001.png/right-0001.png']
    _write(ros / 'left-0002.png', left)
    with pytest.raises(InputError, match="images without their other camera's image: "
                                         'left-0002.png'):
        find_image_pairs(ros)


def _run(capsys, folder, *extra):
    code = main([str(folder), '--size', '9x6', '--square', '0.04', '-o',
                 str(folder / 'out'), *extra])
    return code, capsys.readouterr().err


def test_bad_input_exits_with_2_and_says_why(tmp_path, capsys):
    blank = tmp_path / 'blank'
    blank.mkdir()
    for k in range(3):
        _write(blank / f'left_{k}.png', np.full((240, 320), 128, np.uint8))
        _write(blank / f'right_{k}.png', np.full((240, 320), 128, np.uint8))
    code, err = _run(capsys, blank)
    assert code == 2
    assert ('stereo_calibrate: error: no checkerboard of 9x6 inner corners found in both '
            'images of any of the 3 pairs (found in 0 left and 0 right images)') in err
    assert not (blank / 'out' / 'left.yaml').exists()
    _write(blank / 'left_3.png', np.full((480, 640), 128, np.uint8))
    _write(blank / 'right_3.png', np.full((480, 640), 128, np.uint8))
    code, err = _run(capsys, blank)
    assert code == 2 and ('size mismatch: left_3.png/right_3.png is 640x480 px per camera, '
                          'left_0.png/right_0.png is 320x240 px') in err
    _write(blank / 'right_3.png', np.full((240, 320), 128, np.uint8))
    code, err = _run(capsys, blank)
    assert code == 2 and 'size mismatch: left_3.png is 640x480 px but right_3.png is ' \
                         '320x240 px' in err
    odd = tmp_path / 'odd'
    odd.mkdir()
    _write(odd / 'pair.png', np.zeros((10, 21), np.uint8))
    code, err = _run(capsys, odd)
    assert code == 2 and 'pair.png: a side-by-side image must have an even width' in err
    code, err = _run(capsys, tmp_path / 'missing')
    assert code == 2 and 'missing: no such folder' in err
    (tmp_path / 'empty').mkdir()
    code, err = _run(capsys, tmp_path / 'empty')
    assert code == 2 and 'empty: no images' in err
    code = main([str(blank), '--size', '7x7', '--square', '0.04'])
    assert code == 2 and 'must differ' in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:         # argparse: a board size typo
        main([str(blank), '--size', '9-6', '--square', '0.04'])
    assert exit_info.value.code == 2
    assert "'9-6': expected inner corners as COLSxROWS" in capsys.readouterr().err


def test_installed_command_exit_status(tmp_path):
    exe = WS / 'install' / 'lib' / 'vlc_calibration' / 'stereo_calibrate'
    assert exe.exists(), 'run make build first'
    result = subprocess.run([str(exe), str(tmp_path), '--size', '9x6', '--square', '0.04'],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert f'stereo_calibrate: error: {tmp_path}: no images' in result.stderr


def test_package_imports_only_the_foundation():
    allowed = {'vlc_common', 'vlc_calibration'}
    project = {'vlc_common', 'vlc_stereo_camera', 'vlc_decoder', 'spot_locator',
               'imu_compensator', 'train_localizer', 'companion_localizers', 'vlc_bags',
               'vlc_evaluation', 'vlc_bringup', 'vlc_calibration'}
    package = pathlib.Path(__file__).resolve().parents[1] / 'vlc_calibration'
    for path in package.rglob('*.py'):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module] if isinstance(node, ast.ImportFrom) and node.module
                     else [])
            for name in names:
                top = name.split('.')[0]
                assert top not in project - allowed, f'{path.name} imports {name}'
                assert top != 'rclpy', f'{path.name} imports rclpy'
