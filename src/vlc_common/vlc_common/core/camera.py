"""Pinhole stereo camera model of the rig: intrinsics, mounting, projection.

Frames: ``base_link`` (x forward, y left, z up) and the optical frames (z forward,
x right, y down). The left camera's optical centre is at ``mount_xyz_m`` in
``base_link``; the right camera sits ``baseline_m`` further along the left optical x
axis with the same orientation (rectified stereo, parallel axes).

Mounting: the optical axis is turned from the left-wall normal (+y of ``base_link``)
toward the running direction (+x) by the placement angle (paper eq. 16, 49°) and tilted
down by ``pitch_deg``.
"""
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np


@dataclass
class CameraIntrinsics:
    """Paper camera: f = 3.9 mm, 3.75 µm pixels → 1040 px; 1280×720; no distortion."""

    width: int = 1280
    height: int = 720
    fx: float = 1040.0
    fy: float = 1040.0
    cx: float = 639.5
    cy: float = 359.5

    def __post_init__(self):
        if self.width <= 0 or self.height <= 0 or self.fx <= 0 or self.fy <= 0:
            raise ValueError('camera width, height, fx and fy must be positive')

    @property
    def K(self):
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def fov_deg(self):
        """(horizontal, vertical) full field of view in degrees."""
        return (np.degrees(2 * np.arctan(self.width / (2 * self.fx))),
                np.degrees(2 * np.arctan(self.height / (2 * self.fy))))


def mount_rotation(placement_angle_deg, pitch_deg, roll_deg=0.0):
    """R_base_cam (3, 3): columns are the optical x, y, z axes expressed in base_link.

    ``roll_deg`` turns the camera about its optical axis z (+ turns image right, x,
    toward image down, y): a bracket that is not square to the car body; 0 by design.
    """
    a, p = np.radians(placement_angle_deg), np.radians(pitch_deg)
    z0 = np.array([np.sin(a), np.cos(a), 0.0])    # toward the wall, turned forward
    x0 = np.array([np.cos(a), -np.sin(a), 0.0])   # image right
    y0 = np.array([0.0, 0.0, -1.0])               # image down
    z = np.cos(p) * z0 + np.sin(p) * y0           # tilted down by the pitch
    y = np.cos(p) * y0 - np.sin(p) * z0
    if roll_deg:
        r = np.radians(roll_deg)
        x0, y = np.cos(r) * x0 + np.sin(r) * y, np.cos(r) * y - np.sin(r) * x0
    return np.column_stack([x0, y, z])


def mount_angles(R_base_cam):
    """(placement_angle_deg, pitch_deg, roll_deg) of a rotation: the inverse of
    :func:`mount_rotation` (pitch within ±90°).
    """
    R = np.asarray(R_base_cam, dtype=float).reshape(3, 3)
    z = R[:, 2]
    a = float(np.degrees(np.arctan2(z[0], z[1])))
    p = float(np.degrees(np.arcsin(np.clip(-z[2], -1.0, 1.0))))
    # the roll turns the unrolled mount's image axes about the optical axis
    unrolled = mount_rotation(a, p)
    r = float(np.degrees(np.arctan2(R[:, 0] @ unrolled[:, 1], R[:, 0] @ unrolled[:, 0])))
    return a, p, r


