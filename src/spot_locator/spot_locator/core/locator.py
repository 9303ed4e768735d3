"""The spot locator: a stereo pair in, sub-pixel lamp-centre pairs out.

The images are rectified (camera_info D = 0, R = I, P[:, :3] = K), or raw images of a
calibrated pair (``StereoGeometry.raw_cameras``): then each spot is measured in its raw
image as before and its centre mapped to the rectified image through that camera's K,
D, R and P (``vlc_common.core.camera.CameraModel.rectify_points``, as image_geometry)
before matching, the common centre row, the eccentricity correction and the
disparity; the stamp comes from the left spot's raw row (the row it was exposed on).

Per image: detect spots (closing joins the stripes, :mod:`.detection`); per spot: a
centre (:mod:`.centres`); per stereo pair: epipolar matching (:mod:`.matching`),
optional Wiener deblurring with the blur predicted from the train speed and the
triangulated lamp (:mod:`.deblur`), and the perspective eccentricity correction
(:mod:`.eccentricity`) that turns ellipse centres into projections of the disc centre.
"""
from dataclasses import dataclass, field
import time

import numpy as np

from spot_locator.core import centres as cm
from spot_locator.core import deblur as db
from spot_locator.core import eccentricity as ecc
from spot_locator.core import synth
from spot_locator.core.detection import DetectConfig, detect_spots
from spot_locator.core.matching import MatchConfig, SpotSummary, match_spots

METHODS = ('centroid', 'ellipse', 'fused', 'chord')
ECCENTRICITY_MODES = ('off', 'nominal', 'conic')

# bits of SpotPair.flags
FLAG_METHOD_MASK = 0x3          # index into METHODS
FLAG_WIENER = 1 << 2            # centres measured on the deblurred ROIs
FLAG_ECC_NOMINAL = 1 << 3       # eccentricity removed with the nominal disc normal
FLAG_ECC_CONIC = 1 << 4         # ... with the normal measured from the ellipses
FLAG_V_FROM_WIDTH = 1 << 5      # chord fit found the centre row from the chord widths
FLAG_ROLLING_SHUTTER = 1 << 6   # rolling-shutter model of the moving lamp applied
FLAG_CUT_BY_BORDER = 1 << 7     # a spot of the pair is cut by an image edge (the side
                                # edge: FLAG_EDGE_DISPARITY too)
FLAG_RECTIFIED = 1 << 8         # centres measured in raw images, mapped through camera_info
FLAG_EDGE_DISPARITY = 1 << 9    # one spot cut by the side border: the disparity from the
                                # chord ends both images show (SpotLocator._cut_pairs)

#: a pair from a spot cut by the side border needs this many rows with both chord ends
MIN_EDGE_ROWS = 4
#: 1σ floor of such a pair's disparity, px, and the share of its disc-plane correction
#: (chord end → disc centre) added to its σ for the lamp normal's error
EDGE_DISPARITY_FLOOR_PX = 0.05
EDGE_CORRECTION_SHARE = 0.5


@dataclass
class StereoGeometry:
    """Rectified stereo pair (from the two CameraInfo messages): pixels and metres.

    ``fx`` … ``baseline_m`` are the rectified projection's (P). ``raw_cameras`` is None
    when the images are rectified already (today's rig: D = 0, R = I, P[:, :3] = K);
    otherwise the images are raw and it holds, per camera (left, right), the tuple
    ``(K, D, R, P, distortion_model)`` of its camera_info, matrices flat as tuples of
    floats (hashable and comparable, so a node can tell a changed calibration).
    """

    fx: float = 1040.0
    fy: float = 1040.0
    cx: float = 639.5
    cy: float = 359.5
    baseline_m: float = 0.12
    width: int = 1280
    height: int = 720
    raw_cameras: tuple = None

    @property
    def K(self):
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def camera_models(self):
        """(left, right) :class:`vlc_common.core.camera.CameraModel` of the raw cameras,
        or None when the images are rectified.
        """
        if self.raw_cameras is None:
            return None
        from vlc_common.core.camera import CameraModel
        return tuple(CameraModel(self.width, self.height, K, D, R, P, model)
                     for K, D, R, P, model in self.raw_cameras)


