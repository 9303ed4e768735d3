"""One lamp, one stereo frame → one along-track fix of ``base_link`` with its variance.

Geometry (conventions of ``vlc_common.core.camera``): the left optical centre
sits at ``t_base_cam`` in ``base_link``, its optical axes are the columns of
``R_base_cam``; the right camera is ``baseline_m`` further along the left optical x
axis. ``R_map_base`` is the platform attitude (``base_link`` → ``map``).

Two fixes are offered:

* :func:`paper_fix` — the paper's chain: triangulate (eq. 12), rotate the camera-frame
  lamp vector into ``map`` with the attitude and subtract it from the lamp's map
  position (eq. 13–14). Its along-track component inherits the attitude error times the
  lamp's lateral/vertical lever (≈ 2.5 m: 0.5° of heading error ≈ 2 cm).
* :func:`constrained_fix` — the track constraint (``base_link`` lateral and vertical
  offsets are known to vibration level, mm) leaves one unknown, the chainage ``s``; the
  three triangulated coordinates are three measurements of it. A generalised
  least-squares fit weights them with the full covariance: the pixel noise
  (triangulation Jacobian: the range is noisy, σz = z²·σd/(f·b), the direction is
  precise) plus the attitude error mapped through the lamp's lever (large across the
  line of sight, zero along it — the stereo range is attitude-independent) plus the
  track and lamp-survey tolerances. For a lamp far ahead the fit therefore rests on the
  range, ``s = x_lamp − √(r² − Δy² − Δz²)`` with no attitude error; for a near lamp
  (small along-track offset, where that square root is ill-conditioned) on the
  direction, whose attitude error is small at short range. The fit's residual (two
  degrees of freedom) tests range and direction against each other, which flags a
  wrong stereo match or a lamp off its surveyed place.

Every fix splits its variance into a *random* part (pixel noise, independent from frame
to frame) and a *systematic* part (attitude, track and survey errors, and the camera
calibration: stereo scale, focal length, principal point and mount angles — correlated
over many frames and, for the calibration, over every lamp); the filter uses the sum and
keeps the systematic part as a floor of the published covariance, because averaging
frames does not remove it (:func:`calibration_covariance`).
"""
from dataclasses import dataclass, replace
import math

import numpy as np

from train_localizer.core.track import Track
from vlc_common.core.camera import StereoRig, mount_rotation
from vlc_common.core.observation import NS_PER_S