@dataclass
class StereoRig:
    """Rectified stereo pair rigidly mounted on ``base_link``."""

    intrinsics: CameraIntrinsics = None
    baseline_m: float = 0.12
    mount_xyz_m: tuple = (0.0, 0.8, 2.9)
    placement_angle_deg: float = 49.0
    pitch_deg: float = 27.0
    roll_deg: float = 0.0

    def __post_init__(self):
        if self.intrinsics is None:
            self.intrinsics = CameraIntrinsics()
        if not self.baseline_m > 0.0:
            raise ValueError('baseline_m must be > 0')
        self.R_base_cam = mount_rotation(self.placement_angle_deg, self.pitch_deg,
                                         self.roll_deg)
        left = np.asarray(self.mount_xyz_m, dtype=float)
        self.t_base_cams = np.stack([left, left + self.baseline_m * self.R_base_cam[:, 0]])

    def cam_positions_base(self):
        """(2, 3) optical centres of the left and right cameras in ``base_link`` (m)."""
        return self.t_base_cams.copy()

    def to_camera(self, points_map, base_pos_map, R_map_base, camera=0):
        """Points in ``map`` (N, 3) → camera ``camera`` (0 left, 1 right) optical frame.

        ``base_pos_map`` (3,) or (N, 3) and ``R_map_base`` (3, 3) or (N, 3, 3) may be
        given per point (rolling shutter: each point seen at its own instant).
        """
        p = np.asarray(points_map, dtype=float).reshape(-1, 3)
        base = np.broadcast_to(np.asarray(base_pos_map, dtype=float), p.shape)
        R = np.broadcast_to(np.asarray(R_map_base, dtype=float), (p.shape[0], 3, 3))
        p_base = np.einsum('nji,nj->ni', R, p - base)          # R^T (p - base)
        return (p_base - self.t_base_cams[camera]) @ self.R_base_cam

    def project_camera(self, p_cam):
        """Optical-frame points (N, 3) → pixel (N, 2) (u right, v down) and depth (N,)."""
        k = self.intrinsics
        z = p_cam[:, 2]
        with np.errstate(divide='ignore', invalid='ignore'):
            uv = np.stack([k.fx * p_cam[:, 0] / z + k.cx, k.fy * p_cam[:, 1] / z + k.cy], 1)
        return uv, z

    def project(self, points_map, base_pos_map, R_map_base):
        """Project map points into both cameras.

        Returns ``uv_left`` (N, 2), ``uv_right`` (N, 2) in pixels and ``depth_left`` (N,)
        in metres (the optical z of the left camera; equal for both in rectified stereo).
        """
        uv_l, z_l = self.project_camera(self.to_camera(points_map, base_pos_map, R_map_base, 0))
        uv_r, _ = self.project_camera(self.to_camera(points_map, base_pos_map, R_map_base, 1))
        return uv_l, uv_r, z_l

    def camera_info_dicts(self):
        """CameraInfo contents (K, R, P, D, size) for the left and right cameras.

        Rectified pair: R = I, right ``P[0,3] = −fx·baseline`` (image_geometry layout).
        """
        k = self.intrinsics
        infos = []
        for cam in (0, 1):
            P = np.zeros((3, 4))
            P[:, :3] = k.K
            P[0, 3] = -k.fx * self.baseline_m * cam
            infos.append({'width': k.width, 'height': k.height, 'K': k.K, 'D': np.zeros(5),
                          'R': np.eye(3), 'P': P, 'distortion_model': 'plumb_bob'})
        return infos


# --------------------------------------------------------------------------------------
# Calibrated cameras: lens distortion, rectification and projection as CameraInfo has them
# --------------------------------------------------------------------------------------

#: Distortion models of sensor_msgs/CameraInfo handled here and their coefficient count,
#: in OpenCV's order: plumb_bob [k1, k2, p1, p2, k3], rational_polynomial
#: [k1, k2, p1, p2, k3, k4, k5, k6] (REP-104; OpenCV "Camera Calibration and 3D
#: Reconstruction", the distortion equations).
DISTORTION_MODELS = {'plumb_bob': 5, 'rational_polynomial': 8}

#: Most fixed-point iterations of the undistortion of one point. OpenCV's default is 5,
#: which leaves a few tenths of a pixel at the corners of a 3.9 mm M12 lens (k1 ≈ −0.3);
#: the iteration stops earlier once a point is converged (:data:`UNDISTORT_EPS_PX`).
UNDISTORT_MAX_ITERATIONS = 100
#: Stop a point's undistortion once re-distorting it lands within this distance of the
#: raw pixel, px.
UNDISTORT_EPS_PX = 1e-6

#: Tolerances of the consistency checks of a model: R orthonormal, a rectified pair's
#: common fx, fy, cy (relative).
_ROTATION_TOL = 1e-4
_RECTIFIED_PAIR_RTOL = 1e-6