@dataclass
class LocatorConfig:
    """Everything the locator needs besides the images (see config/spot_locator.yaml).

    method: centre estimator, one of :data:`METHODS`.
    eccentricity: 'off', 'nominal' (normal from the mounting), 'conic' (normal measured
        from large ellipses, nominal otherwise).
    lamp_radius_m: disc radius (m).
    normal_cam: nominal unit disc normal in the optical frame.
    conic_normal_min_rows: spots at least this tall give their own normal.
    conic_normal_max_angle_deg: a measured normal further than this from the nominal
        one is discarded.
    wiener: deblur the ROIs before measuring the centres.
    wiener_balance: Wiener–Hunt regularisation weight.
    min_blur_px: below this blur length the deblurring is skipped (px).
    train_velocity_cam_mps: unit velocity direction of the lamps relative to the camera
        per m/s of train speed, optical frame (−R_cam_base · x̂).
    row_time_s, exposure_s: rolling-shutter timing.
    reject_border_spots: drop spots cut by the image border (the chord fit keeps spots cut
        by the top or bottom edge: their rows are complete; they are flagged).
    pair_cut_spots: a spot cut by the image's side border (dropped as a spot) is still
        paired with the whole spot of its lamp in the other image, the disparity taken
        from the uncut chord ends (see :meth:`SpotLocator._cut_pairs`); chord method only.
    rolling_shutter_model: when the train moves, replace the static eccentricity offset by
        the offset predicted for the moving lamp (its image moves and grows while the spot
        is read out row by row), see :func:`.eccentricity.correct_pair_moving`.
    vignetting: 'cos4' divides each ROI by the natural cos⁴θ fall-off of the lens (a
        brightness gradient across a large spot pulls its centroid toward the image
        centre), 'none' leaves it.
    contour_level: iso-contour level of the paper's ellipse fit, fraction of the peak.
    trigger_skew_s: the right camera's row r is exposed this long after the left
        camera's row r (s; 0 for one trigger). With raw images or a skew, a moving
        lamp's right centre is moved back to the left centre's instant.
    """

    method: str = 'chord'
    eccentricity: str = 'conic'
    lamp_radius_m: float = 0.1
    normal_cam: tuple = (0.0, 0.0, -1.0)
    conic_normal_min_rows: int = 30
    conic_normal_max_angle_deg: float = 20.0
    wiener: bool = False
    wiener_balance: float = 0.02
    min_blur_px: float = 0.3
    train_velocity_cam_mps: tuple = (0.0, 0.0, 0.0)
    row_time_s: float = 30e-6
    exposure_s: float = 50e-6
    reject_border_spots: bool = True
    pair_cut_spots: bool = True
    rolling_shutter_model: bool = True
    vignetting: str = 'cos4'
    contour_level: float = 0.5
    trigger_skew_s: float = 0.0
    detect: DetectConfig = field(default_factory=DetectConfig)
    chord: cm.ChordConfig = field(default_factory=cm.ChordConfig)
    match: MatchConfig = field(default_factory=MatchConfig)

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f'method must be one of {METHODS}, got {self.method!r}')
        if self.eccentricity not in ECCENTRICITY_MODES:
            raise ValueError(f'eccentricity must be one of {ECCENTRICITY_MODES}')
        if self.vignetting not in ('none', 'cos4'):
            raise ValueError("vignetting must be 'none' or 'cos4'")
        n = np.asarray(self.normal_cam, float)
        if n.shape != (3,) or not np.linalg.norm(n) > 0:
            raise ValueError('normal_cam must be a non-zero 3-vector')
        if not np.isfinite(self.trigger_skew_s):
            raise ValueError('trigger_skew_s must be finite')


@dataclass
class SpotPair:
    """One lamp seen in both images (image pixels, seconds).

    ``uv_left``, ``uv_right``: centre estimates of the projected disc centre (2,);
    ``sigma_left``, ``sigma_right``: their 1σ (σu, σv); ``disparity`` and its 1σ;
    ``row_min``, ``row_max``: rows covered in the left image; ``stamp_offset_s``: exposure
    mid-time of those rows after the image stamp; ``circularity_left/right``: α (paper
    eq. 10); ``offset_left/right``: eccentricity offset removed (px); ``flags``: FLAG_*.
    """

    uv_left: np.ndarray
    uv_right: np.ndarray
    sigma_left: np.ndarray
    sigma_right: np.ndarray
    disparity: float
    sigma_disparity: float
    row_min: int
    row_max: int
    stamp_offset_s: float
    circularity_left: float
    circularity_right: float
    offset_left: np.ndarray
    offset_right: np.ndarray
    blur_px: float
    flags: int


@dataclass
class FrameResult:
    """Output of one stereo pair."""

    pairs: list
    n_left: int
    n_right: int
    unmatched_left: int
    unmatched_right: int
    rejected_border: int
    failed: int
    processing_s: float
    edge_pairs: int = 0


@dataclass
class _Spot:
    region: object
    est: cm.CentreEstimate
    alpha: float
    u: float
    v: float
    ur: float = float('nan')    # rectified centre (raw images only)
    vr: float = float('nan')


