"""Stereo calibration files: ROS camera_info_manager YAML and OpenCV FileStorage.

A real installation hands the receivers a checkerboard calibration in one of two forms:

* **ROS** (``camera_calibration``'s stereo calibrator, ``camera_info_manager``): one YAML
  file per camera with ``image_width``, ``image_height``, ``camera_name``,
  ``camera_matrix``, ``distortion_model``, ``distortion_coefficients``,
  ``rectification_matrix`` and ``projection_matrix`` (each matrix a mapping of
  ``rows``, ``cols`` and row-major ``data``). The right camera's
  ``projection_matrix[0,3] = −fx'·baseline``.
* **OpenCV** (a user's ``stereoCalibrate``/``stereoRectify`` script writing
  ``cv2.FileStorage`` YAML, XML or JSON, possibly split over several files such as the
  ``intrinsics.yml`` and ``extrinsics.yml`` of OpenCV's ``stereo_calib.cpp`` sample).
  Keys are matched without regard to case, ``_``, ``-`` and spaces
  (:data:`OPENCV_KEYS` lists the spellings). R1, R2, P1, P2 absent, the pair is rectified
  here with ``cv2.stereoRectify`` from R and T.

Every problem raises :class:`CalibrationError`, whose message names the file and the
field. Lengths are metres (a file in millimetres is read with ``length_unit_m=0.001``).
"""
from dataclasses import dataclass
import json
import math
import os
import pathlib
import re

import numpy as np
import yaml

from vlc_common.core.camera import (
    CameraModel,
    CameraModelError,
    StereoCameraModel,
    distortion_model_of,
)
from vlc_common.core.config_files import SAFE_LOADER

#: A baseline longer than this is taken for a file in other units than metres, m.
MAX_PLAUSIBLE_BASELINE_M = 5.0
#: Largest disagreement allowed between a file's R, T and those implied by its R1, R2,
#: P2: rotation angle (rad) and translation (fraction of the baseline). Files written
#: with 6 significant digits agree to ~1e-6.
_EXTRINSICS_TOL_RAD = 1e-4
_EXTRINSICS_TOL_REL = 1e-4


class CalibrationError(ValueError):
    """A calibration file that cannot be used; the message is ``<file>: <field>: <problem>``.

    Attributes
    ----------
    source : str
        The file (or files) the problem was found in.
    field : str
        The key of that file, as the file spells it, or ``(file)`` for the file as a whole.
    problem : str
        What is wrong.
    """

    def __init__(self, source, field, problem):
        self.source = str(source)
        self.field = field
        self.problem = problem
        super().__init__(f'{self.source}: {field}: {problem}')


@dataclass
class StereoCalibration:
    """A calibrated stereo pair and what is known of its calibration.

    Attributes
    ----------
    left, right : CameraModel
        The two cameras; together a rectified pair (:attr:`stereo`).
    camera_name : str
        The pair's name or the vehicle id (``camera_name`` of the ROS files without the
        ``/left``, ``/right`` suffix).
    rms_px : float
        Stereo reprojection RMS of the calibration, px; NaN when unknown.
    left_rms_px, right_rms_px : float
        Per-camera reprojection RMS, px; NaN when unknown.
    pairs : int
        Image pairs the calibration used; 0 when unknown.
    source : str
        The file(s) it was read from ('' when computed).
    """

    left: CameraModel
    right: CameraModel
    camera_name: str = ''
    rms_px: float = float('nan')
    left_rms_px: float = float('nan')
    right_rms_px: float = float('nan')
    pairs: int = 0
    source: str = ''

    def __post_init__(self):
        try:
            self.stereo = StereoCameraModel(self.left, self.right)
        except CameraModelError as exc:
            raise CalibrationError(self.source or '(calibration)', exc.field,
                                   exc.problem) from None

    @property
    def baseline_m(self):
        return self.stereo.baseline_m

    @property
    def image_size(self):
        """(width, height) the calibration belongs to, px."""
        return self.left.width, self.left.height

    def check_image_size(self, width, height, what='the images'):
        """Raise :class:`CalibrationError` unless ``width`` × ``height`` is the calibrated
        image size (a calibration is valid only at the resolution it was made at).
        """
        if (int(width), int(height)) != self.image_size:
            raise CalibrationError(self.source or '(calibration)', 'image size',
                                   f'calibrated for {self.left.width}x{self.left.height} px, '
                                   f'{what} are {int(width)}x{int(height)} px')

    def camera_info_dicts(self):
        """CameraInfo contents of the left and right cameras."""
        return self.stereo.camera_info_dicts()


