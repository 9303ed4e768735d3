"""Stereo checkerboard calibration: image pairs → :class:`StereoCalibration` (OpenCV).

Steps (the procedure OpenCV's documentation recommends and ROS ``camera_calibration``
follows):

1. Corners: ``findChessboardCorners`` + ``cornerSubPix`` in every image
   (:mod:`vlc_calibration.chessboard`).
2. Each camera alone: ``calibrateCamera`` over every image of that camera in which the
   board was found, also when the other camera missed it (a board pushed into a corner
   of one image is often out of the other): K, D and the per-camera reprojection RMS.
3. The pair: ``stereoCalibrate`` over the pairs with the board in both images, the
   intrinsics of step 2 held fixed (``CALIB_FIX_INTRINSIC``): R, T (m) and the stereo
   reprojection RMS.
4. ``stereoRectify`` (``CALIB_ZERO_DISPARITY``, free scaling ``alpha``): R1, R2, P1, P2;
   the right P[0,3] = −fx'·baseline.

Distortion model: plumb_bob with k1, k2, k3 (``radial_coefficients`` 3, the default),
k3 held at 0 (2, ROS ``camera_calibration``'s default) or rational_polynomial (6).
"""
from dataclasses import dataclass, field
import logging

import cv2
import numpy as np

from vlc_calibration.chessboard import find_corners, object_points, same_order
from vlc_calibration.image_pairs import InputError
from vlc_common.core.calibration import StereoCalibration
from vlc_common.core.camera import StereoCameraModel

_LOG = logging.getLogger(__name__)
#: Fewest views of one camera for calibrateCamera (fx, fy, cx, cy, distortion and six
#: pose parameters per view from 2·N corner coordinates per view: three views are the
#: least that constrain the principal point and the distortion together).
MIN_VIEWS_PER_CAMERA = 3
_CALIBRATE_CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-10)
_RADIAL_FLAGS = {2: cv2.CALIB_FIX_K3, 3: 0, 6: cv2.CALIB_RATIONAL_MODEL}


@dataclass
class CalibrationOptions:
    """Settings of one calibration.

    Attributes
    ----------
    pattern_size : (int, int)
        Inner corners per row and per column of the board (not squares); they must
        differ.
    square_m : float
        Side of a square, m (sets the unit of the baseline).
    radial_coefficients : int
        2 (k1, k2; k3 = 0), 3 (k1, k2, k3) or 6 (rational k1…k6).
    zero_tangential : bool
        Hold p1 = p2 = 0.
    alpha : float
        ``stereoRectify``'s free scaling: 0 keeps only valid pixels (ROS's default),
        1 every source pixel.
    min_pairs : int
        Fewest pairs with the board in both images.
    camera_name : str
        Name of the pair (vehicle id) written into the files.
    """

    pattern_size: tuple
    square_m: float
    radial_coefficients: int = 3
    zero_tangential: bool = False
    alpha: float = 0.0
    min_pairs: int = 5
    camera_name: str = 'stereo'

    def __post_init__(self):
        cols, rows = (int(n) for n in self.pattern_size)
        if cols < 2 or rows < 2:
            raise InputError(f'board size {cols}x{rows}: at least 2x2 inner corners')
        if cols == rows:
            raise InputError(f'board size {cols}x{rows}: the inner corners per row and per '
                             'column must differ, or the board\'s orientation is ambiguous')
        self.pattern_size = (cols, rows)
        if not self.square_m > 0:
            raise InputError(f'square size {self.square_m} m must be > 0')
        if self.radial_coefficients not in _RADIAL_FLAGS:
            raise InputError(f'radial coefficients {self.radial_coefficients}: expected 2, '
                             '3 or 6')
        if not -1.0 <= self.alpha <= 1.0:
            raise InputError(f'alpha {self.alpha} must be in [-1, 1]')
        self.min_pairs = max(1, int(self.min_pairs))

    @property
    def flags(self):
        """OpenCV calibration flags of the distortion model."""
        return (_RADIAL_FLAGS[self.radial_coefficients]
                | (cv2.CALIB_ZERO_TANGENT_DIST if self.zero_tangential else 0))


@dataclass
class Detection:
    """Corners (N, 2) found in one pair, None where the board was not found."""

    name: str
    left: np.ndarray = None
    right: np.ndarray = None


@dataclass
class StereoCalibrationResult:
    """The calibration and what it was made from.

    ``left_views``/``right_views``: images of each camera with the board; ``pairs``:
    pairs with the board in both (the stereo calibration's); ``R``, ``T``: the right
    optical frame from the left (x_r = R·x_l + T, T in m).
    """

    calibration: StereoCalibration
    detections: list = field(default_factory=list)
    left_views: int = 0
    right_views: int = 0
    pairs: int = 0
    R: np.ndarray = None
    T: np.ndarray = None