class SpotLocator:
    """Stateless per-frame spot locator (thread-safe if not shared across threads)."""

    def __init__(self, config=None, geometry=None):
        self.cfg = config or LocatorConfig()
        self.geom = geometry or StereoGeometry()
        n = np.asarray(self.cfg.normal_cam, float)
        self.normal_cam = n / np.linalg.norm(n)
        self._cos4_map = None      # (geometry key, the frame's cos⁴ map), see _cos4
        # raw images: the cameras' models, and the left optical frame → rectified frame
        self.models = self.geom.camera_models()
        self._R_rect = None if self.models is None else self.models[0].R
        if self._R_rect is not None:
            self.normal_cam = self._R_rect @ self.normal_cam

    def process(self, left, right, speed_mps=0.0):
        """Locate lamp spot pairs in one rectified stereo pair.

        Parameters
        ----------
        left, right : (H, W) mono images of identical size.
        speed_mps : train speed for the blur length (m/s, ≥ 0).

        Returns
        -------
        FrameResult
        """
        t_start = time.perf_counter()
        if np.shape(left) != np.shape(right):
            raise ValueError(f'left {np.shape(left)} and right {np.shape(right)} differ')
        spots = []
        cut_regions = ([], [])
        rejected = failed = 0
        keep_cut = self.cfg.pair_cut_spots and self.cfg.method == 'chord'
        for image, side_cut in zip((left, right), cut_regions):
            found = []
            for region in detect_spots(image, self.cfg.detect):
                # The chord fit needs complete rows only: a spot cut by the top or bottom
                # edge keeps them (its centre row comes from the visible part of the
                # width parabola, with a larger σ); the other methods need the whole spot.
                cut = (region.cut_columns if self.cfg.method == 'chord'
                       else region.touches_border)
                if cut and self.cfg.reject_border_spots:
                    rejected += 1
                    if keep_cut and region.cut_columns:
                        side_cut.append(region)
                    continue
                if self.cfg.vignetting == 'cos4':
                    region.roi = self._flat_field(region)
                spot = self.measure(region, region.roi)
                if spot is None:
                    failed += 1
                    continue
                if self._hidden_by_edge(spot, np.shape(image)[0]):
                    rejected += 1
                    continue
                found.append(spot)
            spots.append(found)
        sl, sr = spots
        if self.models is None:
            summaries = [[SpotSummary(s.u, s.v, s.region.row_min, s.region.row_max,
                                      s.region.area_px) for s in side] for side in spots]
        else:
            # raw images: match on rectified centres, the row spans moved with them
            summaries = []
            for side, model in zip(spots, self.models):
                _rectify_spots(side, model)
                summaries.append([SpotSummary(s.ur, s.vr, s.region.row_min + (s.vr - s.v),
                                              s.region.row_max + (s.vr - s.v),
                                              s.region.area_px) for s in side])
        matches, um_l, um_r = match_spots(summaries[0], summaries[1], self.cfg.match)
        pairs = []
        for i, j in matches:
            pair = self._pair(sl[i], sr[j], speed_mps)
            if pair is None:
                failed += 1
            else:
                pairs.append(pair)
        edge_pairs = 0
        if cut_regions[0] or cut_regions[1]:
            found, um_l, um_r = self._cut_pairs(spots, (um_l, um_r), cut_regions, speed_mps)
            pairs += found
            edge_pairs = len(found)
        return FrameResult(pairs, len(sl), len(sr), len(um_l), len(um_r), rejected, failed,
                           time.perf_counter() - t_start, edge_pairs)

    def warm_up(self):
        """Run every per-frame code path once on a synthetic striped stereo pair.

        The first call of many library functions is slow (OpenCV's contour and
        morphology kernels, LAPACK, scipy's assignment solver, scikit-image's lazily
        imported ``measure`` and ``restoration`` submodules, numpy's ufunc loops for each
        dtype): tens of milliseconds that would otherwise fall on the first frames, or
        on the first frame that takes a rare path (the circularity fallback, a Wiener
        restoration) in the middle of a run. A node calls this before it subscribes.

        Returns
        -------
        int
            Pairs found in the synthetic frame at speed 0 and in motion (≥ 2 when the
            whole pipeline ran).
        """
        g, cfg = self.geom, self.cfg
        K = g.K
        # a lamp 3 m in front of the left camera, 0.2 m up and left, facing the
        # configured normal: tens of rows tall, so the conic normal is measured too
        centre = np.array([-0.2, -0.2, 3.0])
        shape = (g.height, g.width)
        exposure = synth.Exposure(row_time_s=cfg.row_time_s, exposure_s=cfg.exposure_s,
                                  n_time=1)
        def stripes(t_s):
            # on for 4 rows, off (5 %) for 4 rows
            return np.where(np.floor(np.asarray(t_s) / (4.0 * cfg.row_time_s)) % 2 == 0,
                            1.0, 0.05)

        images = []
        for offset in (0.0, g.baseline_m):
            c = centre - np.array([offset, 0.0, 0.0])
            spot = synth.render_disc(shape, K, c, self.normal_cam, cfg.lamp_radius_m,
                                     radiance=150.0, supersample=2, exposure=exposure,
                                     level=stripes)
            images.append(np.clip(spot + 4.0, 0, 255).astype(np.uint8))
        found = 0
        # standing, then at 20 m/s (the rolling-shutter model and, if on, Wiener)
        for speed_mps in (0.0, 20.0):
            found += len(self.process(images[0], images[1], speed_mps).pairs)
        regions = detect_spots(images[0], cfg.detect)
        if regions:
            r = regions[0]
            self._alpha(r, r.roi)
            self.measure(r, db.wiener_deblur(r.roi, db.motion_psf((1.0, 0.0)),
                                             cfg.wiener_balance))
        return found

    def measure(self, region, roi, method=None):
        """Centre of one detected spot with ``method`` (default: the configured one).

        ``roi`` is the region's grey levels to use (its own, or a deblurred copy).
        Returns an object with the image coordinates ``u``, ``v`` (px), the
        :class:`~.centres.CentreEstimate` ``est`` and the circularity ``alpha``, or None
        when the method fails.
        """
        method = method or self.cfg.method
        noise = region.noise_sigma
        alpha = float('nan')
        if method == 'chord':
            est = cm.chord_fit(roi, region.support, noise, self.cfg.chord, region.saturated,
                               region.threshold, region.edge_rows)
        else:
            closed = cm.close_stripes(np.where(region.support, roi, 0.0),
                                      self.cfg.detect.closing_rows)
            if method in ('centroid', 'fused'):
                est_c = cm.gray_centroid(closed, region.threshold, noise)
            if method in ('ellipse', 'fused'):
                peak = float(closed.max())
                contour = cm.spot_contour(closed, self.cfg.contour_level * peak)
                est_e = cm.ellipse_fit(contour)
                alpha = cm.circularity(contour)
            if method == 'centroid':
                est = est_c
            elif method == 'ellipse':
                est = est_e
            else:
                est = cm.fuse_by_circularity(est_c, est_e, alpha)
        if not est.ok or not np.isfinite([est.u, est.v]).all():
            return None
        if np.isnan(alpha) and est.conic is not None:
            alpha = cm.ellipse_circularity(est.conic)
        if np.isnan(alpha):
            alpha = self._alpha(region, roi)
        return _Spot(region, est, alpha, est.u + region.u0, est.v + region.v0)

    def _flat_field(self, region):
        """The ROI divided by the lens fall-off, with clipped pixels restored per row.

        A clipped pixel's true level is unknown. The lamp disc is uniform, so within one
        row every fully covered pixel has the same flat-fielded level: clipped pixels
        take the level of that row's unclipped plateau when the row has one (the
        fall-off clips the brighter side of a row first, and a lower value there would
        pull the row's centre away from it), and at least the clip level itself.
        """
        cos4 = self._cos4(region)
        roi = region.roi / cos4
        sat = region.saturated
        if sat is None or not sat.any():
            return roi
        rows = sat.any(axis=1)
        n_sat = np.maximum(sat.sum(axis=1, keepdims=True), 1)
        clip_level = np.where(sat, roi, 0.0).sum(axis=1, keepdims=True) / n_sat
        # the unclipped plateau: unclipped pixels near the row's unclipped maximum (their
        # mean, as the maximum alone is pushed up by the noise)
        top = np.where(sat, -np.inf, roi).max(axis=1, keepdims=True)
        near_top = ~sat & (roi >= 0.95 * top)
        n_top = near_top.sum(axis=1, keepdims=True)
        plateau = np.where(n_top > 0, np.where(near_top, roi, 0.0).sum(axis=1, keepdims=True)
                           / np.maximum(n_top, 1), -np.inf)
        level = np.where(rows[:, None], np.maximum(plateau, clip_level), 0.0)
        return np.where(sat, level, roi)

    def _cos4(self, region):
        """cos⁴ of the angle off the optical axis at each ROI pixel."""
        g = self.geom
        h, w = region.roi.shape
        u0, v0 = region.u0, region.v0
        if 0 <= u0 and u0 + w <= g.width and 0 <= v0 and v0 + h <= g.height:
            # the ROI's part of the whole frame's map, computed once per geometry
            if self._cos4_map is None or self._cos4_map[0] != (g.width, g.height, g.fx,
                                                               g.fy, g.cx, g.cy):
                key = (g.width, g.height, g.fx, g.fy, g.cx, g.cy)
                self._cos4_map = key, _cos4_grid(g, 0, 0, g.width, g.height)
            return self._cos4_map[1][v0:v0 + h, u0:u0 + w]
        return _cos4_grid(g, u0, v0, w, h)

    def _alpha(self, region, roi):
        closed = cm.close_stripes(np.where(region.support, roi, 0.0),
                                  self.cfg.detect.closing_rows)
        return cm.circularity(cm.spot_contour(closed, self.cfg.contour_level
                                              * float(closed.max())))

    def _centre(self, spot):
        """The spot's centre in the rectified image (its raw centre when rectified)."""
        if self.models is None:
            return [spot.u, spot.v]
        return [spot.ur, spot.vr]

    def _right_shift(self, a, b, vel, speed_mps):
        """Image motion of the right spot from the left centre's instant to its own, px.

        The right centre is exposed on its own raw row, ``trigger_skew_s`` late: Δt =
        (v_raw_right − v_raw_left)·row_time_s + trigger_skew_s after the left one. A
        moving lamp's right image is then w·Δt from where the left instant would show it
        (w its image velocity). None when nothing moves or the two instants coincide (a
        rectified pair on one trigger).
        """
        cfg, g = self.cfg, self.geom
        if speed_mps <= 0.0 or (self.models is None and cfg.trigger_skew_s == 0.0):
            return None
        dt = (b.v - a.v) * cfg.row_time_s + cfg.trigger_skew_s
        P = ecc.triangulate(self._centre(a), self._centre(b), g.fx, g.fy, g.cx, g.cy,
                            g.baseline_m)
        if not (np.isfinite(P).all() and P[2] > 0):
            return None
        w = db.image_velocity(P - np.array([g.baseline_m, 0.0, 0.0]), vel, g.fx, g.fy)
        return w * dt

    def _cut_pairs(self, spots, unmatched, cut_regions, speed_mps):
        """Pairs of a spot cut by one image's side border with its lamp's whole spot.

        Whole: its centre measured, not extrapolated (:meth:`_whole`).

        A lamp entering or leaving the view at the far edge is cut by the left image's
        right border while whole in the right image (the left image shows it one
        disparity further right); a lamp at the near left edge is cut by the right
        image's left border while whole in the left one. Such a spot has no centre of
        its own, but the rows it shows still have their uncut chord end: on the rows
        both images show, the two ends lie one disparity apart, exactly, as the two
        images' row is one epipolar plane meeting the disc's rim in the same point
        (:func:`.centres.chord_ends`; raw images: the ends rectified, the whole spot's
        interpolated to the cut one's rectified rows). The end is a rim point, not the
        disc centre: on the disc's plane 1/Z ∝ n·(x, y, 1), so each row's end disparity
        is scaled by n·x̃_centre / n·x̃_end (the whole spot's centre and end, nominal lamp
        normal), about 0.1 px for a lamp 9.5 m ahead seen at 80° off its normal; half
        of that correction is added to the disparity's σ (the lamp normal's own error)
        with a 0.05 px floor, and the rows' scatter over √n. The pair is the whole spot's
        centre and that centre one disparity over; the cut side's σu carries the
        disparity's σ, so the triangulated lamp is known across the whole camera's line
        of sight and loosely along it. Returns (pairs, unmatched left, unmatched right).
        """
        g, cfg = self.geom, self.cfg
        left_out, right_out = list(unmatched[0]), list(unmatched[1])
        free = (left_out, right_out)
        ends = {}
        pairs = []
        for side, regions in enumerate(cut_regions):
            other = 1 - side
            end = 'lo' if side == 0 else 'hi'
            for region in regions:
                columns = np.flatnonzero(region.support.any(axis=0)) + region.u0
                at_left, at_right = columns[0] <= 0, columns[-1] >= g.width - 1
                # only these two show the lamp's whole spot in the other image
                if not ((at_right and not at_left) if side == 0 else
                        (at_left and not at_right)):
                    continue
                if cfg.vignetting == 'cos4':
                    region.roi = self._flat_field(region)
                cut_pts = self._chord_end_points(side, region, end)
                if len(cut_pts) < MIN_EDGE_ROWS:
                    continue
                best = None
                for j in free[other]:
                    s = spots[other][j]
                    if not self._whole(s):
                        continue
                    if (other, j) not in ends:
                        ends[other, j] = self._chord_end_points(other, s.region, end)
                    found = self._edge_disparity(cut_pts, ends[other, j], self._centre(s),
                                                 side)
                    if found is not None and (best is None or found[2] > best[2]):
                        best = found + (j,)
                if best is None:
                    continue
                d, sigma_d, _, j = best
                if not cfg.match.min_disparity_px <= d <= cfg.match.max_disparity_px:
                    continue
                whole = spots[other][j]
                uv_w = np.array(self._centre(whole), float)
                sigma_w = np.array([whole.est.sigma_u, whole.est.sigma_v])
                uv_c = uv_w + np.array([d if side == 0 else -d, 0.0])
                sigma_c = np.array([np.hypot(sigma_w[0], sigma_d), sigma_w[1]])
                raw = (uv_c if self.models is None
                       else self.models[side].unrectify_points(uv_c)[0])
                stand_in = _Spot(region, cm.CentreEstimate(float(raw[0]), float(raw[1]),
                                                           float(sigma_c[0]),
                                                           float(sigma_c[1]), True),
                                 float('nan'), float(raw[0]), float(raw[1]),
                                 float(uv_c[0]), float(uv_c[1]))
                a, b = (stand_in, whole) if side == 0 else (whole, stand_in)
                centres = ((uv_c, uv_w, sigma_c, sigma_w) if side == 0
                           else (uv_w, uv_c, sigma_w, sigma_c))
                pair = self._pair(a, b, speed_mps, centres)
                if pair is not None:
                    free[other].remove(j)
                    pairs.append(pair)
        return pairs, left_out, right_out

    def _hidden_by_edge(self, spot, height):
        """Whether the image's top or bottom edge may hide the part of a spot that holds
        its centre: the chord fit found no vertex of the chord widths among its rows (its
        centre row is then only the signal-weighted middle of the rows it shows) and those
        rows come within ``closing_rows`` of that edge (a dark stripe can hide that many
        rows before it). The lamp entering at the top right and the near lamp leaving at
        the bottom left give such spots, their centre 5-50 px off at a stated σv of
        0.3-1.8 px (ideal 20-120 km/h runs; the localizer refused their fixes as range
        and direction disagreeing, and then distrusted the IMU attitude for 2 s). Chord
        method only (the others reject every spot touching an edge).
        """
        if self.cfg.method != 'chord' or not self.cfg.reject_border_spots:
            return False
        if spot.est.info.get('v_from_width'):
            return False
        margin = self.cfg.detect.closing_rows
        return (spot.region.row_min < margin
                or spot.region.row_max > height - 1 - margin)

    def _whole(self, spot):
        """Whether a spot's centre is measured, not extrapolated: it touches no image
        edge, its centre row is the vertex of its chord widths (``v_from_width``; a spot
        whose lower or upper part is missing has no vertex among its rows and a centre
        row that is only the middle of the rows it shows) and the ellipse those widths
        draw lies inside the image's rows. A near lamp leaving the view at the bottom
        left corner is cut by the bottom edge in both images, its lower stripes in the
        dark: the bright component can end rows above the edge, and its centre then
        reads tens of pixels off with a σ of about a pixel.
        """
        region, info = spot.region, spot.est.info
        if region.touches_border or info.get('cut') or not info.get('v_from_width'):
            return False
        quad = info.get('quad')
        if quad is None:
            return False
        q0, q1, q2 = (float(c) for c in quad)
        disc = q1 * q1 - 4.0 * q2 * q0
        if not (q2 < 0.0 and disc > 0.0):
            return False
        centre = region.v0 + float(info['vbar']) - q1 / (2.0 * q2)
        semi = np.sqrt(disc) / (-2.0 * q2)
        return centre - semi >= -0.5 and centre + semi <= self.geom.height - 0.5

    def _chord_end_points(self, camera, region, end):
        """(n, 2) rectified image points of a region's chord ends on side ``end``
        (:func:`.centres.chord_ends`), one per bright row.
        """
        rows, u = cm.chord_ends(region.roi, region.support, end, region.noise_sigma,
                                region.saturated)
        pts = np.column_stack([u + region.u0, (rows + region.v0).astype(float)])
        if self.models is None or len(pts) == 0:
            return pts
        return self.models[camera].rectify_points(pts)

    def _edge_disparity(self, cut_pts, whole_pts, whole_centre, side):
        """(disparity of the disc centre, its 1σ, rows used) from rectified chord ends
        of the cut spot (image ``side``) and the whole one; None when fewer than
        ``MIN_EDGE_ROWS`` rows have both (see :meth:`_cut_pairs`).
        """
        if len(whole_pts) < 2:
            return None
        order = np.argsort(whole_pts[:, 1])
        V_w, U_w = whole_pts[order, 1], whole_pts[order, 0]
        V_c, U_c = cut_pts[:, 1], cut_pts[:, 0]
        k = np.searchsorted(V_w, V_c)
        inside = (k > 0) & (k < len(V_w))
        kk = np.clip(k, 1, len(V_w) - 1)
        # bracketed by whole-spot ends at most two rows apart (no dark stripe between)
        inside &= V_w[kk] - V_w[kk - 1] <= 2.01
        if np.count_nonzero(inside) < MIN_EDGE_ROWS:
            return None
        V_c, U_c = V_c[inside], U_c[inside]
        U_at = np.interp(V_c, V_w, U_w)
        d_end = U_c - U_at if side == 0 else U_at - U_c
        # the disc's plane: 1/Z ∝ n·x̃ in the whole camera's rectified frame
        g, n = self.geom, self.normal_cam
        def n_dot(u, v):
            return n[0] * (u - g.cx) / g.fx + n[1] * (v - g.cy) / g.fy + n[2]
        at_centre, at_end = n_dot(*whole_centre), n_dot(U_at, V_c)
        if abs(at_centre) < 0.02 or np.min(np.abs(at_end)) < 0.02:
            return None                            # the disc seen edge on
        d_centre = d_end * at_centre / at_end
        d = float(d_centre.mean())
        scatter = float(d_centre.std()) / np.sqrt(len(d_centre))
        model = (EDGE_CORRECTION_SHARE * abs(float((d_centre - d_end).mean()))
                 + EDGE_DISPARITY_FLOOR_PX)
        return d, float(np.hypot(scatter, model)), len(d_centre)

    def _pair(self, a, b, speed_mps, centres=None):
        """One lamp's SpotPair from its left and right spots, or None.

        ``centres`` = (uv_l, uv_r, σ_l, σ_r), rectified, replaces the centres measured
        on the two spots (a pair from a spot cut by the side border, :meth:`_cut_pairs`).
        """
        g, cfg, models = self.geom, self.cfg, self.models
        flags = METHODS.index(cfg.method)
        if centres is not None:
            flags |= FLAG_EDGE_DISPARITY
        blur_px = 0.0
        # lamp velocity relative to the camera, in the (rectified) frame of the centres
        vel = np.asarray(cfg.train_velocity_cam_mps, float) * speed_mps
        if models is not None:
            vel = self._R_rect @ vel
            flags |= FLAG_RECTIFIED
        if cfg.wiener and speed_mps > 0.0 and centres is None:
            P = ecc.triangulate(self._centre(a), self._centre(b), g.fx, g.fy, g.cx, g.cy,
                                g.baseline_m)
            if np.isfinite(P).all() and P[2] > 0:
                blur_px = float(np.hypot(*db.image_velocity(P, vel, g.fx, g.fy))
                                * cfg.exposure_s)
                a2 = self._deblur(a, P, vel)
                b2 = self._deblur(b, P - np.array([g.baseline_m, 0.0, 0.0]), vel)
                if a2 is not None and b2 is not None:
                    a, b = a2, b2
                    if models is not None:
                        _rectify_spots([a], models[0])
                        _rectify_spots([b], models[1])
                    flags |= FLAG_WIENER
        shift_r = self._right_shift(a, b, vel, speed_mps)
        sl = np.array([a.est.sigma_u, a.est.sigma_v])
        sr = np.array([b.est.sigma_u, b.est.sigma_v])
        if centres is not None:
            uv_l, uv_r, sl, sr = (np.array(c, float) for c in centres)
            if shift_r is not None:
                uv_r = uv_r - shift_r
        elif models is None:
            uv_l, uv_r = np.array([a.u, a.v]), np.array([b.u, b.v])
            if cfg.method == 'chord':
                uv_l, uv_r, sl, sr = _common_centre_row(a, b)
            if shift_r is not None:
                uv_r = uv_r - shift_r
        elif cfg.method == 'chord':
            uv_l, uv_r, sl, sr = _common_centre_row_rectified(
                a, b, models, np.zeros(2) if shift_r is None else shift_r)
        else:
            uv_l, uv_r = np.array([a.ur, a.vr]), np.array([b.ur, b.vr])
            if shift_r is not None:
                uv_r = uv_r - shift_r
        row_centre = 0.5 * (uv_l[1] + uv_r[1])
        off_l = off_r = np.zeros(2)
        moving = cfg.rolling_shutter_model and speed_mps > 0.0
        if cfg.eccentricity != 'off':
            normal, source = self._normal(a, b, vel if moving else None, uv_l, uv_r)
            if moving:
                uv_l, uv_r, off_l, off_r, _ = ecc.correct_pair_moving(
                    uv_l, uv_r, vel, normal, cfg.lamp_radius_m, g.K, g.baseline_m,
                    cfg.row_time_s, cfg.exposure_s)
                flags |= FLAG_ROLLING_SHUTTER
            else:
                uv_l, uv_r, off_l, off_r = ecc.correct_pair(
                    uv_l, uv_r, normal, cfg.lamp_radius_m, g.fx, g.fy, g.cx, g.cy,
                    g.baseline_m)
            flags |= FLAG_ECC_CONIC if source == 'conic' else FLAG_ECC_NOMINAL
            # rectified: the disc centre projects on one row in both images
            row_centre = 0.5 * (uv_l[1] + uv_r[1])
            uv_l[1] = uv_r[1] = row_centre
        if a.est.info.get('v_from_width') and b.est.info.get('v_from_width'):
            flags |= FLAG_V_FROM_WIDTH
        # cut: the component reaches the edge, or the fitted ellipse runs past it (its last
        # rows there in a dark stripe)
        if (a.region.touches_border or b.region.touches_border or a.est.info.get('cut')
                or b.est.info.get('cut')):
            flags |= FLAG_CUT_BY_BORDER
        d = float(uv_l[0] - uv_r[0])
        if not np.isfinite(d) or d <= 0.0:
            return None
        row_min, row_max = a.region.row_min, a.region.row_max
        # The centre is the lamp's projection when its own row was exposed (the rig's
        # truth convention). Dark stripe rows at the tips make the lit rows' mid-point a
        # poor proxy for that row, so use the measured one: in a raw image the row the
        # left centre lies on in that image (the row that was exposed), not its
        # rectified row.
        if models is not None:
            row_centre = float(models[0].unrectify_points(uv_l)[0, 1])
        t_mid = row_centre * cfg.row_time_s + 0.5 * cfg.exposure_s
        return SpotPair(uv_l, uv_r, sl, sr, d, float(np.hypot(sl[0], sr[0])), row_min,
                        row_max, t_mid, a.alpha, b.alpha, off_l, off_r, blur_px, flags)

    def _deblur(self, spot, P, vel):
        shift = db.image_velocity(P, vel, self.geom.fx, self.geom.fy) * self.cfg.exposure_s
        if np.hypot(*shift) < self.cfg.min_blur_px:
            return None
        psf = db.motion_psf(shift)
        restored = db.wiener_deblur(spot.region.roi, psf, self.cfg.wiener_balance)
        return self.measure(spot.region, restored)

    def _normal(self, a, b, velocity=None, uv_l=None, uv_r=None):
        """Disc normal for the eccentricity correction and where it came from.

        With a ``velocity`` (lamp relative to the camera, optical frame, m/s) the fitted
        ellipses are first undistorted: the rolling shutter shears and stretches them by
        the image velocity times the row time.
        """
        cfg, g = self.cfg, self.geom
        if cfg.eccentricity == 'conic':
            found = []
            P = (ecc.triangulate(uv_l, uv_r, g.fx, g.fy, g.cx, g.cy, g.baseline_m)
                 if velocity is not None else None)
            for s, offset in ((a, 0.0), (b, g.baseline_m)):
                rows = s.region.row_max - s.region.row_min + 1
                if s.est.conic is None or rows < cfg.conic_normal_min_rows:
                    continue
                T = np.array([[1.0, 0.0, -s.region.u0], [0.0, 1.0, -s.region.v0],
                              [0.0, 0.0, 1.0]])
                Q = T.T @ s.est.conic @ T
                if P is not None and np.isfinite(P).all() and P[2] > 0:
                    du, dv = db.image_velocity(P - [offset, 0.0, 0.0], velocity, g.fx,
                                               g.fy) * cfg.row_time_s
                    # the inverse of [[1, −du, du·v], [0, 1 − dv, dv·v], [0, 0, 1]]
                    b, c, e = du * s.v, 1.0 - dv, dv * s.v
                    Mi = np.array([[1.0, du / c, -du * e / c - b], [0.0, 1.0 / c, -e / c],
                                   [0.0, 0.0, 1.0]])
                    Q = Mi.T @ Q @ Mi
                if self.models is None:
                    n = ecc.pick_normal(ecc.normals_from_conic(Q, self.geom.K),
                                        self.normal_cam, cfg.conic_normal_max_angle_deg)
                else:
                    # the raw conic, through that camera's own K (its lens distortion
                    # over one spot is left out), its normals turned into the rectified
                    # frame
                    model = self.models[0 if offset == 0.0 else 1]
                    n = ecc.pick_normal([model.R @ m for m in
                                         ecc.normals_from_conic(Q, model.K)],
                                        self.normal_cam, cfg.conic_normal_max_angle_deg)
                if n is not None:
                    found.append(n)
            if found:
                n = np.mean(found, axis=0)
                return n / np.linalg.norm(n), 'conic'
        return self.normal_cam, 'nominal'