# ------------------------------------------------------------------ ROS camera_info YAML
#: CameraModel field → camera_info_manager YAML key.
ROS_KEYS = {'width': 'image_width', 'height': 'image_height', 'K': 'camera_matrix',
            'D': 'distortion_coefficients', 'R': 'rectification_matrix',
            'P': 'projection_matrix', 'distortion_model': 'distortion_model'}
_ROS_REQUIRED = ('image_width', 'image_height', 'camera_matrix', 'distortion_coefficients')
_ROS_SHAPES = {'camera_matrix': (3, 3), 'rectification_matrix': (3, 3),
               'projection_matrix': (3, 4)}
#: Comment line carrying what camera_info_manager has no key for (its parsers skip it).
_ROS_META = re.compile(r'^#\s*calibration:\s*(.*)$', re.MULTILINE)


def _ros_matrix(data, key, path):
    node = data[key]
    if not isinstance(node, dict):
        raise CalibrationError(path, key, 'expected a mapping with rows, cols and data')
    for part in ('rows', 'cols', 'data'):
        if part not in node:
            raise CalibrationError(path, key, f'missing {part}')
    rows, cols, values = node['rows'], node['cols'], node['data']
    if not isinstance(values, list):
        raise CalibrationError(path, key, 'data is not a list')
    try:
        a = np.array(values, dtype=float)
    except (TypeError, ValueError):
        raise CalibrationError(path, key, f'data {values!r} is not a list of numbers') from None
    if not (isinstance(rows, int) and isinstance(cols, int)) or rows * cols != a.size:
        raise CalibrationError(path, key, f'rows {rows!r} x cols {cols!r} do not match '
                                          f'{a.size} data values')
    if key in _ROS_SHAPES and (rows, cols) != _ROS_SHAPES[key]:
        expected = 'x'.join(map(str, _ROS_SHAPES[key]))
        raise CalibrationError(path, key, f'expected {expected}, got {rows}x{cols}')
    if key == 'distortion_coefficients' and min(rows, cols) > 1:
        raise CalibrationError(path, key, f'expected 1xN, got {rows}x{cols}')
    if not np.all(np.isfinite(a)):
        raise CalibrationError(path, key, f'non-finite value {a[~np.isfinite(a)][0]}')
    return a.reshape(rows, cols)


def _camera_model(path, keys, paths=None, **fields):
    """CameraModel(**fields), a CameraModelError re-raised naming the file's key.

    ``keys`` maps CameraModel fields to the file's keys, ``paths`` (optional) to the file
    each came from when they are spread over several (default ``path``).
    """
    try:
        return CameraModel(**fields)
    except CameraModelError as exc:
        raise CalibrationError((paths or {}).get(exc.field, path),
                               keys.get(exc.field, exc.field), exc.problem) from None


def _load_yaml(path):
    path = str(path)
    if not os.path.isfile(path):
        raise CalibrationError(path, '(file)', 'no such file')
    with open(path, encoding='utf-8') as stream:
        text = stream.read()
    try:
        data = yaml.load(text, Loader=SAFE_LOADER)
    except yaml.YAMLError as exc:
        problem = ' '.join(str(exc).split())
        raise CalibrationError(path, '(file)', f'not valid YAML ({problem})') from None
    if not isinstance(data, dict):
        raise CalibrationError(path, '(file)', 'not a YAML mapping of camera_info keys')
    return data, text