class CameraModelError(ValueError):
    """A CameraInfo field that does not describe a usable camera.

    ``field`` names the CameraInfo field (``width``, ``height``, ``K``, ``D``, ``R``,
    ``P``, ``distortion_model``), so that the file readers can name the field of their
    own format.
    """

    def __init__(self, field, problem):
        self.field = field
        self.problem = problem
        super().__init__(f'{field}: {problem}')


def distortion_model_of(D):
    """(distortion_model, D) for OpenCV coefficients: 4 or 5 → ``plumb_bob`` (a missing k3
    is 0), 8 → ``rational_polynomial``; other counts raise :class:`CameraModelError`.
    """
    d = np.asarray(D, dtype=float).ravel()
    if d.size in (4, 5):
        return 'plumb_bob', np.concatenate([d, np.zeros(5 - d.size)])
    if d.size == 8:
        return 'rational_polynomial', d
    raise CameraModelError('D', f'{d.size} distortion coefficients: expected 4 or 5 '
                                '(plumb_bob) or 8 (rational_polynomial)')


def _cv2():
    # cv2 is imported on first use: the pinhole rig above, imported by nodes that never
    # undistort (IMU compensator, localizer), should not pay for loading OpenCV.
    import cv2
    return cv2


def _field_array(value, field, shape):
    """``value`` as a float array of ``shape`` (flat row-major lists accepted)."""
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise CameraModelError(field, f'not a numeric matrix ({exc})') from None
    size = int(np.prod(shape))
    if a.size != size:
        raise CameraModelError(field, f'expected {"x".join(map(str, shape))} '
                                      f'({size} values), got {a.size} values')
    a = a.reshape(shape)
    if not np.all(np.isfinite(a)):
        raise CameraModelError(field, f'non-finite value {a[~np.isfinite(a)][0]}')
    return a