def _cos4_grid(g, u0, v0, w, h):
    """cos⁴ of the angle off the optical axis on pixels u0 … u0 + w − 1, v0 … v0 + h − 1."""
    x = (np.arange(u0, u0 + w) - g.cx) / g.fx
    y = (np.arange(v0, v0 + h) - g.cy) / g.fy
    cos2 = 1.0 / (1.0 + x[None, :] ** 2 + y[:, None] ** 2)
    return (cos2 * cos2).astype(np.float32)


def _common_centre_row(a, b):
    """Chord-fit centres of a pair re-evaluated on one shared centre row.

    A rectified pair images the lamp on the same rows, so the two centre-row estimates
    measure one quantity: their weighted mean is more precise, and evaluating both
    midpoint lines on it makes the disparity immune to the centre-row error (the two
    lines have nearly the same slope).
    """
    rows, lines = [], []
    for s in (a, b):
        info = s.est.info
        rows.append((info['vbar'] + s.region.v0 + (s.est.v - info['vbar']),
                     max(info['var_v'], 1e-12)))
        lines.append(info)
    w = np.array([1.0 / r[1] for r in rows])
    v0 = float(np.dot(w, [r[0] for r in rows]) / w.sum())
    var_v0 = 1.0 / w.sum()
    out_uv, out_sigma = [], []
    for s, info in zip((a, b), lines):
        d = v0 - s.region.v0 - info['vbar']
        jac = np.array([1.0, d])
        u = info['a'] + info['k'] * d + s.region.u0
        var_u = float(jac @ info['cov_line'] @ jac) + info['k'] ** 2 * var_v0
        out_uv.append(np.array([u, v0]))
        out_sigma.append(np.array([np.sqrt(var_u), np.sqrt(var_v0)]))
    return out_uv[0], out_uv[1], out_sigma[0], out_sigma[1]