def read_camera_info_yaml(path):
    """One camera_info_manager YAML file → (CameraModel, camera_name, metadata).

    ``rectification_matrix`` defaults to the identity and ``projection_matrix`` to
    ``[camera_matrix | 0]`` (a monocular calibration); ``distortion_model`` to
    ``plumb_bob``; ``camera_name`` to ''. Unknown keys are ignored, as
    camera_info_manager does. ``metadata`` holds the values of a ``# calibration:``
    comment line written by :func:`write_camera_info_yaml` (``stereo_rms_px``,
    ``camera_rms_px``, ``pairs``), empty for other files.
    """
    data, text = _load_yaml(path)
    for key in _ROS_REQUIRED:
        if key not in data:
            raise CalibrationError(path, key, 'missing')
    size = {}
    for key in ('image_width', 'image_height'):
        value = data[key]
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            raise CalibrationError(path, key, f'{value!r} is not a positive integer')
        size[key] = value
    model = data.get('distortion_model', 'plumb_bob')
    matrices = {key: _ros_matrix(data, key, path) for key in
                ('camera_matrix', 'distortion_coefficients', 'rectification_matrix',
                 'projection_matrix') if key in data}
    camera = _camera_model(path, ROS_KEYS, width=size['image_width'],
                           height=size['image_height'], K=matrices['camera_matrix'],
                           D=matrices['distortion_coefficients'].ravel(),
                           R=matrices.get('rectification_matrix'),
                           P=matrices.get('projection_matrix'), distortion_model=model)
    name = data.get('camera_name', '')
    return camera, '' if name is None else str(name), _parse_meta(text)


def _parse_meta(text):
    meta = {}
    for line in _ROS_META.findall(text):
        for item in line.split(','):
            parts = item.split()
            if len(parts) == 2:
                try:
                    meta[parts[0]] = float(parts[1])
                except ValueError:
                    continue
    return meta


def _fmt(values):
    return '[' + ', '.join(repr(float(v) + 0.0) for v in np.ravel(values)) + ']'


def write_camera_info_yaml(path, camera, camera_name='', meta=None):
    """Write one camera as camera_info_manager YAML (the layout ``camera_calibration``
    writes, values at full double precision).

    ``meta`` (name → number, e.g. ``stereo_rms_px``) goes into a ``# calibration:``
    comment line, which ROS parsers skip and :func:`read_camera_info_yaml` reads back.
    """
    lines = ['# Camera calibration (camera_info_manager format), written by '
             'vlc_common.core.calibration.']
    finite = {k: v for k, v in (meta or {}).items() if v is not None and math.isfinite(v)}
    if finite:
        lines.append('# calibration: ' + ', '.join(f'{k} {float(v)!r}' for k, v in
                                                   finite.items()))
    name = str(camera_name)
    if not re.fullmatch(r'[A-Za-z0-9_./-]+', name):
        name = json.dumps(name)           # a double-quoted YAML scalar
    lines += [f'image_width: {camera.width}', f'image_height: {camera.height}',
              f'camera_name: {name}']
    for key, m in (('camera_matrix', camera.K), ('distortion_model', None),
                   ('distortion_coefficients', camera.D.reshape(1, -1)),
                   ('rectification_matrix', camera.R), ('projection_matrix', camera.P)):
        if m is None:
            lines.append(f'distortion_model: {camera.distortion_model}')
            continue
        lines += [f'{key}:', f'  rows: {m.shape[0]}', f'  cols: {m.shape[1]}',
                  f'  data: {_fmt(m)}']
    pathlib.Path(path).write_text('\n'.join(lines) + '\n', encoding='utf-8')


def _stereo_name(left, right):
    for suffix in ('/left', '_left'):
        if left.endswith(suffix):
            return left[:-len(suffix)]
    return left or right


def load_ros_stereo(left_path, right_path):
    """Two camera_info_manager YAML files (left, right) → :class:`StereoCalibration`."""
    left, left_name, meta = read_camera_info_yaml(left_path)
    right, right_name, right_meta = read_camera_info_yaml(right_path)
    try:
        StereoCameraModel(left, right)
    except CameraModelError as exc:
        field = ('image_width, image_height' if exc.field == 'width'
                 else ROS_KEYS.get(exc.field, exc.field))
        raise CalibrationError(right_path, field, f'with {left_path}: {exc.problem}') from None
    return StereoCalibration(left, right, camera_name=_stereo_name(left_name, right_name),
                             rms_px=meta.get('stereo_rms_px', math.nan),
                             left_rms_px=meta.get('camera_rms_px', math.nan),
                             right_rms_px=right_meta.get('camera_rms_px', math.nan),
                             pairs=int(meta.get('pairs', 0)),
                             source=f'{left_path}, {right_path}')


