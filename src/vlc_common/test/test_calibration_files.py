"""Calibration files (core/calibration.py): ROS camera_info_manager YAML, OpenCV
FileStorage, round trips and the message of every error.

OpenCV files are written with cv2.FileStorage as a user's stereoCalibrate script writes
them; ROS files by hand, as ``camera_calibration`` writes them (5 decimals, rows split).
"""
import textwrap

import cv2
import numpy as np
import pytest

from vlc_common.core import rotations as geo
from vlc_common.core.calibration import (
    CalibrationError,
    StereoCalibration,
    load_opencv_stereo,
    load_ros_stereo,
    load_stereo_calibration,
    read_camera_info_yaml,
    save_opencv_stereo,
    save_ros_stereo,
)
from vlc_common.core.camera import StereoCameraModel

K1 = np.array([[1040.0, 0.0, 643.2], [0.0, 1041.5, 356.1], [0.0, 0.0, 1.0]])
D1 = np.array([-0.30, 0.10, 0.0008, -0.0005, -0.015])
K2 = np.array([[1043.0, 0.0, 636.9], [0.0, 1044.1, 362.4], [0.0, 0.0, 1.0]])
D2 = np.array([-0.29, 0.095, -0.0006, 0.0004, -0.012])
R = geo.rot_z(np.radians(0.08)) @ geo.rot_y(np.radians(0.2)) @ geo.rot_x(np.radians(-0.1))
T = -R @ np.array([0.12, 0.002, -0.001])
SIZE = (1280, 720)


@pytest.fixture(scope='module')
def pair():
    return StereoCameraModel.from_stereo_extrinsics(K1, D1, K2, D2, SIZE, R, T)


def _assert_same_cameras(a, b, atol=0.0):
    for cam_a, cam_b in ((a.left, b.left), (a.right, b.right)):
        for key in ('K', 'D', 'R', 'P'):
            np.testing.assert_allclose(getattr(cam_a, key), getattr(cam_b, key), rtol=0,
                                       atol=atol, err_msg=key)
        assert (cam_a.width, cam_a.height) == (cam_b.width, cam_b.height)
        assert cam_a.distortion_model == cam_b.distortion_model


# ------------------------------------------------------------------ ROS YAML
def test_ros_round_trip_is_exact(tmp_path, pair):
    calibration = StereoCalibration(pair.left, pair.right, camera_name='train_0412',
                                    rms_px=0.141, left_rms_px=0.12, right_rms_px=0.13,
                                    pairs=14)
    left, right = tmp_path / 'left.yaml', tmp_path / 'right.yaml'
    save_ros_stereo(calibration, left, right)
    text = left.read_text()
    for key in ('image_width: 1280', 'image_height: 720', 'camera_name: train_0412/left',
                'camera_matrix:', 'distortion_model: plumb_bob', 'distortion_coefficients:',
                'rectification_matrix:', 'projection_matrix:', '  rows: 3', '  cols: 4'):
        assert key in text
    loaded = load_stereo_calibration([left, right])
    _assert_same_cameras(loaded, calibration)
    assert loaded.camera_name == 'train_0412'
    assert (loaded.rms_px, loaded.left_rms_px, loaded.right_rms_px, loaded.pairs) == (
        0.141, 0.12, 0.13, 14)
    assert loaded.baseline_m == pytest.approx(np.linalg.norm(T), rel=1e-12)
    assert str(left) in loaded.source and str(right) in loaded.source


LEFT_YAML = """\
image_width: 1280
image_height: 720
camera_name: narrow_stereo/left
camera_matrix:
  rows: 3
  cols: 3
  data: [1040.00000, 0.00000, 643.20000, 0.00000, 1041.50000, 356.10000,
         0.00000, 0.00000, 1.00000]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.300000, 0.100000, 0.000800, -0.000500, -0.015000]
rectification_matrix:
  rows: 3
  cols: 3
  data: [0.99983, 0.01666, -0.00833, -0.01666, 0.99986, 0.00093, 0.00835, -0.00079, 0.99996]
projection_matrix:
  rows: 3
  cols: 4
  data: [1030.00000, 0.00000, 640.00000, 0.00000, 0.00000, 1030.00000, 358.00000, 0.00000,
         0.00000, 0.00000, 1.00000, 0.00000]
"""
RIGHT_YAML = (LEFT_YAML.replace('narrow_stereo/left', 'narrow_stereo/right')
              .replace('640.00000, 0.00000, 0.00000, 1030.00000',
                       '640.00000, -123.60000, 0.00000, 1030.00000'))


