"""Checkerboard calibration images rendered through a calibrated camera (ROS-free).

Ground truth for the stereo calibration of ``vlc_calibration``: a plane checkerboard at
a known pose, imaged into the raw (distorted) images of a :class:`CameraModel` or of
both cameras of a :class:`StereoCameraModel`, whose lens distortion is therefore known.

Usage::

    from vlc_stereo_camera.core.checkerboard import (Checkerboard, StereoBoardRenderer,
                                                     calibration_poses)
    renderer = StereoBoardRenderer(stereo_model, Checkerboard((9, 6), 0.05))
    rng = np.random.default_rng(1)
    for R_lb, t_lb in calibration_poses(renderer, 12, rng):
        left, right = renderer.render(R_lb, t_lb, rng)        # (H, W) uint8 each
        uv_left, uv_right = renderer.corners(R_lb, t_lb)      # true inner corners, px

Rendering, per camera: the corners of every raw pixel, (u ± ½, v ± ½), are undistorted
once (:meth:`CameraModel.undistort_normalized`) to rays (x, y, 1). For a board pose the
board coordinates of a ray are a homography of (x, y) (ray–plane intersection), so they
are exact at the pixel corners. A pixel whose four corners lie in one square (or all on
the margin or the background) is uniform. The others — the pixels an edge crosses —
are supersampled: the board coordinates of ``supersample``² sub-pixel centres are
interpolated bilinearly from the pixel's corners (the lens and the perspective are
smooth at the scale of a pixel) and the pixel takes the mean brightness: a box-filtered,
anti-aliased image. Only the pixels inside the bounding box of the board's projected
outline are computed; the rest is background. Then a Gaussian PSF (``blur_sigma_px``),
Gaussian noise (``noise_dn``) and rounding to 8 bits.
"""
from dataclasses import dataclass

import cv2
import numpy as np

from vlc_common.core.rotations import rot_x, rot_y, rot_z


