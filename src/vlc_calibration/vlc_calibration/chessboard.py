"""Checkerboard corners in one image: OpenCV's detector, sub-pixel refinement, and an
order that is the same in both images of a stereo pair.
"""
import cv2
import numpy as np

#: ``findChessboardCorners`` flags, tried in turn: adaptive threshold with the fast
#: check that gives up quickly on an image without a board; then, as ROS
#: ``camera_calibration``, also with histogram normalisation (very uneven lighting),
#: which costs ten times more on an image whose board is cut by the image edge.
FIND_FLAGS = (cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_FAST_CHECK,
              cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
              | cv2.CALIB_CB_FAST_CHECK)
#: Images larger than this are searched for the board at a reduced size (as ROS
#: ``camera_calibration`` does); the corners are then refined at full size. A board cut
#: by the image edge costs the search seconds at 1280x720 and a fraction of a second
#: at this size, px².
DETECTION_PIXELS = 640 * 480
#: ``cornerSubPix`` termination: 100 iterations or a step below 1e-4 px.
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-4)


def object_points(pattern_size, square_m):
    """Inner corners in the board frame (N, 3), m: (i·square, j·square, 0), i fastest
    (OpenCV's corner order, ``pattern_size`` = (corners per row, corners per column)).
    """
    cols, rows = pattern_size
    i, j = np.meshgrid(np.arange(cols), np.arange(rows))
    return (np.column_stack([i.ravel(), j.ravel(), np.zeros(i.size)])
            * float(square_m)).astype(np.float32)


def subpix_window(corners, pattern_size):
    """Half-size of the ``cornerSubPix`` window, px: 0.4 of the smallest distance
    between neighbouring corners (the window must not reach the next corner), in 3…15.
    """
    cols, rows = pattern_size
    grid = corners.reshape(rows, cols, 2)
    along = np.linalg.norm(np.diff(grid, axis=1), axis=2).min()
    down = np.linalg.norm(np.diff(grid, axis=0), axis=2).min()
    return int(np.clip(np.floor(0.4 * min(along, down)), 3, 15))


def find_corners(gray, pattern_size):
    """Sub-pixel inner corners (N, 2) float32 of a board in ``gray``, or None.

    Parameters
    ----------
    gray : ndarray (H, W) uint8
    pattern_size : (int, int)
        Inner corners per row and per column; they must differ, so that the board's
        orientation is unambiguous.

    The board is searched at most :data:`DETECTION_PIXELS` large and refined by
    ``cornerSubPix`` at full size. The corners come row by row; the first is the one
    nearer the top of the image (OpenCV may start from either end of the board).
    """
    h, w = gray.shape
    scale = max(1.0, np.sqrt(h * w / DETECTION_PIXELS))
    small = gray if scale == 1.0 else cv2.resize(
        gray, (int(round(w / scale)), int(round(h / scale))), interpolation=cv2.INTER_AREA)
    for flags in FIND_FLAGS:
        ok, corners = cv2.findChessboardCorners(small, tuple(pattern_size), flags=flags)
        if ok:
            break
    else:
        return None
    if small is not gray:        # pixel centres: u_full + ½ = (u_small + ½)·(w / w_small)
        factor = np.array([w / small.shape[1], h / small.shape[0]], dtype=np.float32)
        corners = ((corners + 0.5) * factor - 0.5).astype(np.float32)
    half = subpix_window(corners.reshape(-1, 2), pattern_size)
    corners = cv2.cornerSubPix(gray, corners, (half, half), (-1, -1), SUBPIX_CRITERIA)
    corners = corners.reshape(-1, 2)
    first_to_last = corners[-1] - corners[0]
    if first_to_last[1] < 0 or (first_to_last[1] == 0 and first_to_last[0] < 0):
        corners = corners[::-1].copy()
    return corners


def same_order(left, right):
    """``right`` in the corner order of ``left``: reversed when their first-to-last
    directions point apart (a board seen nearly diagonal, where the top-first rule of
    :func:`find_corners` may decide differently in the two images).
    """
    if np.dot(left[-1] - left[0], right[-1] - right[0]) < 0:
        return right[::-1].copy()
    return right