def _write_pair(tmp_path, left_text=LEFT_YAML, right_text=RIGHT_YAML):
    left, right = tmp_path / 'left.yaml', tmp_path / 'right.yaml'
    left.write_text(left_text)
    right.write_text(right_text)
    return left, right


def test_hand_written_ros_files(tmp_path):
    left, right = _write_pair(tmp_path)
    calibration = load_ros_stereo(left, right)
    np.testing.assert_array_equal(calibration.left.K, K1)
    np.testing.assert_array_equal(calibration.left.D, D1)
    assert calibration.left.R[0, 1] == 0.01666          # a rotation written to 5 decimals
    assert calibration.baseline_m == pytest.approx(0.12)             # 123.6 / 1030
    assert calibration.camera_name == 'narrow_stereo'
    assert np.isnan(calibration.rms_px) and calibration.pairs == 0
    camera, name, meta = read_camera_info_yaml(right)
    assert name == 'narrow_stereo/right' and meta == {}
    # a monocular file: R and P default to I and [K | 0]
    mono = tmp_path / 'mono.yaml'
    mono.write_text(LEFT_YAML.split('rectification_matrix')[0])
    camera, _, _ = read_camera_info_yaml(mono)
    np.testing.assert_array_equal(camera.P, np.column_stack([K1, np.zeros(3)]))


@pytest.mark.parametrize('edit, field, words', [
    (('camera_matrix:\n  rows: 3\n  cols: 3\n', 'camera_matrx:\n  rows: 3\n  cols: 3\n'),
     'camera_matrix', 'missing'),
    (('image_height: 720\n', ''), 'image_height', 'missing'),
    (('image_width: 1280', 'image_width: wide'), 'image_width', 'not a positive integer'),
    (('  rows: 1\n  cols: 5', '  rows: 1\n  cols: 4'), 'distortion_coefficients',
     'do not match 5 data values'),
    (('-0.300000, 0.100000, 0.000800, -0.000500, -0.015000]', '-0.3, 0.1, 0.0008]\n  '
      'xx: 0'), 'distortion_coefficients', 'do not match 3 data values'),
    (('  rows: 3\n  cols: 4', '  rows: 4\n  cols: 3'), 'projection_matrix',
     'expected 3x4, got 4x3'),
    (('-0.015000]', '.nan]'), 'distortion_coefficients', 'non-finite value nan'),
    (('data: [1040.00000,', 'data: [-1040.00000,'), 'camera_matrix',
     'focal lengths fx = -1040, fy = 1041.5 px must be > 0'),
    (('data: [1030.00000,', 'data: [0.0,'), 'projection_matrix', 'must be > 0'),
    (('data: [0.99983, 0.01666', 'data: [0.99983, 0.01766'), 'rectification_matrix',
     'not a rotation'),
    (('distortion_model: plumb_bob', 'distortion_model: equidistant'), 'distortion_model',
     "'equidistant' is not supported"),
])
def test_ros_file_errors_name_file_and_field(tmp_path, edit, field, words):
    text = LEFT_YAML.replace(*edit)
    assert text != LEFT_YAML
    left, right = _write_pair(tmp_path, left_text=text)
    with pytest.raises(CalibrationError) as info:
        load_ros_stereo(left, right)
    assert info.value.field == field
    assert info.value.source == str(left)
    assert words in str(info.value)
    assert str(info.value).startswith(f'{left}: {field}: ')


def test_ros_pair_errors(tmp_path):
    left, right = _write_pair(tmp_path, right_text=LEFT_YAML)      # right without baseline
    with pytest.raises(CalibrationError, match=r'right.yaml: projection_matrix: .*baseline '
                                               r'of 0 m; must be > 0'):
        load_ros_stereo(left, right)
    left, right = _write_pair(tmp_path, right_text=RIGHT_YAML.replace('720', '480'))
    with pytest.raises(CalibrationError, match='right.yaml: image_width, image_height: .*'
                                               'image sizes differ'):
        load_ros_stereo(left, right)
    left.write_text('camera_matrix: [1, 2\n')
    with pytest.raises(CalibrationError, match=r'left.yaml: \(file\): not valid YAML'):
        load_ros_stereo(left, right)
    with pytest.raises(CalibrationError, match=r'nothere.yaml: \(file\): no such file'):
        load_ros_stereo(tmp_path / 'nothere.yaml', right)