@dataclass
class Checkerboard:
    """A plane checkerboard.

    Parameters
    ----------
    inner_corners : (int, int)
        Inner corners per row and per column (OpenCV's ``patternSize``: columns, rows);
        the board has one square more each way.
    square_m : float
        Side of a square, m.
    margin_squares : int
        Width of the white border around the squares (OpenCV's detector needs a light
        quiet zone around the board), in squares.

    Board frame: origin at the outer top-left corner of the squares, x along a row of
    squares, y down the columns, z into the board; the top-left square is black.
    """

    inner_corners: tuple = (9, 6)
    square_m: float = 0.05
    margin_squares: int = 1

    def __post_init__(self):
        cols, rows = (int(n) for n in self.inner_corners)
        if cols < 2 or rows < 2 or not self.square_m > 0 or self.margin_squares < 1:
            raise ValueError('a checkerboard needs ≥ 2×2 inner corners, square_m > 0 and a '
                             'margin of ≥ 1 square')
        self.inner_corners = (cols, rows)

    def object_points(self):
        """Inner corners in the board frame (N, 3), m, row by row (x fastest)."""
        cols, rows = self.inner_corners
        i, j = np.meshgrid(np.arange(1, cols + 1), np.arange(1, rows + 1))
        return np.column_stack([i.ravel(), j.ravel(), np.zeros(i.size)]) * self.square_m

    @property
    def centre_m(self):
        """Centre of the squares in the board frame (3,), m."""
        cols, rows = self.inner_corners
        return np.array([(cols + 1) / 2.0, (rows + 1) / 2.0, 0.0]) * self.square_m

    def outline(self, border_squares=0.25, points_per_side=16):
        """Points (4·n, 3) on a rectangle ``border_squares`` outside the squares, m.

        With the default half square, the quiet zone a detector needs around the board.
        """
        cols, rows = self.inner_corners
        lo = -border_squares * self.square_m
        hi_x = (cols + 1 + border_squares) * self.square_m
        hi_y = (rows + 1 + border_squares) * self.square_m
        t = np.linspace(0.0, 1.0, points_per_side, endpoint=False)
        x, y = lo + t * (hi_x - lo), lo + t * (hi_y - lo)
        xy = np.concatenate([np.column_stack([x, np.full_like(x, lo)]),
                             np.column_stack([np.full_like(y, hi_x), y]),
                             np.column_stack([hi_x + lo - x, np.full_like(x, hi_y)]),
                             np.column_stack([np.full_like(y, lo), hi_y + lo - y])])
        return np.column_stack([xy, np.zeros(len(xy))])

    def cell_label(self, s, q):
        """An integer per point (arrays of one shape, board coordinates in m), equal for
        points of one uniform region: a square, one cell of the margin, or the
        background (everything beyond the margin); −1 where ``s`` or ``q`` is NaN.
        """
        cols, rows = self.inner_corners
        m = self.margin_squares
        i = np.clip(np.floor(s / self.square_m), -m - 1, cols + m + 1) + (m + 1)
        j = np.clip(np.floor(q / self.square_m), -m - 1, rows + m + 1) + (m + 1)
        label = i * (rows + 2 * m + 3) + j
        return np.where(np.isfinite(label), label, -1).astype(np.int32)

    def label_brightness(self, black, white, background):
        """Brightness of every :meth:`cell_label` value, indexable by label (the last
        entry, index −1, is the background of rays that miss the board).
        """
        cols, rows = self.inner_corners
        m = self.margin_squares
        i, j = np.meshgrid(np.arange(-m - 1, cols + m + 2), np.arange(-m - 1, rows + m + 2),
                           indexing='ij')
        on_board = (i >= -m) & (i <= cols + m) & (j >= -m) & (j <= rows + m)
        in_squares = (i >= 0) & (i <= cols) & (j >= 0) & (j <= rows)
        dark = in_squares & ((i + j) % 2 == 0)
        table = np.where(on_board, np.where(dark, black, white), background).ravel()
        return np.append(table, background).astype(np.float32)


@dataclass
class BoardImageConfig:
    """Photometry of the rendered board, DN of an 8-bit image.

    ``supersample``: sub-pixels per side of an edge pixel; ``blur_sigma_px``: Gaussian
    PSF, px (0 = none); ``noise_dn``: Gaussian noise, 1σ DN.
    """

    black_dn: float = 35.0
    white_dn: float = 205.0
    background_dn: float = 90.0
    supersample: int = 8
    blur_sigma_px: float = 0.6
    noise_dn: float = 2.0


def board_pose(centre_cam_m, board, roll_deg=0.0, tilt_x_deg=0.0, tilt_y_deg=0.0):
    """(R_cam_board, t_cam_board) of a board facing the camera with its centre at
    ``centre_cam_m`` (optical frame, m), turned by ``roll_deg`` about the optical axis
    and tilted by ``tilt_x_deg``, ``tilt_y_deg`` about its own x and y axes.

    x_cam = R_cam_board · x_board + t_cam_board.
    """
    R = rot_z(np.radians(roll_deg)) @ rot_x(np.radians(tilt_x_deg)) @ rot_y(
        np.radians(tilt_y_deg))
    t = np.asarray(centre_cam_m, dtype=float) - R @ board.centre_m
    return R, t