def _points(corners):
    """Corners as OpenCV's calibration functions take them: (N, 1, 2) float32."""
    return np.asarray(corners, dtype=np.float32).reshape(-1, 1, 2)


def detect_boards(image_pairs, pattern_size):
    """Corners of every pair: (list of :class:`Detection`, (width, height) px).

    Raises InputError when the pairs' image sizes differ (from each other or between
    the cameras of one pair) or an image cannot be read.
    """
    detections, size, first = [], None, None
    for pair in image_pairs:
        left, right = pair.load()
        this = (left.shape[1], left.shape[0])
        if size is None:
            size, first = this, pair.name
        elif this != size:
            raise InputError(f'size mismatch: {pair.name} is {this[0]}x{this[1]} px per '
                             f'camera, {first} is {size[0]}x{size[1]} px')
        found = Detection(pair.name, find_corners(left, pattern_size),
                          find_corners(right, pattern_size))
        if found.left is not None and found.right is not None:
            found.right = same_order(found.left, found.right)
        _LOG.info('%s: board %s in the left image, %s in the right', pair.name,
                  'found' if found.left is not None else 'not found',
                  'found' if found.right is not None else 'not found')
        detections.append(found)
    return detections, size


def calibrate(detections, image_size, options):
    """Calibrate from detected corners (:func:`detect_boards`) → StereoCalibrationResult.

    Raises InputError when no pair has the board in both images, fewer than
    ``options.min_pairs`` do, or a camera has fewer than 3 views.
    """
    cols, rows = options.pattern_size
    views = {side: [getattr(d, side) for d in detections if getattr(d, side) is not None]
             for side in ('left', 'right')}
    both = [d for d in detections if d.left is not None and d.right is not None]
    if not both:
        raise InputError(f'no checkerboard of {cols}x{rows} inner corners found in both '
                         f'images of any of the {len(detections)} pairs (found in '
                         f'{len(views["left"])} left and {len(views["right"])} right '
                         'images); check --size (inner corners, not squares) and the images')
    if len(both) < options.min_pairs:
        raise InputError(f'the board is in both images of only {len(both)} of the '
                         f'{len(detections)} pairs; at least {options.min_pairs} are needed '
                         '(--min-pairs)')
    board = object_points(options.pattern_size, options.square_m)
    size = tuple(int(n) for n in image_size)
    intrinsics = {}
    for side, corners in views.items():
        if len(corners) < MIN_VIEWS_PER_CAMERA:
            raise InputError(f'the board is in only {len(corners)} {side} images; at least '
                             f'{MIN_VIEWS_PER_CAMERA} are needed')
        try:
            rms, K, D, _, _ = cv2.calibrateCamera(
                [board] * len(corners), [_points(c) for c in corners], size, None, None,
                flags=options.flags, criteria=_CALIBRATE_CRITERIA)
        except cv2.error as exc:
            raise InputError(f'{side} camera calibration failed: '
                             f'{" ".join(str(exc).split())}') from None
        intrinsics[side] = (float(rms), K, D.ravel())
    (rms_l, K1, D1), (rms_r, K2, D2) = intrinsics['left'], intrinsics['right']
    try:
        rms, K1, D1, K2, D2, R, T, _, _ = cv2.stereoCalibrate(
            [board] * len(both), [_points(d.left) for d in both],
            [_points(d.right) for d in both], K1, D1, K2, D2, size,
            flags=cv2.CALIB_FIX_INTRINSIC | options.flags, criteria=_CALIBRATE_CRITERIA)
    except cv2.error as exc:
        raise InputError(f'stereo calibration failed: {" ".join(str(exc).split())}') from None
    T = T.ravel()
    if not T[0] < 0:
        raise InputError(f'the right camera is not to the right of the left one (T = '
                         f'{np.round(T, 4).tolist()} m, expected T[0] < 0): are the left '
                         'and right images swapped?')
    pair = StereoCameraModel.from_stereo_extrinsics(K1, D1, K2, D2, size, R, T,
                                                    alpha=options.alpha)
    calibration = StereoCalibration(pair.left, pair.right, camera_name=options.camera_name,
                                    rms_px=float(rms), left_rms_px=rms_l, right_rms_px=rms_r,
                                    pairs=len(both))
    return StereoCalibrationResult(calibration, detections, len(views['left']),
                                   len(views['right']), len(both), R, T)