def save_ros_stereo(calibration, left_path, right_path):
    """Write ``calibration`` as ``left.yaml``/``right.yaml`` camera_info_manager files,
    camera names ``<camera_name>/left`` and ``/right`` (as ``camera_calibration``).
    """
    name = calibration.camera_name or 'stereo'
    for path, camera, side, rms in ((left_path, calibration.left, 'left',
                                     calibration.left_rms_px),
                                    (right_path, calibration.right, 'right',
                                     calibration.right_rms_px)):
        write_camera_info_yaml(path, camera, f'{name}/{side}',
                               meta={'stereo_rms_px': calibration.rms_px,
                                     'camera_rms_px': rms,
                                     'pairs': calibration.pairs or math.nan})


# ------------------------------------------------------------------ OpenCV FileStorage
#: Accepted spellings of the OpenCV keys (compared lower-case without ``_``, ``-`` or
#: spaces, so ``cameraMatrix1``, ``camera_matrix_1`` and ``CameraMatrix1`` are one key).
OPENCV_KEYS = {
    'K1': ('K1', 'M1', 'cameraMatrix1', 'cameraMatrixL', 'cameraMatrixLeft', 'K_left',
           'mtx1', 'mtxL', 'mtx_left', 'left_camera_matrix'),
    'D1': ('D1', 'distCoeffs1', 'distCoeffsL', 'distCoeffsLeft', 'D_left', 'dist1', 'distL',
           'dist_left', 'left_distortion'),
    'K2': ('K2', 'M2', 'cameraMatrix2', 'cameraMatrixR', 'cameraMatrixRight', 'K_right',
           'mtx2', 'mtxR', 'mtx_right', 'right_camera_matrix'),
    'D2': ('D2', 'distCoeffs2', 'distCoeffsR', 'distCoeffsRight', 'D_right', 'dist2',
           'distR', 'dist_right', 'right_distortion'),
    'R': ('R', 'rotation', 'R_stereo'),
    'T': ('T', 'translation', 'T_stereo'),
    'R1': ('R1', 'rectification1', 'R_rect_left'),
    'R2': ('R2', 'rectification2', 'R_rect_right'),
    'P1': ('P1', 'projection1', 'P_rect_left'),
    'P2': ('P2', 'projection2', 'P_rect_right'),
    'image_size': ('image_size', 'imageSize', 'img_size', 'size'),
    'image_width': ('image_width', 'imageWidth', 'width'),
    'image_height': ('image_height', 'imageHeight', 'height'),
    'camera_name': ('camera_name', 'cameraName', 'name', 'vehicle_id'),
    'rms': ('rms', 'rms_px', 'rms_stereo_px', 'stereo_rms', 'reprojection_error'),
    'rms_left': ('rms_left_px', 'rms_left', 'left_rms'),
    'rms_right': ('rms_right_px', 'rms_right', 'right_rms'),
    'pairs': ('pairs', 'n_pairs', 'image_pairs'),
}


def _norm(key):
    return re.sub(r'[\s_\-]', '', str(key)).lower()


_ALIASES = {_norm(alias): canonical for canonical, aliases in OPENCV_KEYS.items()
            for alias in aliases}


def _node_value(node):
    """A FileNode → ndarray (matrix or sequence), float, int or str."""
    if node.isString():
        return node.string()
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return float(node.real())
    if node.isSeq():
        return np.array([_node_value(node.at(i)) for i in range(node.size())], dtype=object)
    if node.isMap():
        mat = node.mat()
        if mat is not None:
            return np.asarray(mat, dtype=float)
    return None