class BoardRenderer:
    """Renders a :class:`Checkerboard` into the raw image of one :class:`CameraModel`."""

    def __init__(self, camera, board, config=None):
        self.camera = camera
        self.board = board
        self.config = config or BoardImageConfig()
        w, h = camera.width, camera.height
        u, v = np.meshgrid(np.arange(w + 1) - 0.5, np.arange(h + 1) - 0.5)
        rays = camera.undistort_normalized(np.column_stack([u.ravel(), v.ravel()]))
        self._rays = rays.reshape(h + 1, w + 1, 2)
        self._ray_radius = float(np.hypot(rays[:, 0], rays[:, 1]).max())

    def _board_coords(self, xy, R, t):
        """Board coordinates (s, q) (m) of normalized rays ``xy`` (..., 2)."""
        e1, e2, n = R[:, 0], R[:, 1], R[:, 2]
        x, y = xy[..., 0], xy[..., 1]
        a = e1[0] * x + e1[1] * y + e1[2]
        b = e2[0] * x + e2[1] * y + e2[2]
        c = n[0] * x + n[1] * y + n[2]
        nt = float(n @ t)
        with np.errstate(divide='ignore', invalid='ignore'):
            lam = nt / c                                  # ray length to the plane
            s = np.where(lam > 0, lam * a - e1 @ t, np.nan)
            q = np.where(lam > 0, lam * b - e2 @ t, np.nan)
        return s, q

    def _board_box(self, R, t):
        """(row0, row1, col0, col1): the pixels the board (margin included) can touch,
        from its projected outline plus a few pixels; the whole image when part of the
        outline is behind the camera or outside the lens's field of view (where the
        distortion polynomial is no longer monotonic and projections are not to be
        trusted).
        """
        h, w = self.camera.height, self.camera.width
        whole = (0, h, 0, w)
        p = self.board.outline(self.board.margin_squares, 32) @ R.T + t
        if np.any(p[:, 2] <= 0):
            return whole
        if np.any(np.hypot(p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]) > self._ray_radius):
            return whole
        uv, _ = self.camera.project(p)
        pad = 4
        c0, r0 = np.floor(uv.min(axis=0)).astype(int) - pad
        c1, r1 = np.ceil(uv.max(axis=0)).astype(int) + pad
        return max(r0, 0), min(r1, h), max(c0, 0), min(c1, w)

    def render(self, R_cam_board, t_cam_board, rng):
        """The raw image (H, W) uint8 of the board at this pose (x_cam = R·x_board + t)."""
        cfg, board = self.config, self.board
        R = np.asarray(R_cam_board, dtype=float)
        t = np.asarray(t_cam_board, dtype=float)
        table = board.label_brightness(cfg.black_dn, cfg.white_dn, cfg.background_dn)
        image = np.full((self.camera.height, self.camera.width), cfg.background_dn,
                        dtype=np.float32)
        r0, r1, c0, c1 = self._board_box(R, t)
        if r1 > r0 and c1 > c0:
            image[r0:r1, c0:c1] = self._render_box(self._rays[r0:r1 + 1, c0:c1 + 1], R, t,
                                                   table)
        if cfg.blur_sigma_px > 0:
            image = cv2.GaussianBlur(image, (0, 0), cfg.blur_sigma_px)
        if cfg.noise_dn > 0:
            image += cfg.noise_dn * rng.standard_normal(image.shape, dtype=np.float32)
        return np.clip(np.rint(image), 0, 255).astype(np.uint8)

    def _render_box(self, rays, R, t, table):
        """Mean brightness (h, w) of the pixels whose corner rays are ``rays``
        (h + 1, w + 1, 2).
        """
        board = self.board
        s, q = self._board_coords(rays, R, t)
        label = board.cell_label(s, q)
        top_left = label[:-1, :-1]
        uniform = ((top_left == label[:-1, 1:]) & (top_left == label[1:, :-1])
                   & (top_left == label[1:, 1:]))
        image = table[top_left]
        rows, cols = np.nonzero(~uniform)
        if rows.size:
            n = int(self.config.supersample)
            f = ((np.arange(n) + 0.5) / n).astype(np.float32)
            fu, fv = (g.ravel()[None, :] for g in np.meshgrid(f, f))  # sub-pixel offsets
            sub = []
            for grid in (s, q):
                c00, c01 = grid[rows, cols], grid[rows, cols + 1]
                c10, c11 = grid[rows + 1, cols], grid[rows + 1, cols + 1]
                # bilinear in the pixel: c00 + Δu·fu + Δv·fv + Δuv·fu·fv
                sub.append(c00[:, None] + (c01 - c00)[:, None] * fu
                           + (c10 - c00)[:, None] * fv
                           + (c11 - c10 - c01 + c00)[:, None] * (fu * fv))
            image[rows, cols] = table[board.cell_label(*sub)].mean(axis=1)
        return image

    def corners(self, R_cam_board, t_cam_board):
        """True raw pixels (N, 2) of the inner corners, in :meth:`Checkerboard.object_points`
        order.
        """
        p = self.board.object_points() @ np.asarray(R_cam_board).T + t_cam_board
        return self.camera.project(p)[0]

    def visible(self, R_cam_board, t_cam_board, margin_px=2.0):
        """True when the squares and half a square of white around them are in the
        image, ``margin_px`` inside its edges (what the detector needs).
        """
        p = self.board.outline() @ np.asarray(R_cam_board).T + t_cam_board
        if np.any(p[:, 2] <= 0):
            return False
        uv, _ = self.camera.project(p)
        size = np.array([self.camera.width, self.camera.height])
        return bool(np.all((uv >= margin_px - 0.5) & (uv <= size - 0.5 - margin_px)))