@dataclass
class CameraModel:
    """One calibrated camera as sensor_msgs/CameraInfo describes it (REP-104).

    The same geometry as ROS ``image_geometry.PinholeCameraModel``: the raw (distorted)
    image is related to the camera's optical frame (z forward, x right, y down) by K
    and D; the rectified image by the rectification rotation R (unrectified optical
    frame → rectified frame) and the projection P.

    Parameters
    ----------
    width, height : int
        Image size the calibration belongs to, px.
    K : array_like (3, 3) or (9,)
        Intrinsic matrix of the raw image, px.
    D : array_like (5,) or (8,), optional
        Distortion coefficients in OpenCV order (dimensionless); default: none.
    R : array_like (3, 3) or (9,), optional
        Rectification rotation; default identity.
    P : array_like (3, 4) or (12,), optional
        Projection of the rectified image, px (P[0,3] = −fx'·baseline on the right camera
        of a stereo pair, m·px); default ``[K | 0]``.
    distortion_model : str
        A key of :data:`DISTORTION_MODELS`.

    Raises
    ------
    CameraModelError
        A field of the wrong shape, a non-finite value, a non-positive size or focal
        length, an unknown distortion model, K or P not of pinhole form, R not a rotation.
    """

    width: int
    height: int
    K: np.ndarray
    D: np.ndarray = None
    R: np.ndarray = None
    P: np.ndarray = None
    distortion_model: str = 'plumb_bob'

    def __post_init__(self):
        for name in ('width', 'height'):
            value = getattr(self, name)
            try:
                ok = not isinstance(value, bool) and float(value).is_integer() and value > 0
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise CameraModelError(name, f'{value!r} is not a positive integer')
            setattr(self, name, int(value))
        if self.distortion_model not in DISTORTION_MODELS:
            raise CameraModelError('distortion_model', f'{self.distortion_model!r} is not '
                                   f'supported (expected {", ".join(DISTORTION_MODELS)})')
        self.K = _field_array(self.K, 'K', (3, 3))
        n = DISTORTION_MODELS[self.distortion_model]
        if self.D is None or np.size(self.D) == 0:
            self.D = np.zeros(n)           # an empty D means no distortion (image_geometry)
        self.D = _field_array(self.D, 'D', (n,))
        self.R = np.eye(3) if self.R is None else _field_array(self.R, 'R', (3, 3))
        if self.P is None:
            self.P = np.column_stack([self.K, np.zeros(3)])
        self.P = _field_array(self.P, 'P', (3, 4))
        for name, m in (('K', self.K), ('P', self.P)):
            if not (m[0, 0] > 0 and m[1, 1] > 0):
                raise CameraModelError(name, f'focal lengths fx = {m[0, 0]:g}, fy = '
                                             f'{m[1, 1]:g} px must be > 0')
            if m[1, 0] != 0 or np.any(m[2, :3] != (0.0, 0.0, 1.0)):
                raise CameraModelError(name, 'not a pinhole matrix (expected rows '
                                             '[fx s cx], [0 fy cy], [0 0 1])')
        err = np.abs(self.R.T @ self.R - np.eye(3)).max()
        if err > _ROTATION_TOL or np.linalg.det(self.R) < 0:
            raise CameraModelError('R', f'not a rotation (|RᵀR − I| = {err:.2g}, det '
                                        f'{np.linalg.det(self.R):.6g})')

    # ------------------------------------------------------------------ conversions
    @classmethod
    def from_intrinsics(cls, intrinsics, D=None, distortion_model='plumb_bob'):
        """The camera of :class:`CameraIntrinsics` with an optional distortion ``D``."""
        return cls(width=intrinsics.width, height=intrinsics.height, K=intrinsics.K, D=D,
                   distortion_model=distortion_model)

    @classmethod
    def from_camera_info(cls, info):
        """From a CameraInfo-like mapping or a sensor_msgs/CameraInfo message.

        A mapping may use the keys of :meth:`to_camera_info` (``K``, ``D``, ``R``, ``P``)
        or the message's lower-case field names (``k``, ``d``, ``r``, ``p``); a message
        (any object with those attributes) is read by attribute. Matrices flat (row-major,
        as in the message) or shaped; an empty ``distortion_model`` is plumb_bob.
        ``binning`` and ``roi`` are not modelled.
        """
        def get(name):
            for key in (name, name.lower()):
                if isinstance(info, Mapping):
                    if key in info:
                        return info[key]
                elif hasattr(info, key):
                    return getattr(info, key)
            raise CameraModelError(name, 'missing')
        try:
            model = get('distortion_model')
        except CameraModelError:
            model = ''
        return cls(width=get('width'), height=get('height'), K=get('K'), D=get('D'),
                   R=get('R'), P=get('P'), distortion_model=model or 'plumb_bob')

    def to_camera_info(self):
        """CameraInfo contents: ``width``, ``height``, ``distortion_model``, ``D`` (n,),
        ``K`` (3, 3), ``R`` (3, 3), ``P`` (3, 4), as :meth:`StereoRig.camera_info_dicts`.
        """
        return {'width': self.width, 'height': self.height, 'K': self.K.copy(),
                'D': self.D.copy(), 'R': self.R.copy(), 'P': self.P.copy(),
                'distortion_model': self.distortion_model}

    # ------------------------------------------------------------------ properties
    @property
    def fx(self):
        """Rectified focal length P[0,0], px (image_geometry's ``fx()``)."""
        return float(self.P[0, 0])

    @property
    def fy(self):
        """Rectified focal length P[1,1], px."""
        return float(self.P[1, 1])

    @property
    def cx(self):
        """Rectified principal point P[0,2], px."""
        return float(self.P[0, 2])

    @property
    def cy(self):
        """Rectified principal point P[1,2], px."""
        return float(self.P[1, 2])

    @property
    def is_ideal(self):
        """True when rectification is the identity: no distortion, R = I, P[:, :3] = K."""
        return bool(not np.any(self.D) and np.array_equal(self.R, np.eye(3))
                    and np.array_equal(self.P[:, :3], self.K))

    # ------------------------------------------------------------------ raw image
    def distort_normalized(self, xy):
        """Ideal normalized coordinates (N, 2) → distorted normalized coordinates (N, 2).

        OpenCV's model (``projectPoints``): r² = x² + y²,
        x_d = x·(1 + k1 r² + k2 r⁴ + k3 r⁶)/(1 + k4 r² + k5 r⁴ + k6 r⁶)
        + 2 p1 x y + p2 (r² + 2x²), y_d likewise with p1 (r² + 2y²) + 2 p2 x y.
        """
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        x, y = xy[:, 0], xy[:, 1]
        k = np.zeros(8)
        k[:self.D.size] = self.D
        k1, k2, p1, p2, k3, k4, k5, k6 = k
        r2 = x * x + y * y
        radial = ((1.0 + r2 * (k1 + r2 * (k2 + r2 * k3)))
                  / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return np.stack([xd, yd], axis=1)

    def _normalized_to_raw(self, xy):
        d = self.distort_normalized(xy)
        K = self.K
        return np.stack([K[0, 0] * d[:, 0] + K[0, 1] * d[:, 1] + K[0, 2],
                         K[1, 1] * d[:, 1] + K[1, 2]], axis=1)

    def project(self, points_cam):
        """Optical-frame points (N, 3) → raw (distorted) pixels (N, 2) and depth (N,).

        Points in the camera's own (unrectified) optical frame, m; pixels u right,
        v down, the centre of the top-left pixel at (0, 0). Points with depth ≤ 0 get
        NaN pixels.
        """
        p = np.asarray(points_cam, dtype=float).reshape(-1, 3)
        z = p[:, 2]
        with np.errstate(divide='ignore', invalid='ignore'):
            xy = p[:, :2] / np.where(z > 0, z, np.nan)[:, None]
        return self._normalized_to_raw(xy), z

    def undistort_normalized(self, uv_raw):
        """Raw pixels (N, 2) → ideal normalized coordinates (N, 2) before R.

        ``cv2.undistortPoints`` iterated to :data:`UNDISTORT_EPS_PX`.
        """
        return self._undistort(uv_raw, None, None)

    def _undistort(self, uv, R, P):
        cv2 = _cv2()
        src = np.asarray(uv, dtype=np.float64).reshape(-1, 1, 2)
        if src.shape[0] == 0:
            return np.zeros((0, 2))
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS,
                    UNDISTORT_MAX_ITERATIONS, UNDISTORT_EPS_PX)
        iterative = getattr(cv2, 'undistortPointsIter', None)
        if iterative is not None:       # OpenCV 4: the criteria overload has its own name
            out = iterative(src, self.K, self.D, R, P, criteria)
        else:                            # OpenCV 5: undistortPoints takes the criteria
            out = cv2.undistortPoints(src, self.K, self.D, R=R, P=P, criteria=criteria)
        return out.reshape(-1, 2)

    # ------------------------------------------------------------------ rectified image
    def rectify_points(self, uv_raw):
        """Raw pixels (N, 2) → rectified pixels (N, 2).

        As ``image_geometry.PinholeCameraModel.rectifyPoint``:
        ``cv2.undistortPoints(src, K, D, R=R, P=P)`` (only P[:, :3] is used), with the
        iteration run to :data:`UNDISTORT_EPS_PX` instead of OpenCV's 5 steps.
        """
        uv = np.asarray(uv_raw, dtype=float).reshape(-1, 2)
        if self.is_ideal:
            return uv.copy()
        return self._undistort(uv, self.R, self.P)

    def rectified_rays(self, uv_rect):
        """Rectified pixels (N, 2) → rays (N, 3) with z = 1 in the rectified frame."""
        uv = np.asarray(uv_rect, dtype=float).reshape(-1, 2)
        rays = np.linalg.solve(self.P[:, :3], np.column_stack([uv, np.ones(len(uv))]).T).T
        return rays / rays[:, 2:3]

    def unrectify_points(self, uv_rect):
        """Rectified pixels (N, 2) → raw pixels (N, 2): the inverse of
        :meth:`rectify_points` (for renderers and overlays on the raw image).

        The ray through the rectified pixel (P[:, :3]⁻¹), turned back into the
        unrectified frame (Rᵀ), distorted and mapped by K.
        """
        uv = np.asarray(uv_rect, dtype=float).reshape(-1, 2)
        if self.is_ideal:
            return uv.copy()
        rays = self.rectified_rays(uv) @ self.R          # row-wise Rᵀ·ray
        return self.project(rays)[0]

    def project_rectified(self, points_rect):
        """Points (N, 3) in the rectified frame of the stereo reference camera → rectified
        pixels (N, 2) and depth (N,), through the full P (image_geometry's
        ``project3dToPixel``; on the right camera P[0,3] shifts by the baseline).
        """
        p = np.asarray(points_rect, dtype=float).reshape(-1, 3)
        h = np.column_stack([p, np.ones(len(p))]) @ self.P.T
        with np.errstate(divide='ignore', invalid='ignore'):
            return h[:, :2] / h[:, 2:3], p[:, 2]