def _read_opencv_nodes(paths):
    """{canonical key: (value, key as spelled, file)} merged over ``paths``."""
    import cv2
    found = {}
    for path in paths:
        path = str(path)
        if not os.path.isfile(path):
            raise CalibrationError(path, '(file)', 'no such file')
        try:
            fs = cv2.FileStorage(path, cv2.FILE_STORAGE_READ)
        except (cv2.error, SystemError) as exc:
            # OpenCV 5's binding raises SystemError with the cv2.error as its cause
            cause = exc.__cause__ or exc
            detail = ' '.join(str(cause).split())
            raise CalibrationError(path, '(file)', 'cv2.FileStorage cannot parse it ('
                                   f'{detail})') from None
        if not fs.isOpened():
            raise CalibrationError(path, '(file)', 'cv2.FileStorage cannot open it')
        try:
            for key in fs.root().keys():
                canonical = _ALIASES.get(_norm(key))
                if canonical is None:
                    continue                     # E, F, Q, dates, user notes
                if canonical in found:
                    _, other, other_path = found[canonical]
                    raise CalibrationError(path, key, f'given twice (also as {other} in '
                                                      f'{other_path})')
                found[canonical] = (_node_value(fs.getNode(key)), key, path)
        finally:
            fs.release()
    return found


def _cv_matrix(found, canonical, shape, source):
    if canonical not in found:
        spellings = ', '.join(OPENCV_KEYS[canonical])
        raise CalibrationError(source, canonical, f'missing (accepted keys: {spellings})')
    value, key, path = found[canonical]
    try:
        a = np.array(np.asarray(value, dtype=object).tolist(), dtype=float)
    except (TypeError, ValueError):
        shown = repr(value) if len(repr(value)) <= 80 else repr(value)[:77] + '...'
        raise CalibrationError(path, key, f'{shown} is not a numeric matrix') from None
    if shape is not None:
        if a.size != int(np.prod(shape)):
            expected = 'x'.join(map(str, shape))
            got = 'x'.join(map(str, a.shape)) if a.ndim else 'a scalar'
            raise CalibrationError(path, key, f'expected {expected}, got {got}')
        a = a.reshape(shape)
    if not np.all(np.isfinite(a)):
        raise CalibrationError(path, key, f'non-finite value {a[~np.isfinite(a)][0]}')
    return a, key, path


def _cv_image_size(found, image_size, source):
    if 'image_size' in found:
        size, key, path = _cv_matrix(found, 'image_size', None, source)
        if size.size != 2:
            raise CalibrationError(path, key, f'expected [width, height], got {size.size} '
                                              'values')
        size = size.ravel()
    elif 'image_width' in found and 'image_height' in found:
        size = np.array([_cv_matrix(found, k, (1,), source)[0][0]
                         for k in ('image_width', 'image_height')])
        key, path = 'image_width, image_height', found['image_width'][2]
    elif image_size is not None:
        return int(image_size[0]), int(image_size[1])
    else:
        raise CalibrationError(source, 'image_size', 'missing (accepted keys: '
                               f'{", ".join(OPENCV_KEYS["image_size"])}, or image_width and '
                               'image_height); or give image_size')
    if not np.all((size > 0) & (size == np.round(size))):
        raise CalibrationError(path, key, f'{size.tolist()} is not a positive integer size')
    width, height = int(size[0]), int(size[1])
    if image_size is not None and (width, height) != (int(image_size[0]), int(image_size[1])):
        raise CalibrationError(path, key, f'calibrated for {width}x{height} px, not the '
                                          f'given {int(image_size[0])}x{int(image_size[1])}')
    return width, height