def skew(v):
    """Cross-product matrix (3, 3) of a vector (3,): ``skew(a) @ b == a × b``."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@dataclass
class RigGeometry:
    """Rectified stereo rig on ``base_link`` plus its rolling-shutter timing.

    Attributes
    ----------
    fx, fy, cx, cy : float
        Rectified intrinsics of both cameras, px.
    baseline_m : float
        Right optical centre minus left, along the left optical x axis, m.
    t_base_cam : ndarray (3,)
        Left optical centre in ``base_link``, m.
    R_base_cam : ndarray (3, 3)
        Columns: the optical x, y, z axes expressed in ``base_link``.
    row_time_s, exposure_s : float
        Rolling shutter: row r is exposed over [t0 + r·row_time_s, … + exposure_s], s.
    calibration_sigma_px : tuple of 2 floats
        1σ of the stereo calibration's error in the rectified centres (direction, px:
        principal point, distortion, rectification) and in the disparity (px: the
        stereo rotation and the residual of the lenses' distortion), a systematic
        error (the same for every frame) of a real calibration; used only while
        ``raw_images`` (camera_info with a lens D or a rectification R).
    raw_images : bool
        The spot pairs come from raw images rectified through a calibration
        (:class:`~train_localizer.conversions.CameraInfoIntrinsics` sets it); with an
        ideal rectified pair (the simulated ideal rig) the geometry is exact.
    """

    fx: float = 1040.0
    fy: float = 1040.0
    cx: float = 639.5
    cy: float = 359.5
    baseline_m: float = 0.12
    t_base_cam: np.ndarray = None
    R_base_cam: np.ndarray = None
    row_time_s: float = 30e-6
    exposure_s: float = 50e-6
    calibration_sigma_px: tuple = (0.0, 0.0)
    raw_images: bool = False

    def __post_init__(self):
        if self.t_base_cam is None or self.R_base_cam is None:
            # The rig's own mounting defaults: one source of truth for the geometry.
            rig = StereoRig()
            if self.t_base_cam is None:
                self.t_base_cam = rig.cam_positions_base()[0]
            if self.R_base_cam is None:
                self.R_base_cam = rig.R_base_cam
        self.t_base_cam = np.asarray(self.t_base_cam, dtype=float).reshape(3)
        self.R_base_cam = np.asarray(self.R_base_cam, dtype=float).reshape(3, 3)
        if not (self.fx > 0.0 and self.fy > 0.0 and self.baseline_m > 0.0):
            raise ValueError('fx, fy and baseline_m must be > 0')
        if self.row_time_s < 0.0 or self.exposure_s < 0.0:
            raise ValueError('row_time_s and exposure_s must be >= 0')

    @classmethod
    def from_mount(cls, mount_xyz_m, placement_angle_deg, pitch_deg, roll_deg=0.0, **kwargs):
        """Geometry from the rig's mounting parameters (see ``mount_rotation``)."""
        return cls(t_base_cam=np.asarray(mount_xyz_m, dtype=float),
                   R_base_cam=mount_rotation(placement_angle_deg, pitch_deg, roll_deg),
                   **kwargs)

    @classmethod
    def from_stereo_rig(cls, rig, row_time_s=30e-6, exposure_s=50e-6):
        """Geometry of a ``vlc_common.core.camera.StereoRig`` (the truth)."""
        k = rig.intrinsics
        return cls(fx=k.fx, fy=k.fy, cx=k.cx, cy=k.cy, baseline_m=rig.baseline_m,
                   t_base_cam=rig.cam_positions_base()[0], R_base_cam=rig.R_base_cam,
                   row_time_s=row_time_s, exposure_s=exposure_s)


@dataclass
class FixConfig:
    """Error model and switches of a fix.

    Attributes
    ----------
    use_range_constraint : bool
        True: :func:`constrained_fix` (track constraint + stereo range); False: the
        paper's :func:`paper_fix`.
    track_sigma_yz_m : tuple of 2 floats
        1σ of ``base_link``'s lateral and vertical offset from its nominal place on the
        track (vibration and track irregularity), m.
    track_offset_yz_m : tuple of 2 floats
        Nominal lateral and vertical position of ``base_link`` in ``map``, m.
    lamp_position_sigma_m : float
        1σ of each coordinate of a lamp's surveyed map position, m (also absorbs small
        spot-centre biases; a systematic error).
    min_disparity_px : float
        Pairs with a smaller disparity (range beyond fx·b/d) are not used, px.
    track : Track or None
        The alignment ``base_link`` rides on (None: the straight line along map x with
        ``track_offset_yz_m``; see :mod:`train_localizer.core.track`).
    attitude_weight_inflation : float
        Factor on the attitude covariance in the *weights* of the constrained fit (not
        in its reported variance). The attitude error is correlated over many frames,
        so unlike pixel noise it does not average out in the filter; weighting it as if
        it were ``k`` times larger shifts the fit toward the attitude-free range
        wherever the range is informative. 1 = plain single-frame GLS.
    stereo_scale_sigma : float
        Relative 1σ of the stereo scale fx·b as calibrated (every range scales with it),
        dimensionless; 0 = taken as exact.
    focal_length_sigma : float
        Relative 1σ of the focal length at a fixed fx·b (turns the off-axis directions),
        dimensionless.
    principal_point_sigma_px : float
        1σ of the principal point (cx, cy) of the rectified pair, px.
    mount_angle_sigma_rad : tuple of 3 floats
        1σ of the camera mount angles about ``base_link`` x, y, z (roll, pitch, yaw) as
        calibrated, rad.

    The last four are systematic: shared by every frame and every lamp of a run
    (:func:`calibration_covariance`). A lamp map entry with ``position_sigma_m`` replaces
    ``lamp_position_sigma_m`` for that lamp.
    """

    use_range_constraint: bool = True
    track_sigma_yz_m: tuple = (0.004, 0.004)
    track_offset_yz_m: tuple = (0.0, 0.0)
    lamp_position_sigma_m: float = 0.005
    min_disparity_px: float = 4.0
    attitude_weight_inflation: float = 4.0
    stereo_scale_sigma: float = 0.001
    focal_length_sigma: float = 0.001
    principal_point_sigma_px: float = 0.5
    mount_angle_sigma_rad: tuple = (0.05 * math.pi / 180.0, 0.1 * math.pi / 180.0,
                                    0.1 * math.pi / 180.0)
    track: Track = None

    def __post_init__(self):
        if self.track is None:
            self.track = Track(None, self.track_offset_yz_m)
        self.mount_angle_sigma_rad = tuple(float(v) for v in self.mount_angle_sigma_rad)
        values = (self.stereo_scale_sigma, self.focal_length_sigma,
                  self.principal_point_sigma_px, self.lamp_position_sigma_m,
                  *self.mount_angle_sigma_rad)
        if len(self.mount_angle_sigma_rad) != 3 or not all(
                math.isfinite(v) and v >= 0.0 for v in values):
            raise ValueError('calibration and survey sigmas must be finite and >= 0 '
                             '(mount_angle_sigma_rad: 3 values)')

    def without_calibration(self):
        """A copy with the calibration taken as exact (the pre-calibration-term model)."""
        return replace(self, stereo_scale_sigma=0.0, focal_length_sigma=0.0,
                       principal_point_sigma_px=0.0, mount_angle_sigma_rad=(0.0, 0.0, 0.0))


@dataclass
class FixResult:
    """Along-track position of ``base_link`` from one lamp in one frame.

    Attributes
    ----------
    chainage_m : float
        Estimated chainage (map x) of ``base_link`` at the measurement time, m.
    var_m2 : float
        Total variance of ``chainage_m``, m² (= random + systematic).
    var_random_m2, var_systematic_m2 : float
        Pixel-noise part and attitude/track/survey part, m².
    chi2_geometry : float
        GLS residual χ² (2 degrees of freedom) of :func:`constrained_fix`; NaN for
        :func:`paper_fix`.
    position_m : ndarray (3,)
        Full ``base_link`` position of the fix in ``map`` (paper fix: eq. 14;
        constrained fix: chainage and the nominal track offsets), m.
    range_m : float
        Stereo range from the left optical centre to the lamp, m.
    attitude_error_rad, attitude_error_cov_rad2 : ndarray (3,), (3, 3) or None
        :func:`constrained_fix` only: the fitted error ``δθ`` of the IMU attitude about
        the map axes (true = Exp(δθ)·R_imu) and its covariance, rad, rad².
    """

    chainage_m: float
    var_m2: float
    var_random_m2: float
    var_systematic_m2: float
    chi2_geometry: float
    position_m: np.ndarray
    range_m: float
    attitude_error_rad: np.ndarray = None
    attitude_error_cov_rad2: np.ndarray = None

    @property
    def sigma_m(self):
        return math.sqrt(self.var_m2)


def measurement_time_ns(obs, geometry, use_exposure_stamping=True):
    """Instant a lamp observation describes, ns.

    The exposure mid-time of the rows the spot covers (rolling shutter: the spot's rows
    are exposed ``row·row_time_s`` after the image stamp; 1 ms is 2.8 cm at 100 km/h).
    Uses the record's own offset when it has one, else the spot's centre row
    ``v = (v_left + v_right)/2``: ``stamp + v·row_time_s + exposure_s/2``. With
    ``use_exposure_stamping`` False the image stamp itself (the paper's timing).
    """
    if not use_exposure_stamping:
        return int(obs.stamp_ns)
    offset_s = obs.exposure_mid_offset_s
    if not math.isfinite(offset_s):
        v = 0.5 * (obs.uv_left[1] + obs.uv_right[1])
        offset_s = max(v, 0.0) * geometry.row_time_s + 0.5 * geometry.exposure_s
    return int(obs.stamp_ns) + int(round(offset_s * NS_PER_S))


def triangulate(obs, geometry, min_disparity_px=0.0):
    """Stereo triangulation of a spot pair in the left optical frame (paper eq. 12).

    ``Z = fx·b/d``, ``X = (u_l − cx)·b/d``, ``Y = (v − cy)·(fx/fy)·b/d`` with the
    disparity ``d = u_l − u_r`` and ``v`` the mean row of the two centres.

    Parameters
    ----------
    obs : LampObservation
    geometry : RigGeometry
    min_disparity_px : float
        Smaller disparities are refused (too far, or a wrong pair), px.

    Returns
    -------
    p_cam : ndarray (3,) or None
        Lamp in the left optical frame, m; None when the disparity is too small.
    cov_cam : ndarray (3, 3) or None
        First-order covariance of ``p_cam`` from the centre uncertainties, m².
    """
    g = geometry
    d = obs.disparity_px
    if not d > max(min_disparity_px, 0.0):
        return None, None
    u = obs.uv_left[0]
    v = 0.5 * (obs.uv_left[1] + obs.uv_right[1])
    k = g.baseline_m / d
    p = np.array([(u - g.cx) * k, (v - g.cy) * (g.fx / g.fy) * k, g.fx * k])  # paper eq. 12
    su2 = obs.sigma_u_px ** 2
    sd2 = obs.sigma_disparity_px ** 2 if math.isfinite(obs.sigma_disparity_px) else 2.0 * su2
    # d = u_l − u_r shares u_l's error: cov(u_l, d) = σu² for independent centres,
    # clipped so that the input covariance stays positive definite.
    c_ud = min(su2, 0.999 * math.sqrt(su2 * sd2))
    cov_in = np.array([[su2, 0.0, c_ud], [0.0, 0.5 * obs.sigma_v_px ** 2, 0.0],
                       [c_ud, 0.0, sd2]])
    J = np.array([[k, 0.0, -p[0] / d],
                  [0.0, (g.fx / g.fy) * k, -p[1] / d],
                  [0.0, 0.0, -p[2] / d]])
    return p, J @ cov_in @ J.T


def calibration_covariance(p_cam, geometry, config, raw_scale=1.0, disparity_sigma_px=None):
    """Covariance (3, 3) of a triangulated lamp from the calibration's uncertainty, m².

    First order, in the left optical frame, for the lamp at ``p_cam = (X, Y, Z)``: with
    the stereo scale fx·b off by ``ε_s`` every coordinate scales (δp = ε_s·p); a focal
    length off by ``ε_f`` at the same fx·b turns the off-axis directions
    (δp = −ε_f·(X, Y, 0)); a principal point off by (δcx, δcy) shifts the direction
    (δp = −Z·(δcx/fx, δcy/fy, 0)); the camera turned by δφ about ``base_link`` against
    its calibrated mount moves the lamp across its line of sight
    (δp = [p]×·R_bcᵀ·δφ). The errors are those of the run's calibration: the same for
    every frame and lamp, so the fix reports them in its systematic part. With raw
    images (``geometry.raw_images``) the rectification of the calibration adds its own
    direction and disparity error (:func:`raw_calibration_covariance`, times
    ``raw_scale``; ``disparity_sigma_px`` replaces the calibration's disparity 1σ for
    this lamp, e.g. where the learnt disparity map knows it better).
    """
    p = np.asarray(p_cam, dtype=float)
    g = geometry
    cov = config.stereo_scale_sigma ** 2 * np.outer(p, p)
    q = np.array([p[0], p[1], 0.0])
    cov += config.focal_length_sigma ** 2 * np.outer(q, q)
    pp = config.principal_point_sigma_px * p[2]
    cov += np.diag([(pp / g.fx) ** 2, (pp / g.fy) ** 2, 0.0])
    sig = np.asarray(config.mount_angle_sigma_rad, dtype=float)
    if np.any(sig > 0.0):
        J = skew(p) @ g.R_base_cam.T
        cov += J @ np.diag(sig * sig) @ J.T
    return cov + raw_scale * raw_calibration_covariance(p, g, disparity_sigma_px)


def lamp_sigma(lamp, config):
    """Survey 1σ (3,) of a map lamp along map x, y, z: its own ``position_sigma_m`` where
    the map states it, else ``config.lamp_position_sigma_m``, m.
    """
    return _lamp_sigma_or_default(getattr(lamp, 'position_sigma_m', None), config)


def raw_calibration_covariance(p_cam, geometry, disparity_sigma_px=None):
    """(3, 3) covariance of a triangulated lamp ``p_cam`` (left optical frame, m) from
    the calibration's systematic error (``geometry.calibration_sigma_px``: direction and
    disparity 1σ, px), through the triangulation Jacobian; zero unless
    ``geometry.raw_images``.

    A calibration of 0.15 px reprojection RMS still leaves the rectified pair a few
    tenths of a pixel of disparity error (its stereo rotation to ~0.01°, the lenses'
    distortion near the image corners): 0.4 px on the 13 px of a lamp 9 m ahead is a
    3 % range error, 30 cm, far above the spot's own 0.02 px. Weighted as such, the fix
    leans on the lamp's direction where the range is weak instead of trusting a biased
    range. ``disparity_sigma_px`` (not None) replaces the disparity 1σ for this lamp.
    """
    sigma_dir, sigma_disp = (float(v) for v in geometry.calibration_sigma_px)
    if disparity_sigma_px is not None:
        sigma_disp = float(disparity_sigma_px)
    if not geometry.raw_images or (sigma_dir <= 0.0 and sigma_disp <= 0.0):
        return np.zeros((3, 3))
    g = geometry
    p = np.asarray(p_cam, float)
    k = p[2] / g.fx                                   # b/d with d = fx·b/z
    d = g.fx * g.baseline_m / p[2]
    J = np.array([[k, 0.0, -p[0] / d],
                  [0.0, (g.fx / g.fy) * k, -p[1] / d],
                  [0.0, 0.0, -p[2] / d]])
    return J @ np.diag([sigma_dir ** 2, sigma_dir ** 2, sigma_disp ** 2]) @ J.T


def predicted_camera_point(base_position_m, R_map_base, lamp_position_m, geometry):
    """Lamp in the left optical frame for a given ``base_link`` pose, m (3,)."""
    p_base = R_map_base.T @ (np.asarray(lamp_position_m, float) - base_position_m)
    return geometry.R_base_cam.T @ (p_base - geometry.t_base_cam)


def paper_fix(p_cam, cov_cam, lamp_position_m, R_map_base, cov_att, geometry, config,
              lamp_sigma_m=None, disparity_sigma_px=None):
    """``base_link`` position from the lamp's map position and the attitude (eq. 13–14).

    ``p_base = R_base_cam·p_cam + t_base_cam`` (eq. 13) and
    ``p_map(base_link) = p_lamp − R_map_base·p_base`` (eq. 14); the chainage is its x.

    Parameters
    ----------
    p_cam, cov_cam : ndarray (3,), (3, 3)
        Triangulated lamp and covariance (:func:`triangulate`), m, m².
    lamp_position_m : ndarray (3,)
        Lamp centre in ``map``, m.
    R_map_base : ndarray (3, 3)
        Platform attitude.
    cov_att : ndarray (3, 3)
        Attitude error covariance about map x, y, z, rad².
    geometry : RigGeometry
    config : FixConfig
    lamp_sigma_m : ndarray (3,) or None
        Survey 1σ of this lamp along map x, y, z (:func:`lamp_sigma`); None:
        ``config.lamp_position_sigma_m`` on every axis, m.
    disparity_sigma_px : float or None
        Systematic disparity 1σ of this lamp's pair (raw images), px; None: the
        calibration's (``geometry.calibration_sigma_px``).

    Returns
    -------
    FixResult
    """
    w = geometry.R_base_cam @ p_cam + geometry.t_base_cam            # paper eq. 13
    Rw = R_map_base @ w
    position = np.asarray(lamp_position_m, float) - Rw               # paper eq. 14
    chainage = config.track.chainage_of(position)
    _, t, _ = config.track.frame(chainage)
    J_cam = -t @ (R_map_base @ geometry.R_base_cam)
    # R_true = Exp(δθ)·R: p = lamp − Exp(δθ)·R·w ⇒ ∂p/∂δθ = [R·w]×
    J_att = t @ skew(Rw)
    var_random = float(J_cam @ cov_cam @ J_cam)
    sigma_lamp = _lamp_sigma_or_default(lamp_sigma_m, config)
    var_sys = (float(J_att @ cov_att @ J_att) + float(t @ (sigma_lamp ** 2 * t))
               + float(J_cam @ calibration_covariance(p_cam, geometry, config,
                                                      disparity_sigma_px=disparity_sigma_px)
                       @ J_cam))
    return FixResult(chainage_m=chainage, var_m2=var_random + var_sys,
                     var_random_m2=var_random, var_systematic_m2=var_sys,
                     chi2_geometry=float('nan'), position_m=position,
                     range_m=float(np.linalg.norm(p_cam)))


def exp_so3(v):
    """Rotation matrix of the rotation vector ``v`` (3,) (Rodrigues)."""
    angle = float(np.linalg.norm(v))
    K = skew(v)
    if angle < 1e-12:
        return np.eye(3) + K
    return (np.eye(3) + math.sin(angle) / angle * K
            + (1.0 - math.cos(angle)) / (angle * angle) * K @ K)


def constrained_fix(p_cam, cov_cam, lamp_position_m, R_map_base, cov_att, geometry, config,
                    lamp_sigma_m=None, disparity_sigma_px=None):
    """Chainage of ``base_link`` by a Gauss–Newton fit under the track constraint, with
    the attitude error estimated alongside it.

    Model (``base_link`` at ``(s, y0, z0)`` in ``map``, true attitude
    ``Exp(δθ)·R`` with ``R`` the IMU attitude and ``δθ`` its error about the map axes)::

        p_cam = R_cbᵀ · (Rᵀ·Exp(−δθ)·(p_lamp − (s, y0, z0)) − t_cb)

    Unknowns ``s`` and ``δθ`` (4); measurements the three triangulated coordinates
    (covariance: triangulation + track offsets + lamp survey + calibration) and the prior
    ``δθ ~ N(0, Σ_att)`` from ``imu/data`` (3). The fit is iterated to convergence
    because a linearisation about ``δθ = 0`` fails exactly when it matters: after a
    cold start at speed the heading is uncertain by ~5°, and the second-order term
    ``|d|·δθ²/2`` (4 cm at 9 m) then biases a single linearised step by several
    centimetres while its variance claims half a centimetre. The reported variance is
    the ``s`` marginal of the fit's covariance at the solution (so it carries the
    attitude uncertainty), split into the pixel-noise part and the rest; the fitted
    ``δθ`` and its covariance are returned as a vision measurement of the attitude.
    ``chi2_geometry`` is the fit's weighted residual (2 degrees of freedom).

    ``config.attitude_weight_inflation`` scales ``Σ_att`` in the prior: the attitude
    error is correlated over many frames, so a prior weaker than its single-frame
    value keeps successive frames from re-using the same attitude information.

    Parameters and returns as :func:`paper_fix`.
    """
    fit = _attitude_fit(p_cam, cov_cam, lamp_position_m, R_map_base,
                        np.asarray(cov_att, float) * config.attitude_weight_inflation,
                        geometry, config, lamp_sigma_m,
                        disparity_sigma_px=disparity_sigma_px)
    s, dtheta, cov_post, J, W, e, prior_info = fit
    var = float(cov_post[0, 0])
    # s = K·p_cam to first order: its pixel-noise part (independent frame to frame)
    gain = (cov_post @ J.T @ W)[0]
    var_random = min(float(gain @ cov_cam @ gain), var)
    chi2 = float(e @ W @ e + dtheta @ prior_info @ dtheta)
    return FixResult(chainage_m=s, var_m2=var, var_random_m2=var_random,
                     var_systematic_m2=var - var_random, chi2_geometry=chi2,
                     position_m=config.track.position(s), range_m=float(np.linalg.norm(p_cam)),
                     attitude_error_rad=dtheta, attitude_error_cov_rad2=cov_post[1:, 1:])


def _lamp_sigma_or_default(lamp_sigma_m, config):
    if lamp_sigma_m is None:
        return np.full(3, config.lamp_position_sigma_m)
    sigma = np.asarray(lamp_sigma_m, dtype=float).reshape(3)
    return np.where(np.isfinite(sigma), sigma, config.lamp_position_sigma_m)


def _attitude_fit(p_cam, cov_cam, lamp_position_m, R_map_base, cov_prior, geometry, config,
                  lamp_sigma_m=None, calibration_scale=1.0, disparity_sigma_px=None):
    """Gauss–Newton fit of ``s`` and ``δθ`` (see :func:`constrained_fix`).

    Returns ``(s, δθ, cov_post (4, 4), J (3, 4), W (3, 3), residual (3,), prior_info)``
    at the solution. ``calibration_scale`` multiplies the calibration's covariance
    (:func:`calibration_covariance`) in the measurement covariance.
    """
    g = geometry
    track = config.track
    lamp = np.asarray(lamp_position_m, float)
    p_cam = np.asarray(p_cam, float)
    B = g.R_base_cam.T @ R_map_base.T                  # map vector → optical frame (IMU R)
    c = g.R_base_cam.T @ g.t_base_cam
    # start: the paper's fix with the IMU attitude, put on the track
    s = track.chainage_of(lamp - R_map_base @ (g.R_base_cam @ p_cam + g.t_base_cam))
    _, _, n = track.frame(s)
    A_nz = B @ np.column_stack([n, [0.0, 0.0, 1.0]])
    sigma_lamp = _lamp_sigma_or_default(lamp_sigma_m, config)
    cov_meas = (cov_cam + A_nz @ np.diag(np.square(config.track_sigma_yz_m)) @ A_nz.T
                + B @ np.diag(sigma_lamp ** 2) @ B.T
                + calibration_covariance(p_cam, g, config, calibration_scale,
                                         disparity_sigma_px))
    W = np.linalg.inv(cov_meas)
    prior_info = np.linalg.inv(cov_prior + np.eye(3) * 1e-14)
    dtheta = np.zeros(3)

    def linearise():
        E = exp_so3(-dtheta)
        P, t, _ = track.frame(s)
        d = lamp - P
        # ∂h/∂s = −B·E·t(s); ∂h/∂δθ = B·E·[d]× (first order about the current δθ)
        J = np.column_stack([-(B @ E) @ t, B @ E @ skew(d)])
        N = J.T @ W @ J
        N[1:, 1:] += prior_info
        return J, N, p_cam - (B @ E @ d - c)

    for _ in range(8):
        J, N, r = linearise()
        g_vec = J.T @ W @ r
        g_vec[1:] -= prior_info @ dtheta
        step = np.linalg.solve(N, g_vec)
        s += float(step[0])
        dtheta = dtheta + step[1:]
        if abs(step[0]) < 1e-7 and float(np.max(np.abs(step[1:]))) < 1e-9:
            break
    J, N, r = linearise()
    return s, dtheta, np.linalg.inv(N), J, W, r, prior_info


#: 1σ (roll, pitch, heading) of the weak prior, centred on the IMU attitude, that bounds
#: the attitude direction a lamp cannot see (rotation about its line of sight) in
#: :func:`vision_attitude`, rad. Tilt errors stay within degrees; the heading of a
#: compensator that cold-started on a curve can be tens of degrees off, and a prior
#: that resisted it would push the unseen share of that error into the tilt.
VISION_ATTITUDE_PRIOR_SIGMA_RAD = (0.2, 0.2, 1.0)


def vision_attitude(p_cam, cov_cam, lamp_position_m, R_map_base, geometry, config,
                    lamp_sigma_m=None, calibration_scale=1.0, disparity_sigma_px=None):
    """Attitude error of the IMU seen by one lamp, without the IMU's attitude prior.

    The fit of :func:`constrained_fix` with the IMU prior replaced by a weak one
    (:data:`VISION_ATTITUDE_PRIOR_SIGMA_RAD`): the lamp's range fixes the
    chainage and its direction two attitude angles — rotations about the line of sight
    stay unseen, and keep the weak prior's variance. The result is a measurement
    independent of the IMU attitude it corrects (for ``attitude_aiding``: the
    compensator fuses it with its full covariance, so the roll/pitch error its own
    heading inherits at close range is carried by its roll/pitch state instead of
    being averaged away as independent noise).

    Returns
    -------
    (ndarray (3,), ndarray (3, 3))
        ``δθ`` about the map axes (true attitude = Exp(δθ)·IMU attitude) and its
        covariance, rad².
    """
    cov_prior = np.diag(np.square(VISION_ATTITUDE_PRIOR_SIGMA_RAD))
    # Without the calibration terms: with the weak prior a near lamp has a mirror solution
    # (the same range with the heading turned the other way and the chainage metres off),
    # and the direction weakened by the mount uncertainty let the iteration reach it from
    # a 30° heading error. The mount error (0.1°) is small beside the aid's own σ.
    fit = _attitude_fit(p_cam, cov_cam, lamp_position_m, R_map_base, cov_prior, geometry,
                        config.without_calibration(), lamp_sigma_m, calibration_scale,
                        disparity_sigma_px)
    return np.asarray(fit[1], float), np.asarray(fit[2][1:, 1:], float)


def compute_fix(p_cam, cov_cam, lamp_position_m, R_map_base, cov_att, geometry, config,
                lamp_sigma_m=None, disparity_sigma_px=None):
    """:func:`constrained_fix` or :func:`paper_fix` as ``config.use_range_constraint`` says."""
    fn = constrained_fix if config.use_range_constraint else paper_fix
    return fn(p_cam, cov_cam, lamp_position_m, R_map_base, cov_att, geometry, config,
              lamp_sigma_m, disparity_sigma_px)