class StereoBoardRenderer:
    """Renders a board pose given in the left optical frame into both cameras of a
    :class:`StereoCameraModel` (the right pose from the pair's extrinsics).
    """

    def __init__(self, stereo, board, config=None):
        self.stereo = stereo
        self.board = board
        self.left = BoardRenderer(stereo.left, board, config)
        self.right = BoardRenderer(stereo.right, board, config)
        self._R, self._T = stereo.extrinsics()

    def right_pose(self, R_left_board, t_left_board):
        """The board pose in the right optical frame."""
        return self._R @ R_left_board, self._R @ t_left_board + self._T

    def render(self, R_left_board, t_left_board, rng):
        """(left, right) raw images, (H, W) uint8 each."""
        return (self.left.render(R_left_board, t_left_board, rng),
                self.right.render(*self.right_pose(R_left_board, t_left_board), rng))

    def corners(self, R_left_board, t_left_board):
        """(left, right) true raw pixels (N, 2) of the inner corners."""
        return (self.left.corners(R_left_board, t_left_board),
                self.right.corners(*self.right_pose(R_left_board, t_left_board)))

    def visible(self, R_left_board, t_left_board, margin_px=2.0):
        """(left, right): whether each camera sees the board (:meth:`BoardRenderer.visible`)."""
        return (self.left.visible(R_left_board, t_left_board, margin_px),
                self.right.visible(*self.right_pose(R_left_board, t_left_board), margin_px))