def load_opencv_stereo(paths, alpha=0.0, length_unit_m=1.0, image_size=None):
    """OpenCV FileStorage file(s) of a stereo calibration → :class:`StereoCalibration`.

    Parameters
    ----------
    paths : str or sequence of str
        One file or several (their keys merged; a key in two files is an error).
    alpha : float
        ``cv2.stereoRectify``'s free scaling, used only when R1, R2, P1, P2 are absent.
    length_unit_m : float
        Metres per length unit of the file (T, P2[0,3]); 0.001 for millimetres.
    image_size : (int, int), optional
        (width, height), px: required when the files hold no image size, else checked
        against it.

    Required keys: K1, D1, K2, D2, an image size, and R1, R2, P1, P2 or R and T.
    """
    paths = [paths] if isinstance(paths, (str, os.PathLike)) else list(paths)
    source = ', '.join(map(str, paths))
    found = _read_opencv_nodes(paths)
    width, height = _cv_image_size(found, image_size, source)
    cams = []
    for side in ('1', '2'):
        K, k_key, k_path = _cv_matrix(found, 'K' + side, (3, 3), source)
        D, d_key, d_path = _cv_matrix(found, 'D' + side, None, source)
        try:
            model, D = distortion_model_of(D)
        except CameraModelError as exc:
            raise CalibrationError(d_path, d_key, exc.problem) from None
        keys = {'K': k_key, 'D': d_key, 'width': 'image size', 'height': 'image size'}
        _camera_model(k_path, keys, {'D': d_path}, width=width, height=height, K=K, D=D,
                      distortion_model=model)                   # K and D checked alone
        cams.append((K, D, model, keys, {'K': k_path, 'D': d_path}))
    rectified = [c for c in ('R1', 'R2', 'P1', 'P2') if c in found]
    extrinsic = {}
    for canonical, shape in (('R', (3, 3)), ('T', (3,))):
        if canonical in found:
            extrinsic[canonical] = _cv_matrix(found, canonical, shape, source)
    if 'T' in extrinsic:
        T, key, path = extrinsic['T']
        extrinsic['T'] = (T * length_unit_m, key, path)
    if rectified:
        mats = {c: _cv_matrix(found, c, (3, 3) if c[0] == 'R' else (3, 4), source)
                for c in ('R1', 'R2', 'P1', 'P2')}
        models = []
        for side, (K, D, model, keys, paths_of) in zip('12', cams):
            R_rect, r_key, r_path = mats['R' + side]
            P, p_key, p_path = mats['P' + side]
            P = P.copy()
            P[:, 3] *= length_unit_m
            models.append(_camera_model(p_path, dict(keys, R=r_key, P=p_key),
                                        dict(paths_of, R=r_path), width=width, height=height,
                                        K=K, D=D, R=R_rect, P=P, distortion_model=model))
    else:
        for canonical in ('R', 'T'):
            if canonical not in extrinsic:
                raise CalibrationError(source, canonical, 'missing (needed to rectify, as '
                                       'R1, R2, P1, P2 are absent; accepted keys: '
                                       f'{", ".join(OPENCV_KEYS[canonical])})')
        (K1, D1, *_), (K2, D2, *_) = cams
        try:
            pair = StereoCameraModel.from_stereo_extrinsics(
                K1, D1, K2, D2, (width, height), extrinsic['R'][0], extrinsic['T'][0],
                alpha=alpha)
        except CameraModelError as exc:
            raise CalibrationError(extrinsic['R'][2], 'R, T', exc.problem) from None
        models = [pair.left, pair.right]
    try:
        stereo = StereoCameraModel(*models)
    except CameraModelError as exc:
        raise CalibrationError(source, 'P2' if exc.field == 'P' else exc.field,
                               exc.problem) from None
    _check_baseline(stereo, found, source)
    if rectified:
        _check_extrinsics(stereo, extrinsic)
    meta = {}
    for canonical in ('rms', 'rms_left', 'rms_right', 'pairs'):
        if canonical in found:
            meta[canonical] = float(_cv_matrix(found, canonical, (1,), source)[0][0])
    name = found.get('camera_name', ('', None, None))[0]
    return StereoCalibration(models[0], models[1], camera_name=str(name or ''),
                             rms_px=meta.get('rms', math.nan),
                             left_rms_px=meta.get('rms_left', math.nan),
                             right_rms_px=meta.get('rms_right', math.nan),
                             pairs=int(meta.get('pairs', 0)), source=source)