@dataclass
class StereoCameraModel:
    """A calibrated, rectified stereo pair (image_geometry's ``StereoCameraModel``).

    The right camera's P[0,3] = −fx'·b carries the baseline b (m); both cameras' rectified
    frames share one orientation, the right one's origin b along the left's rectified x.

    Raises
    ------
    CameraModelError
        Image sizes that differ, P[:, :3] that differ other than in cx (not a rectified
        pair; a cx difference is a disparity offset, handled), a vertical
        offset P[1,3] ≠ 0 on the right camera, a left P[:, 3] ≠ 0, or a baseline ≤ 0.
    """

    left: CameraModel
    right: CameraModel

    def __post_init__(self):
        if (self.left.width, self.left.height) != (self.right.width, self.right.height):
            raise CameraModelError('width', f'left {self.left.width}x{self.left.height} and '
                                            f'right {self.right.width}x{self.right.height} '
                                            'image sizes differ')
        # cx may differ (stereoRectify without CALIB_ZERO_DISPARITY): a disparity offset
        same = np.ones((3, 3), dtype=bool)
        same[0, 2] = False
        if not np.allclose(self.left.P[:, :3][same], self.right.P[:, :3][same],
                           rtol=_RECTIFIED_PAIR_RTOL, atol=1e-9):
            raise CameraModelError('P', 'left and right P[:, :3] differ in fx, fy, skew or '
                                        'cy: not a rectified pair')
        if np.any(self.left.P[:, 3] != 0.0):
            raise CameraModelError('P', f'left P[:, 3] = {self.left.P[:, 3]} must be zero')
        if self.right.P[1, 3] != 0.0 or self.right.P[2, 3] != 0.0:
            raise CameraModelError('P', 'right P[1,3] and P[2,3] must be zero (a '
                                        'horizontal stereo pair)')
        if not self.baseline_m > 0.0:
            raise CameraModelError('P', f'right P[0,3] = {self.right.P[0, 3]:g} gives a '
                                        f'baseline of {self.baseline_m:g} m; must be > 0 '
                                        '(P[0,3] = −fx·baseline)')

    @property
    def baseline_m(self):
        """Baseline b = −P_right[0,3] / P_right[0,0], m."""
        return float(-self.right.P[0, 3] / self.right.P[0, 0]) + 0.0     # no -0.0

    @classmethod
    def from_rig(cls, rig, D_left=None, D_right=None):
        """The pair of a :class:`StereoRig` (its CameraInfo), optionally with distortion."""
        infos = rig.camera_info_dicts()
        for info, D in zip(infos, (D_left, D_right)):
            if D is not None:
                info['D'] = np.asarray(D, dtype=float)
        return cls(CameraModel.from_camera_info(infos[0]),
                   CameraModel.from_camera_info(infos[1]))

    @classmethod
    def from_stereo_extrinsics(cls, K1, D1, K2, D2, image_size, R, T, alpha=0.0):
        """Rectify a calibrated pair with ``cv2.stereoRectify`` (CALIB_ZERO_DISPARITY).

        Parameters
        ----------
        K1, D1, K2, D2 : array_like
            Raw intrinsics and distortion of the left and right camera (4, 5 or 8
            coefficients, see :func:`distortion_model_of`).
        image_size : (int, int)
            (width, height), px.
        R : array_like (3, 3)
            Rotation from the left to the right optical frame (x_r = R·x_l + T).
        T : array_like (3,)
            Translation of the same transform, m (≈ (−b, 0, 0)).
        alpha : float
            ``stereoRectify``'s free scaling: 0 keeps only valid pixels (the ROS
            ``camera_calibration`` default), 1 keeps every source pixel, −1 OpenCV's
            default.
        """
        cv2 = _cv2()
        K1, K2 = (np.asarray(k, dtype=float).reshape(3, 3) for k in (K1, K2))
        (model1, D1), (model2, D2) = distortion_model_of(D1), distortion_model_of(D2)
        size = (int(image_size[0]), int(image_size[1]))
        R1, R2, P1, P2, *_ = cv2.stereoRectify(
            K1, D1, K2, D2, size, np.asarray(R, dtype=float).reshape(3, 3),
            np.asarray(T, dtype=float).reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY,
            alpha=float(alpha))
        return cls(CameraModel(size[0], size[1], K1, D1, R1, P1, model1),
                   CameraModel(size[0], size[1], K2, D2, R2, P2, model2))

    def extrinsics(self):
        """(R, T): the right optical frame from the left one, x_r = R·x_l + T (T in m).

        Follows from the rectification: R2·x_r = R1·x_l − (b, 0, 0).
        """
        R = self.right.R.T @ self.left.R
        T = -self.right.R.T @ np.array([self.baseline_m, 0.0, 0.0])
        return R, T

    def project_raw(self, points_left):
        """Points (N, 3) in the left camera's optical frame → raw pixels of both cameras.

        Returns ``uv_left`` (N, 2), ``uv_right`` (N, 2) (px) and the left depth (N,) (m).
        """
        p = np.asarray(points_left, dtype=float).reshape(-1, 3)
        R, T = self.extrinsics()
        uv_l, z = self.left.project(p)
        uv_r, _ = self.right.project(p @ R.T + T)
        return uv_l, uv_r, z

    def project_rectified(self, points_rect):
        """Points (N, 3) in the left rectified frame → rectified pixels (N, 2) of the left
        and right cameras and depth (N,) (m); rows equal, disparity fx'·b/z.
        """
        uv_l, z = self.left.project_rectified(points_rect)
        uv_r, _ = self.right.project_rectified(points_rect)
        return uv_l, uv_r, z

    def rectify_points(self, uv_left_raw, uv_right_raw):
        """Raw pixels (N, 2) of the two cameras → rectified pixels (N, 2) of each."""
        return self.left.rectify_points(uv_left_raw), self.right.rectify_points(uv_right_raw)

    def triangulate(self, uv_left_rect, uv_right_rect):
        """Rectified pixel pairs (N, 2) → points (N, 3) in the left rectified frame, m.

        z = fx'·b / (u_l − u_r − (cx_l − cx_r)), as image_geometry's
        ``projectPixelTo3d`` (the rows are taken from the left pixel).
        """
        uv_l = np.asarray(uv_left_rect, dtype=float).reshape(-1, 2)
        uv_r = np.asarray(uv_right_rect, dtype=float).reshape(-1, 2)
        P = self.left.P
        disparity = (uv_l[:, 0] - uv_r[:, 0]) - (self.left.cx - self.right.cx)
        with np.errstate(divide='ignore', invalid='ignore'):
            z = P[0, 0] * self.baseline_m / disparity
        y = (uv_l[:, 1] - P[1, 2]) * z / P[1, 1]
        x = (uv_l[:, 0] - P[0, 2] - P[0, 1] * y / z) * z / P[0, 0]
        return np.column_stack([x, y, z])

    def camera_info_dicts(self):
        """CameraInfo contents of the left and right cameras (see
        :meth:`CameraModel.to_camera_info`).
        """
        return [self.left.to_camera_info(), self.right.to_camera_info()]