def test_image_size_check(tmp_path):
    calibration = load_ros_stereo(*_write_pair(tmp_path))
    calibration.check_image_size(1280, 720)
    with pytest.raises(CalibrationError) as info:
        calibration.check_image_size(640, 480)
    assert info.value.field == 'image size'
    assert str(info.value) == (f'{tmp_path}/left.yaml, {tmp_path}/right.yaml: image size: '
                               'calibrated for 1280x720 px, the images are 640x480 px')
    with pytest.raises(CalibrationError, match='calibrated for 1280x720 px, the given size'):
        load_stereo_calibration(list(_write_pair(tmp_path)), image_size=(1920, 1080))


# ------------------------------------------------------------------ OpenCV FileStorage
def _user_script_file(path, pair, keys=('K1', 'D1', 'K2', 'D2'), rectified=True,
                      scale=1.0):
    """What a user's stereoCalibrate + stereoRectify script writes with cv2.FileStorage."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in zip(keys, (K1, D1.reshape(1, 5), K2, D2.reshape(1, 5))):
        fs.write(key, value)
    fs.write('R', R)
    fs.write('T', T.reshape(3, 1) * scale)
    fs.write('E', np.eye(3))
    fs.write('F', np.eye(3))
    if rectified:
        P2 = pair.right.P.copy()
        P2[0, 3] *= scale
        for key, value in (('R1', pair.left.R), ('R2', pair.right.R), ('P1', pair.left.P),
                           ('P2', P2), ('Q', np.eye(4))):
            fs.write(key, value)
    fs.write('imageSize', SIZE)
    fs.write('calibration_date', 'Tue Dec  1 10:00:00 2026')
    fs.release()
    return path


@pytest.mark.parametrize('suffix', ['yml', 'xml'])
def test_opencv_user_file(tmp_path, pair, suffix):
    path = _user_script_file(tmp_path / f'stereo.{suffix}', pair)
    calibration = load_stereo_calibration(path)
    _assert_same_cameras(calibration, pair)
    assert calibration.baseline_m == pytest.approx(np.linalg.norm(T), rel=1e-12)
    assert calibration.source == str(path)


def test_opencv_spellings_split_files_and_rectification_done_here(tmp_path, pair):
    # stereo_calib.cpp's two files, M1/M2 for the camera matrices, no R1..P2
    intrinsics = tmp_path / 'intrinsics.yml'
    fs = cv2.FileStorage(str(intrinsics), cv2.FILE_STORAGE_WRITE)
    for key, value in (('M1', K1), ('D1', D1.reshape(1, 5)), ('M2', K2),
                       ('D2', D2.reshape(1, 5))):
        fs.write(key, value)
    fs.release()
    extrinsics = tmp_path / 'extrinsics.yml'
    extrinsics.write_text(textwrap.dedent(f"""\
        %YAML:1.0
        ---
        R: [{', '.join(repr(float(v)) for v in R.ravel())}]
        T: [{', '.join(repr(float(v)) for v in T.ravel())}]
        image_width: 1280
        image_height: 720
        """))
    calibration = load_opencv_stereo([intrinsics, extrinsics], alpha=0.0)
    _assert_same_cameras(calibration, pair, atol=1e-9)
    # cameraMatrixL, distCoeffsL, ... with a 4-coefficient D (k3 = 0)
    path = tmp_path / 'lr.yaml'
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in (('cameraMatrixL', K1), ('distCoeffsL', D1[:4]),
                       ('cameraMatrixR', K2), ('distCoeffsR', D2[:4]), ('R', R), ('T', T),
                       ('image_width', 1280), ('image_height', 720)):
        fs.write(key, value)
    fs.release()
    calibration = load_opencv_stereo(path)
    np.testing.assert_array_equal(calibration.right.D, np.append(D2[:4], 0.0))


def test_opencv_round_trip(tmp_path, pair):
    original = StereoCalibration(pair.left, pair.right, camera_name='train 0412',
                                 rms_px=0.2, left_rms_px=0.15, pairs=12)
    for name in ('out.yaml', 'out.xml'):
        save_opencv_stereo(original, tmp_path / name)
        loaded = load_opencv_stereo(tmp_path / name)
        _assert_same_cameras(loaded, original)
        assert loaded.camera_name == 'train 0412' and loaded.pairs == 12
        assert (loaded.rms_px, loaded.left_rms_px) == (0.2, 0.15)
        assert np.isnan(loaded.right_rms_px)


def test_opencv_millimetres(tmp_path, pair):
    path = _user_script_file(tmp_path / 'mm.yml', pair, scale=1000.0)
    with pytest.raises(CalibrationError, match=r'mm.yml: P2: baseline 120\.0\d* is not a '
                                               'stereo baseline in metres; .*length_unit_m'):
        load_opencv_stereo(path)
    assert load_opencv_stereo(path, length_unit_m=0.001).baseline_m == pytest.approx(
        np.linalg.norm(T), rel=1e-12)


def _edited_user_file(tmp_path, pair, **replace):
    path = _user_script_file(tmp_path / 'stereo.yml', pair)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    values = {key: fs.getNode(key).mat() for key in fs.root().keys()
              if fs.getNode(key).isMap()}
    fs.release()
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in values.items():
        if key in replace and replace[key] is None:
            continue
        fs.write(key, replace.get(key, value))
    fs.release()
    return path


@pytest.mark.parametrize('replace, field, words', [
    (dict(K2=None), 'K2', 'missing (accepted keys: K2, M2, cameraMatrix2'),
    (dict(K1=np.eye(3)[:2]), 'K1', 'expected 3x3, got 2x3'),
    (dict(D1=np.zeros((1, 6))), 'D1', '6 distortion coefficients'),
    (dict(D2=np.array([[-0.3, np.nan, 0, 0, 0]])), 'D2', 'non-finite value nan'),
    (dict(K2=np.diag([0.0, 1040.0, 1.0])), 'K2', 'fx = 0, fy = 1040 px must be > 0'),
    (dict(imageSize=None), 'image_size', 'missing (accepted keys: image_size, imageSize'),
    (dict(imageSize=np.array([1280.5, 720.0])), 'imageSize', 'not a positive integer size'),
    (dict(R2=None), 'R2', 'missing'),
    (dict(R=np.eye(3)), 'R', 'differs by 0.238 deg from the rotation R2ᵀ·R1'),
    (dict(T=np.array([[-0.1], [0.0], [0.0]])), 'T', 'differs by 0.0202 m'),
    (dict(P2=np.eye(3, 4)), 'P2', 'not a rectified pair'),
])
def test_opencv_errors_name_file_and_field(tmp_path, pair, replace, field, words):
    path = _edited_user_file(tmp_path, pair, **replace)
    with pytest.raises(CalibrationError) as info:
        load_opencv_stereo(path)
    assert info.value.field == field
    assert info.value.source == str(path)
    assert words in info.value.problem


def test_opencv_file_errors(tmp_path, pair):
    bad = tmp_path / 'bad.yml'
    bad.write_text('%YAML:1.0\nK1: [1, 2\n')
    with pytest.raises(CalibrationError, match=r'bad.yml: \(file\): cv2.FileStorage cannot '
                                               'parse it'):
        load_stereo_calibration(bad)
    with pytest.raises(CalibrationError, match=r'missing.yml: \(file\): no such file'):
        load_stereo_calibration(tmp_path / 'missing.yml')
    path = _user_script_file(tmp_path / 'stereo.yml', pair)
    other = _user_script_file(tmp_path / 'again.yml', pair, keys=('M1', 'D1x', 'K2x', 'D2x'))
    with pytest.raises(CalibrationError, match=r'again.yml: M1: given twice \(also as K1 in '):
        load_opencv_stereo([path, other])
    with pytest.raises(CalibrationError, match='calibrated for 1280x720 px, not the given '
                                               '640x480'):
        load_opencv_stereo(path, image_size=(640, 480))
    no_size = _edited_user_file(tmp_path, pair, imageSize=None)
    assert load_opencv_stereo(no_size, image_size=SIZE).image_size == SIZE