def _check_baseline(stereo, found, source):
    if stereo.baseline_m > MAX_PLAUSIBLE_BASELINE_M:
        key, path = (found['P2'][1], found['P2'][2]) if 'P2' in found else ('T', source)
        raise CalibrationError(path, key, f'baseline {stereo.baseline_m:g} is not a stereo '
                                          'baseline in metres; a file in millimetres is read '
                                          'with length_unit_m=0.001')


def _check_extrinsics(stereo, extrinsic):
    R_rect, T_rect = stereo.extrinsics()
    if 'R' in extrinsic:
        R, key, path = extrinsic['R']
        angle = np.arccos(np.clip((np.trace(R_rect.T @ R) - 1.0) / 2.0, -1.0, 1.0))
        if angle > _EXTRINSICS_TOL_RAD:
            raise CalibrationError(path, key, f'differs by {np.degrees(angle):.3g} deg from '
                                              'the rotation R2ᵀ·R1 of R1, R2')
    if 'T' in extrinsic:
        T, key, path = extrinsic['T']
        off = np.linalg.norm(T - T_rect)
        if off > _EXTRINSICS_TOL_REL * stereo.baseline_m:
            raise CalibrationError(path, key, f'{T.tolist()} differs by {off:.3g} m from the '
                                              f'translation {T_rect.tolist()} of R2 and P2')


def save_opencv_stereo(calibration, path):
    """Write ``calibration`` with ``cv2.FileStorage`` (YAML, XML or JSON by extension).

    Keys: K1, D1, K2, D2, R, T (m; derived from the rectification), R1, R2, P1, P2,
    image_width, image_height, camera_name, and rms_stereo_px, rms_left_px, rms_right_px,
    pairs where known.
    """
    import cv2
    R, T = calibration.stereo.extrinsics()
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    if not fs.isOpened():
        raise CalibrationError(path, '(file)', 'cv2.FileStorage cannot write it')
    try:
        left, right = calibration.left, calibration.right
        for key, value in (('K1', left.K), ('D1', left.D.reshape(1, -1)), ('K2', right.K),
                           ('D2', right.D.reshape(1, -1)), ('R', R), ('T', T.reshape(3, 1)),
                           ('R1', left.R), ('R2', right.R), ('P1', left.P), ('P2', right.P)):
            fs.write(key, np.asarray(value, dtype=np.float64))
        fs.write('image_width', int(left.width))
        fs.write('image_height', int(left.height))
        fs.write('camera_name', calibration.camera_name or '')
        for key, value in (('rms_stereo_px', calibration.rms_px),
                           ('rms_left_px', calibration.left_rms_px),
                           ('rms_right_px', calibration.right_rms_px)):
            if math.isfinite(value):
                fs.write(key, float(value))
        if calibration.pairs:
            fs.write('pairs', int(calibration.pairs))
    finally:
        fs.release()


# ------------------------------------------------------------------ either format
def _is_ros_yaml(path):
    try:
        with open(path, encoding='utf-8') as stream:
            head = stream.read(4096)
    except (OSError, UnicodeDecodeError):
        return False
    if head.lstrip().startswith(('%YAML', '<?xml', '{')):
        return False                      # cv2.FileStorage YAML, XML, JSON
    return re.search(r'^camera_matrix\s*:', head, re.MULTILINE) is not None


def load_stereo_calibration(paths, alpha=0.0, length_unit_m=1.0, image_size=None):
    """Read a stereo calibration in either format.

    Two camera_info_manager YAML files (left, right, in that order) are read by
    :func:`load_ros_stereo`; anything else by :func:`load_opencv_stereo` (its
    ``alpha``, ``length_unit_m`` and ``image_size``). With ``image_size`` the result is
    checked against it.
    """
    paths = [paths] if isinstance(paths, (str, os.PathLike)) else list(paths)
    if len(paths) == 2 and all(_is_ros_yaml(p) for p in paths):
        calibration = load_ros_stereo(*paths)
        if image_size is not None:
            calibration.check_image_size(*image_size, what='the given size')
        return calibration
    if not paths:
        raise CalibrationError('(no file)', '(file)', 'no calibration file given')
    return load_opencv_stereo(paths, alpha=alpha, length_unit_m=length_unit_m,
                              image_size=image_size)