def _rectify_spots(spots, model):
    """Set each spot's rectified centre (``ur``, ``vr``) from its raw one, in one call."""
    if not spots:
        return
    rect = model.rectify_points(np.array([[s.u, s.v] for s in spots]))
    for s, (ur, vr) in zip(spots, rect):
        s.ur, s.vr = float(ur), float(vr)


def _common_centre_row_rectified(a, b, models, shift_right):
    """:func:`_common_centre_row` for raw images of a calibrated pair.

    The two spots lie on one rectified row, not one raw row. Each chord fit's midpoint
    line u(v) (raw image) is mapped to the rectified image near the spot's centre row
    (the right one moved back by ``shift_right`` to the left centre's instant); the two
    rectified centre rows are averaged (inverse variance) and each line is followed to
    the raw row whose point maps onto that common rectified row (Newton steps on the
    local slope), so the disparity stays immune to the centre-row error. Returns
    rectified centres (2,) and their σ (2,) as :func:`_common_centre_row` (the raw σ:
    the lens scales them by its local Jacobian, a few per cent).
    """
    lines, rows = [], []
    for s, model, shift in ((a, models[0], np.zeros(2)), (b, models[1], shift_right)):
        info = s.est.info
        u0, v0r, aa, k, vbar = s.region.u0, s.region.v0, info['a'], info['k'], info['vbar']

        def line(v, u0=u0, v0r=v0r, aa=aa, k=k, vbar=vbar):
            v = np.atleast_1d(np.asarray(v, float))
            return np.column_stack([aa + k * (v - v0r - vbar) + u0, v])

        p = model.rectify_points(line([s.v, s.v + 1.0])) - shift
        slope = p[1] - p[0]                # rectified (du, dv) per raw row along the line
        lines.append((line, model, shift, s.v, p[0], slope))
        rows.append((p[0, 1], max(info['var_v'], 1e-12) * slope[1] ** 2))
    w = np.array([1.0 / r[1] for r in rows])
    V0 = float(np.dot(w, [r[0] for r in rows]) / w.sum())
    var_V0 = 1.0 / w.sum()
    out_uv, out_sigma = [], []
    for (line, model, shift, v, p0, slope), s in zip(lines, (a, b)):
        q = p0
        for _ in range(2):
            v = v + (V0 - q[1]) / slope[1]
            q = model.rectify_points(line(v))[0] - shift
        info = s.est.info
        d = v - s.region.v0 - info['vbar']
        jac = np.array([1.0, d])
        var_u = (float(jac @ info['cov_line'] @ jac)
                 + info['k'] ** 2 * var_V0 / max(slope[1] ** 2, 1e-12))
        out_uv.append(np.array([q[0], V0]))
        out_sigma.append(np.array([np.sqrt(var_u), np.sqrt(var_V0)]))
    return out_uv[0], out_uv[1], out_sigma[0], out_sigma[1]