def calibration_poses(renderer, count, rng, distance_m=(0.6, 1.1), max_tilt_deg=40.0,
                      max_roll_deg=15.0, in_both=True, draws=6):
    """``count`` board poses (R_left_board, t_left_board) spread over the image, as a
    careful calibration takes them.

    The board is pushed in turn into the four corners, to the four edges and into the
    centre of the image (where the distortion is largest, and where it is not). A pose
    is drawn as a distance in ``distance_m`` (m), a turn toward the camera plus up to
    ±25° of tilt about each board axis (within ``max_tilt_deg``) and a roll of up to
    ``max_roll_deg``; its centre is then slid from the image centre toward the target
    (bisection on the fraction of the way) as far as the board stays in view. Of
    ``draws`` such poses the one whose inner corners come nearest the target is kept.

    ``renderer`` is a :class:`BoardRenderer` or a :class:`StereoBoardRenderer`. For a
    stereo pair with ``in_both`` every pose is in view of both cameras (targets in the
    left image); without, the targets alternate between the left and the right image
    and each pose need be in view of its own camera only, so that each camera's image
    is covered to its edges, as the single-camera views of a real calibration do.
    """
    stereo = hasattr(renderer, 'left')
    targets = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0), (0.5, 0.5),
               (0.5, 0.0), (0.5, 1.0), (0.0, 0.5), (1.0, 0.5)]
    alternate = stereo and not in_both
    poses = []
    for k in range(count):
        side = k % 2 if alternate else 0
        target = np.array(targets[(k // 2 if alternate else k) % len(targets)])
        best, best_gap = None, np.inf
        for _ in range(draws):
            draw = _PoseDraw(rng.uniform(*distance_m), rng.normal(0.0, 0.01, 2),
                             rng.choice([-1.0, 1.0], 2) * rng.uniform(10.0, 35.0, 2),
                             rng.uniform(-max_roll_deg, max_roll_deg), max_tilt_deg)
            if not _in_view(renderer, _aimed_pose(renderer, side, target, 0.0, draw), side,
                            in_both):
                continue
            lo, hi = 0.0, 1.0                                  # in view at lo, not at hi
            if _in_view(renderer, _aimed_pose(renderer, side, target, hi, draw), side,
                        in_both):
                lo = hi
            for _ in range(12 if lo < hi else 0):
                mid = 0.5 * (lo + hi)
                if _in_view(renderer, _aimed_pose(renderer, side, target, mid, draw), side,
                            in_both):
                    lo = mid
                else:
                    hi = mid
            pose = _aimed_pose(renderer, side, target, lo, draw)
            corners = renderer.corners(*pose)[side] if stereo else renderer.corners(*pose)
            view = _view(renderer, side)
            size = np.array([view.camera.width - 1, view.camera.height - 1], dtype=float)
            gap = np.linalg.norm(corners - target * size, axis=1).min()
            if gap < best_gap:
                best, best_gap = pose, gap
        if best is None:
            raise ValueError(f'no board pose in view found for the image position '
                             f'{tuple(target)} in {draws} draws; use a smaller board or a '
                             'larger distance')
        poses.append(best)
    return poses


@dataclass
class _PoseDraw:
    """The random part of a pose: distance (m), aim jitter (fraction of the image),
    tilts about the board's x and y beyond facing the camera (deg), roll (deg).
    """

    distance_m: float
    jitter: np.ndarray
    tilt_deg: np.ndarray
    roll_deg: float
    max_tilt_deg: float


def _view(renderer, side):
    return (renderer.left, renderer.right)[side] if hasattr(renderer, 'left') else renderer


def _aimed_pose(renderer, side, target, fraction, draw):
    """The pose of ``draw`` with its centre ``fraction`` of the way from the image centre
    to ``target`` (fractions of the image of camera ``side``), in the left frame.
    """
    camera = _view(renderer, side).camera
    size = np.array([camera.width, camera.height], dtype=float)
    aim = 0.5 + (target - 0.5) * fraction + draw.jitter
    ray = np.append(camera.undistort_normalized(aim * size)[0], 1.0)
    tilt_x = np.clip(-np.degrees(np.arctan(ray[1])) + draw.tilt_deg[0], -draw.max_tilt_deg,
                     draw.max_tilt_deg)
    tilt_y = np.clip(np.degrees(np.arctan(ray[0])) + draw.tilt_deg[1], -draw.max_tilt_deg,
                     draw.max_tilt_deg)
    R, t = board_pose(ray / np.linalg.norm(ray) * draw.distance_m, renderer.board,
                      draw.roll_deg, tilt_x, tilt_y)
    if side == 1:                              # aimed in the right camera: to the left frame
        R_rl, T_rl = renderer.stereo.extrinsics()
        R, t = R_rl.T @ R, R_rl.T @ (t - T_rl)
    return R, t


def _in_view(renderer, pose, side, in_both):
    if not hasattr(renderer, 'left'):
        return renderer.visible(*pose)
    seen = renderer.visible(*pose)
    return all(seen) if in_both else seen[side]
