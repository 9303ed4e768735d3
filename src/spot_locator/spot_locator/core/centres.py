"""Sub-pixel centre of one lamp spot: the paper's three estimators and the row-chord fit.

All functions take a region of interest (ROI) of one spot, background already removed,
and return coordinates in that ROI's pixel frame (integer = pixel centre); the caller
adds the ROI offset.

Paper methods (§3.1):

* :func:`gray_centroid` — intensity-weighted centroid of the closed spot, the maximum-
  likelihood centre of the Gaussian spot model (paper eq. 1–5);
* :func:`ellipse_fit` — least-squares ellipse through the spot contour and its centre
  (paper eq. 6–9; OpenCV's Fitzgibbon fit on a sub-pixel iso-contour);
* :func:`circularity` and :func:`fuse_by_circularity` — α = 4πS/L² (paper eq. 10) and the
  α-weighted blend of the two centres (paper eq. 11).

Row-chord fit (this project, :func:`chord_fit`): the rolling shutter stripes the spot
along rows, so every row is an independent, complete measurement of one horizontal chord
of the imaged ellipse, whatever that row's lamp level. The chord midpoints of an ellipse
lie exactly on a straight line (the conjugate diameter of the row direction) and the
squared half-chord is a quadratic in v whose vertex is the centre row. Fitting both
uses every lit row at its own gain and needs no morphological closing, so the stripes
cause no bias.
"""
from dataclasses import dataclass, field

import cv2
import numpy as np
from skimage import measure


@dataclass
class CentreEstimate:
    """One centre estimate in ROI pixel coordinates.

    ``u``, ``v`` (px); ``sigma_u``, ``sigma_v`` (px, 1σ, from the fit residuals and the
    image noise); ``ok`` False when the method could not produce a centre; ``conic``
    (3, 3) the fitted ellipse in ROI coordinates when the method gives one.
    """

    u: float = float('nan')
    v: float = float('nan')
    sigma_u: float = float('nan')
    sigma_v: float = float('nan')
    ok: bool = False
    conic: np.ndarray = None
    info: dict = field(default_factory=dict)


def close_stripes(roi, closing_rows):
    """Grey-level morphological closing with a vertical line (paper Fig. 7).

    Joins the dark rolling-shutter stripes (rows where the lamp was off) into one solid
    spot. ``closing_rows`` must exceed the longest dark run in rows.
    """
    n = max(int(closing_rows), 1)
    kernel = np.ones((n, 1), np.uint8)
    # pad with background so that the erosion half of the closing does not eat the
    # spot's top and bottom rows at the ROI edge
    padded = np.pad(roi.astype(np.float32), ((n, n), (0, 0)))
    return cv2.morphologyEx(padded, cv2.MORPH_CLOSE, kernel)[n:-n]


def gray_centroid(roi_closed, threshold, noise_sigma=1.0):
    """Grey-centroid centre (paper eq. 1–5) of a closed spot.

    Parameters
    ----------
    roi_closed : (h, w) float, background-subtracted, stripes closed.
    threshold : pixels at or below it do not count; the others weigh ``I - threshold``.
    noise_sigma : image noise (DN, 1σ), for the centre uncertainty.

    Notes
    -----
    For a Gaussian spot (paper eq. 1) the weighted first moments are the
    maximum-likelihood centre (eq. 4–5); subtracting the threshold removes the
    background pedestal's pull toward the ROI centre.
    """
    w = roi_closed.astype(float) - threshold
    w[w < 0.0] = 0.0
    s = w.sum()
    if s <= 0.0:
        return CentreEstimate()
    vv, uu = np.indices(w.shape, dtype=float)
    u = (w * uu).sum() / s
    v = (w * vv).sum() / s
    lit = w > 0
    su = noise_sigma * np.sqrt(((uu[lit] - u) ** 2).sum()) / s
    sv = noise_sigma * np.sqrt(((vv[lit] - v) ** 2).sum()) / s
    return CentreEstimate(u, v, su, sv, True)


def spot_contour(roi_closed, level):
    """Longest closed sub-pixel iso-contour at ``level`` as (N, 2) (u, v) points."""
    padded = np.pad(roi_closed.astype(float), 1, constant_values=0.0)
    contours = measure.find_contours(padded, level)
    if not contours:
        return np.zeros((0, 2))
    best = max(contours, key=len)
    return best[:, ::-1] - 1.0   # (row, col) → (u, v), undo the padding


def ellipse_fit(contour_uv):
    """Least-squares ellipse through contour points (paper eq. 6–9).

    Returns the centre and the conic in the same coordinates as ``contour_uv``.
    """
    if len(contour_uv) < 6:
        return CentreEstimate()
    pts = contour_uv.astype(np.float32).reshape(-1, 1, 2)
    (cu, cv_), (d1, d2), angle_deg = cv2.fitEllipse(pts)
    if not (np.isfinite(cu) and np.isfinite(cv_)) or min(d1, d2) <= 0.0:
        return CentreEstimate()
    conic = _conic_from_params(cu, cv_, 0.5 * d1, 0.5 * d2, np.radians(angle_deg))
    # uncertainty from the algebraic residual of the contour points
    r = _geometric_residuals(conic, contour_uv)
    rms = float(np.sqrt(np.mean(r ** 2))) if len(r) else float('nan')
    sigma = rms * np.sqrt(2.0 / len(contour_uv))
    return CentreEstimate(float(cu), float(cv_), sigma, sigma, True, conic,
                          {'axes': (0.5 * d1, 0.5 * d2), 'angle_deg': angle_deg})


def circularity(contour_uv):
    """α = 4πS/L² (paper eq. 10) of a closed polygon; 1 for a circle."""
    if len(contour_uv) < 3:
        return 0.0
    x, y = contour_uv[:, 0], contour_uv[:, 1]
    area = 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
    closed = np.vstack([contour_uv, contour_uv[:1]])
    perimeter = np.sum(np.hypot(*np.diff(closed, axis=0).T))
    if perimeter <= 0.0:
        return 0.0
    return float(min(4.0 * np.pi * area / perimeter ** 2, 1.0))


def conic_axes(Q):
    """Semi-axes (a ≥ b) in px of the ellipse with conic matrix ``Q``, or None."""
    (p, q, d), (_, r, e), (_, _, f) = np.asarray(Q, float).tolist()
    det = p * r - q * q
    if det == 0.0:
        return None
    # centre c = −A⁻¹ (d, e); the conic there equals f − (d, e)·A⁻¹·(d, e), whose negative
    # is k in (x − c)ᵀ A (x − c) = k
    k = (d * (r * d - q * e) + e * (p * e - q * d)) / det - f
    mean, diff = 0.5 * (p + r), np.hypot(0.5 * (p - r), q)
    lam = (mean - diff, mean + diff)                 # eigenvalues of the 2×2 part
    if k == 0.0 or lam[0] * k <= 0.0 or lam[1] * k <= 0.0:
        return None
    axes = sorted((np.sqrt(k / lam[0]), np.sqrt(k / lam[1])))
    return float(axes[1]), float(axes[0])


def ellipse_circularity(Q):
    """α = 4πS/L² (paper eq. 10) of a fitted ellipse (Ramanujan's perimeter)."""
    axes = conic_axes(Q)
    if axes is None:
        return float('nan')
    a, b = axes
    perimeter = np.pi * (3 * (a + b) - np.sqrt((3 * a + b) * (a + 3 * b)))
    return float(4.0 * np.pi * np.pi * a * b / perimeter ** 2)


def fuse_by_circularity(centroid, ellipse, alpha):
    """Paper eq. 11: ``α · centroid + (1 − α) · ellipse centre``.

    A round spot (α → 1) follows the Gaussian model, so the centroid gets the weight; an
    elongated one is better described by its contour ellipse.
    """
    if not centroid.ok:
        return ellipse
    if not ellipse.ok:
        return centroid
    a = float(np.clip(alpha, 0.0, 1.0))
    return CentreEstimate(a * centroid.u + (1 - a) * ellipse.u,
                          a * centroid.v + (1 - a) * ellipse.v,
                          np.hypot(a * centroid.sigma_u, (1 - a) * ellipse.sigma_u),
                          np.hypot(a * centroid.sigma_v, (1 - a) * ellipse.sigma_v),
                          True, ellipse.conic, {'alpha': a})


@dataclass
class ChordConfig:
    """Tuning of :func:`chord_fit`.

    min_row_snr: a row counts when its summed signal exceeds this many noise σ.
    min_chord_px: rows with a shorter chord (no fully covered pixel) stay out of the
        width fit.
    systematic_px: floor on each row's midpoint scatter (pixel-area sampling of a sharp
        edge), px.
    width_floor_fraction: floor on the scatter of each row's squared half-chord, as a
        fraction of the largest one (optics-PSF and pixel-sampling errors that the noise
        does not describe; it keeps the narrow rows near the tips, whose widths the PSF
        distorts most, from dominating the fit).
    edge_threshold_factor: a row's own support reaches past both ends of its chord only
        when the row's peak exceeds this many detection thresholds (plus two noise σ):
        its edge pixels then clear the threshold. A dimmer row (the residual light of a
        dark stripe) passes the threshold in scattered pixels only, and the vertical
        closing turns them into a window that cuts the chord short.
    window_margin_px: second pass: each row is measured between the first-pass ellipse's
        chord ends widened by this much (the optics PSF and the first pass's error), px.
    plateau_margin_px: a row's plateau level is the mean of its pixels at least this far
        inside its chord ends (fully covered, past the PSF edge), px: in the first pass
        the chord its maximum implies, in the second the predicted one. Unlike the
        maximum, which noise lifts most in the dimmest rows, the mean is unbiased.
    two_pass: False keeps the single pass over each row's own support even when the
        detection threshold is known (the method before the second pass; for comparison).
    symmetric_width_rows: for a spot whose first-pass ellipse runs past its ROI's top or
        bottom row (cut by the image edge: one tip only), the width parabola's vertex is
        refitted on the rows within the shorter side's reach of it (the PSF's width error
        near a tip cancels only between two tips); False: every row.
    """

    min_row_snr: float = 8.0
    min_chord_px: float = 2.0
    systematic_px: float = 0.02
    width_floor_fraction: float = 0.01
    edge_threshold_factor: float = 2.0
    window_margin_px: float = 2.0
    plateau_margin_px: float = 1.5
    two_pass: bool = True
    symmetric_width_rows: bool = True


@dataclass
class _Rows:
    """Per-row measurements of a striped spot (ROI coordinates), one entry per row.

    ``v`` row (px); ``S`` summed signal (DN); ``M`` first moment, the chord midpoint (px);
    ``spread2`` Σ (u − M)² over the row's window (px², for the midpoint's noise); ``n_pix``
    pixels in the window; ``P`` plateau level (DN) from ``n_core`` pixels (0: none);
    ``clipped`` the window holds a saturated pixel.
    """

    v: np.ndarray
    S: np.ndarray
    M: np.ndarray
    spread2: np.ndarray
    n_pix: np.ndarray
    P: np.ndarray
    n_core: np.ndarray
    clipped: np.ndarray

    def take(self, mask):
        return _Rows(*(getattr(self, f)[mask] for f in self.__dataclass_fields__))


class _RowSums:
    """Prefix sums along the rows of a ROI: any row window's sums in O(1).

    ``s0[r, c]`` = Σ roi[r, :c], ``s1[r, c]`` = Σ u·roi[r, u] over u < c, ``n_sat[r, c]`` =
    clipped pixels among the first c (None when nothing is clipped).
    """

    def __init__(self, roi, saturated=None):
        h, w = roi.shape
        self.roi = roi
        # Cumulative sums, O(h·w) and single-threaded. (A product with a triangular
        # (w, w + 1) matrix is O(h·w²) and goes to the multi-threaded BLAS: slow, with
        # wall-time spikes on a near lamp's 100-row, 250-column ROI.) Both in one
        # (2, h, w + 1) array, read through flat indices r·(w + 1) + c: one gather
        # gives a window's sum and first moment.
        self.stride = w + 1
        both = np.zeros((2, h, w + 1))
        np.cumsum(roi, axis=1, out=both[0, :, 1:])
        np.cumsum(roi * np.arange(w, dtype=float), axis=1, out=both[1, :, 1:])
        self.s0, self.s1 = both[0], both[1]
        self.flat = both.reshape(2, -1)
        self.n_sat = None
        if saturated is not None and saturated.any():
            self.n_sat = _prefix_sums(saturated)
        self._roi_flat = None

    def columns(self, lo, hi):
        """First and last column (int) of the windows ``lo ≤ u ≤ hi``; empty: last < first."""
        w = self.roi.shape[1]
        c0 = np.minimum(np.maximum(np.ceil(lo), 0), w).astype(int)
        c1 = np.minimum(np.maximum(np.floor(hi), -1), w - 1).astype(int)
        return c0, np.maximum(c1, c0 - 1)

    def window(self, rows, c0, c1):
        """(2, n): sum and first moment Σ u·roi of each row's window c0 ≤ u ≤ c1."""
        base = rows * self.stride
        return self.flat.take(base + (c1 + 1), axis=1) - self.flat.take(base + c0, axis=1)

    def level(self, rows, c0, c1):
        """Sum of each row's window c0 ≤ u ≤ c1."""
        base = rows * self.stride
        s0 = self.flat[0]
        return s0.take(base + (c1 + 1)) - s0.take(base + c0)

    def peak(self, rows, c0, c1):
        """Largest value of each row's window (−inf when empty)."""
        w = self.roi.shape[1]
        if self._roi_flat is None:
            # the whole ROI row after row, and a 0 past its end for the last bound
            self._roi_flat = np.append(self.roi.ravel(), 0.0)
        flat = self._roi_flat
        start = rows * w + c0
        # maxima over [start, end) and over the gaps between windows, interleaved
        bounds = np.empty(2 * len(rows), int)
        bounds[0::2] = start
        bounds[1::2] = start + np.maximum(c1 - c0 + 1, 0)
        out = np.maximum.reduceat(flat, np.minimum(bounds, len(flat) - 1))[::2]
        return np.where(c1 >= c0, out, -np.inf)


def _prefix_sums(x):
    """(h, w + 1) float64 ``out[r, c] = Σ x[r, :c]`` of an (h, w) array."""
    out = np.zeros((x.shape[0], x.shape[1] + 1))
    np.cumsum(x, axis=1, dtype=float, out=out[:, 1:])
    return out


def _measure_rows(sums, rows, lo, hi, core_lo=None, core_hi=None, plateau_margin=None):
    """Sums, midpoints and plateaus of ``rows`` over the windows ``lo ≤ u ≤ hi`` (px).

    ``sums`` is the ROI's :class:`_RowSums`. The plateau is the mean over the core
    ``core_lo ≤ u ≤ core_hi`` (within the window) when given; with ``plateau_margin``
    instead, the core is the chord that the window maximum implies, less that margin at
    each end (the maximum overstates the level, so that chord is short and its core
    safely inside); with neither, the plateau is the window maximum. Rows with no core
    pixel keep their maximum and get ``n_core`` 0.
    """
    c0, c1 = sums.columns(lo, hi)
    n_pix = c1 - c0 + 1
    S, moment = sums.window(rows, c0, c1)
    M = moment / np.where(S != 0.0, S, 1.0)
    # Σ (u − M)² over the window in closed form (its columns are consecutive integers)
    sum_c = 0.5 * (c0 + c1) * n_pix
    sum_c2 = (c1 * (c1 + 1.0) * (2 * c1 + 1) - (c0 - 1.0) * c0 * (2 * c0 - 1)) / 6.0
    spread2 = sum_c2 - 2.0 * M * sum_c + n_pix * M * M
    peak = None
    if core_lo is None:
        peak = sums.peak(rows, c0, c1)
        if plateau_margin is not None:
            half = 0.5 * S / np.where(peak > 0.0, peak, np.inf)
            core_lo, core_hi = M - half + plateau_margin, M + half - plateau_margin
    if core_lo is None:
        P, n_core = peak, np.ones(len(rows), int)
    else:
        k0, k1 = sums.columns(np.maximum(core_lo, c0), np.minimum(core_hi, c1))
        n_core = k1 - k0 + 1
        P = sums.level(rows, k0, k1) / np.maximum(n_core, 1)
        empty = n_core == 0
        if empty.any():
            P[empty] = (peak[empty] if peak is not None
                        else sums.peak(rows[empty], c0[empty], c1[empty]))
    clipped = (np.zeros(len(rows), bool) if sums.n_sat is None
               else sums.n_sat[rows, c1 + 1] - sums.n_sat[rows, c0] > 0.5)
    return _Rows(rows.astype(float), S, M, spread2, n_pix, P, n_core, clipped)


def chord_fit(roi, support, noise_sigma=1.0, config=None, saturated=None, threshold=None,
              edge_rows=(True, True)):
    """Row-chord ellipse fit of a striped spot (ROI coordinates).

    Parameters
    ----------
    roi : (h, w) float, background-subtracted, NOT closed (raw stripes).
    support : (h, w) bool, the spot's pixels (a generous mask; in the first pass each
        row's chord is taken between its first and last support pixel).
    noise_sigma : image noise (DN, 1σ).
    config : :class:`ChordConfig`.
    saturated : (h, w) bool, clipped pixels, or None. A clipped row's plateau is
        unknown, so its half-chord is not measured (its midpoint still is: clipping is
        symmetric about it).
    threshold : the detection threshold above background (DN) that made ``support``, or
        None. With it the fit runs twice: first on the rows whose own support is
        bounded by the spot's true edge (see ``ChordConfig.edge_threshold_factor``), then
        on every row, each measured between the chord ends that first ellipse predicts
        (widened by ``window_margin_px``) with the mean of its fully covered pixels as
        its plateau. Without it (or with ``two_pass`` off), one pass over every row's
        own support.
    edge_rows : (bool, bool) the ROI's first / last row is the image's: where the first
        ellipse runs past such a row, the image edge cut the spot (``info['cut']``).

    Returns
    -------
    CentreEstimate with ``conic`` (the fitted ellipse, None when the centre row could not
    come from the chord widths) and ``info`` holding the midpoint line (``a``, ``k``,
    ``vbar``, ``cov_line``), the width parabola ``quad`` (in v − vbar), the centre row's
    variance ``var_v``, ``v_from_width``, ``passes`` (1 or 2) and ``cut`` (the ellipse runs
    past the ROI's top or bottom row).

    Notes
    -----
    Row r has gain g_r (the lamp's mean output over that row's exposure window) and
    chord ``[m_r - w_r, m_r + w_r]``. Its grey-level first moment is m_r whatever g_r,
    and its sum over its plateau level is 2 w_r. An ellipse gives m(v) = a + k v
    (midpoints of parallel chords lie on a diameter) and w(v)² = α + β v + γ v²
    (γ < 0), the vertex v0 = −β / 2γ being the centre row; u0 = a + k v0.

    Both hold only for complete chords. The rows of a dark stripe still carry the lamp's
    residual light (a few % of "on"), barely above the detection threshold: their
    thresholded support is a scatter of pixels, which the detection's closing extends
    into columns that cover part of the chord. Such a row's window cuts its chord: its
    half-chord comes out short and its midpoint off-centre. Where one of the spot's tips
    lies in a dark stripe, several such rows sit on one side of the centre and pull the
    vertex of the width parabola by up to a row (and u by k times that).
    """
    cfg = config or ChordConfig()
    roi = np.asarray(roi, float)
    h, w = roi.shape
    has = support.any(axis=1)
    if has.sum() < 3:
        return CentreEstimate()
    rows = np.nonzero(has)[0]
    sup = support[rows]
    # One pixel beyond the support on each side: in a dim stripe row the threshold
    # misses the chord's faint ends, which would shorten it.
    lo = sup.argmax(axis=1) - 1.0
    hi = w - sup[:, ::-1].argmax(axis=1).astype(float)
    sums = _RowSums(roi, saturated)
    if threshold is None or not cfg.two_pass:
        return _fit_rows(_measure_rows(sums, rows, lo, hi), noise_sigma, cfg, 1)
    own = _measure_rows(sums, rows, lo, hi, plateau_margin=cfg.plateau_margin_px)
    bounded = own.P > cfg.edge_threshold_factor * threshold + 2.0 * noise_sigma
    sketch = _sketch_ellipse(own.take(bounded), noise_sigma, cfg)
    if sketch is None:
        # too few complete rows to draw the ellipse (a small or faint spot): every row
        return _fit_rows(own, noise_sigma, cfg, passes=1)
    # second pass: every row of the first ellipse, hidden tip rows included, measured
    # between that ellipse's chord ends, or the row's own window where wider (a wider
    # window only adds zero-mean noise, a narrower one would cut the chord)
    vbar, mid_poly, w2_poly = sketch
    d = np.arange(h, dtype=float) - vbar
    w2 = (w2_poly[0] * d + w2_poly[1]) * d + w2_poly[2]
    inside = np.nonzero(w2 > 0.0)[0]
    half = np.sqrt(w2[inside])
    di = d[inside]
    mid = (mid_poly[0] * di + mid_poly[1]) * di + mid_poly[2]
    own_lo, own_hi = np.full(h, np.inf), np.full(h, -np.inf)
    own_lo[rows], own_hi[rows] = lo, hi
    rows2 = _measure_rows(sums, inside,
                          np.minimum(mid - half - cfg.window_margin_px, own_lo[inside]),
                          np.maximum(mid + half + cfg.window_margin_px, own_hi[inside]),
                          mid - half + cfg.plateau_margin_px, mid + half - cfg.plateau_margin_px)
    # the first ellipse runs past the ROI's top or bottom row, and that row is the
    # image's: the edge cut one of its tips (a tip hidden in a dark stripe inside the
    # image keeps its rows, measured here like any other)
    g2, g1, g0 = (float(c) for c in w2_poly)
    cut = any(bool(edge) and (g2 * x + g1) * x + g0 > 0.0
              for x, edge in zip((-1.0 - vbar, h - vbar), edge_rows))
    second = _fit_rows(rows2, noise_sigma, cfg, passes=2, cut=cut)
    return second if second.info.get('v_from_width') else _fit_rows(own, noise_sigma, cfg, 1)


def chord_ends(roi, support, end, noise_sigma=1.0, saturated=None, min_snr=10.0,
               min_level_fraction=0.5, min_inside_px=2.5):
    """Sub-pixel end of each bright row's chord on one side of a spot (ROI pixels).

    Parameters
    ----------
    roi : (h, w) float, background-subtracted.
    support : (h, w) bool, the spot's pixels.
    end : 'lo' (the end toward column 0) or 'hi'.
    noise_sigma : image noise (DN, 1σ).
    saturated : (h, w) bool or None; a row holding a clipped pixel is left out (its
        level, hence its half level, is unknown).
    min_snr, min_level_fraction : a row is used when its level (its largest supported
        pixel) exceeds ``min_snr`` noise σ and ``min_level_fraction`` of the brightest
        row's: the rows of a bright stripe, not the dark ones between.
    min_inside_px : the row's pixels at half its level must reach this far beyond the
        end (px): a chord shorter than that, or a part of it too short to reach the
        plateau (a spot cut by the image border), has no level to halve.

    Returns
    -------
    (rows (n,) int, u (n,) float): the ROI row and the column where the row first
    reaches half its level from ``end``, linear between the two pixels around it. A
    symmetric blur moves that point by nothing, so one lamp's chord ends in the two
    images of a rectified pair lie one disparity apart, row by row (the two images'
    row r is one epipolar plane, which meets the disc's rim in the same two points).
    """
    if end not in ('lo', 'hi'):
        raise ValueError("end must be 'lo' or 'hi'")
    roi = np.asarray(roi, float)
    level = np.where(support, roi, -np.inf).max(axis=1)
    has = np.isfinite(level)
    if not has.any():
        return np.zeros(0, int), np.zeros(0)
    keep = has & (level > min_snr * noise_sigma) & (level > min_level_fraction
                                                     * level[has].max())
    if saturated is not None:
        keep &= ~np.asarray(saturated, bool).any(axis=1)
    rows = np.nonzero(keep)[0]
    prof = roi[rows] if end == 'lo' else roi[rows, ::-1]
    half = 0.5 * level[rows]
    above = prof >= half[:, None]
    first = above.argmax(axis=1)
    last = prof.shape[1] - 1 - above[:, ::-1].argmax(axis=1)
    i = np.maximum(first, 1)
    k = np.arange(len(rows))
    below, over = prof[k, i - 1], prof[k, i]
    x = (i - 1) + (half - below) / np.where(over > below, over - below, np.inf)
    ok = (first > 0) & (last - x >= min_inside_px)
    if end == 'hi':
        x = roi.shape[1] - 1 - x
    return rows[ok], x[ok]


def _sketch_ellipse(rows, noise_sigma, cfg):
    """First-pass ellipse through complete rows: ``(vbar, midpoint poly, half-chord² poly)``.

    Unweighted least squares (np.polyval coefficients in v − vbar), enough to place the
    second pass's windows to a fraction of a pixel; None when the rows draw no ellipse
    (fewer than four usable rows, no downward curvature, or a vertex outside them).
    """
    lit = rows.S > cfg.min_row_snr * noise_sigma * np.sqrt(np.maximum(rows.n_pix, 1))
    half = 0.5 * rows.S / np.where(rows.P > 0.0, rows.P, np.inf)
    use = lit & (half >= 0.5 * cfg.min_chord_px)
    if (use & ~rows.clipped).sum() >= 4:
        use &= ~rows.clipped
    if use.sum() < 4:
        return None
    v = rows.v[use]
    vbar = float(v.sum()) / len(v)
    d = v - vbar
    # one quadratic design for both (the midpoints' d² term only absorbs noise); the
    # normal equations solved in closed form, coefficients highest power first
    d2 = d * d
    N_inv = _inv_sym3(float(len(d)), float(d.sum()), float(d2.sum()), float(d2 @ d),
                      float(d2 @ d2))
    Y = np.column_stack([rows.M[use], half[use] ** 2])
    coef = (N_inv @ np.array([Y.sum(axis=0), d @ Y, d2 @ Y]))[::-1]
    mid_poly, w2_poly = coef[:, 0], coef[:, 1]
    if not w2_poly[0] < 0.0:
        return None
    d0 = -w2_poly[1] / (2.0 * w2_poly[0])
    if not d[0] - 1.0 <= d0 <= d[-1] + 1.0:
        return None
    return vbar, mid_poly, w2_poly


def _fit_rows(rows, noise_sigma, cfg, passes, cut=False):
    """Midpoint line and half-chord² parabola through measured rows (see chord_fit).

    ``cut``: the spot has one tip only (see ``ChordConfig.symmetric_width_rows``).
    """
    lit = rows.S > cfg.min_row_snr * noise_sigma * np.sqrt(np.maximum(rows.n_pix, 1))
    n_lit = int(np.count_nonzero(lit))
    if n_lit < 3:
        return CentreEstimate()
    r = rows if n_lit == len(lit) else rows.take(lit)
    S, P, n_pix, n_core, M = r.S, r.P, r.n_pix, r.n_core, r.M
    vbar = float(r.v.sum()) / len(r.v)
    dv = r.v - vbar

    # midpoint line m = a + k (v - vbar): noise variance of each row's first moment
    var_m = noise_sigma ** 2 * r.spread2 / S ** 2 + cfg.systematic_px ** 2
    line, cov_line, res_line = _wls(dv, M, 1.0 / var_m, 1)
    a, k = line

    # half-chord² parabola from rows whose chord holds a fully covered pixel
    half = 0.5 * S / P
    use = ((n_core > 0) & (half >= 0.5 * cfg.min_chord_px)
           & (P * np.sqrt(n_core) > cfg.min_row_snr * noise_sigma))
    idx = np.flatnonzero(use)
    if len(idx) >= 3:
        idx = idx[1:-1]                            # outermost rows straddle the tip
    unclipped = idx[~r.clipped[idx]]
    if len(unclipped) >= 4:
        idx = unclipped
    v_from_width = False
    quad = None
    if len(idx) >= 4:
        vertex = _width_vertex(half[idx], dv[idx], S[idx], P[idx], n_pix[idx], n_core[idx],
                               noise_sigma, cfg, dv[0] - 1.0, dv[-1] + 1.0)
        if vertex is not None and cut and cfg.symmetric_width_rows:
            # The optics PSF widens the narrow rows near a tip (the vertical blur lowers
            # their plateau more than their sum), an error symmetric about the centre
            # row: it cancels in the vertex only when both sides are sampled alike. A
            # spot cut by the image edge is not: keep the rows within the shorter
            # side's reach of the vertex. (A whole spot keeps every row: its usable rows
            # are nearly balanced, and dropping any costs more than it removes.)
            for _ in range(2):
                reach = min(vertex[0] - dv[idx[0]], dv[idx[-1]] - vertex[0])
                band = idx[np.abs(dv[idx] - vertex[0]) <= reach + 0.5]
                if len(band) == len(idx) or len(band) < 4:
                    break
                idx = band
                vertex = _width_vertex(half[idx], dv[idx], S[idx], P[idx], n_pix[idx],
                                       n_core[idx], noise_sigma, cfg, dv[0] - 1.0,
                                       dv[-1] + 1.0) or vertex
        if vertex is not None:
            d0, var_d0, quad = vertex
            v_from_width = True
    if not v_from_width:
        # no usable width profile (Gaussian or tiny spot): signal-weighted centre row
        S_sum = S.sum()
        d0 = float(S @ dv / S_sum)
        e2 = (dv - d0) ** 2
        var_d0 = float(noise_sigma ** 2 * (n_pix @ e2) / S_sum ** 2 + (S @ e2) / S_sum / len(S))
    var_u = float(cov_line[0, 0] + 2.0 * d0 * cov_line[0, 1] + d0 * d0 * cov_line[1, 1]
                  + k * k * var_d0)
    conic = _conic_from_chords(a, k, quad, vbar) if v_from_width else None
    return CentreEstimate(float(a + k * d0), float(vbar + d0), float(np.sqrt(var_u)),
                          float(np.sqrt(var_d0)), True, conic,
                          {'a': float(a), 'k': float(k), 'vbar': vbar,
                           'cov_line': cov_line, 'var_v': var_d0, 'quad': quad,
                           'v_from_width': v_from_width, 'line_rms_px': res_line,
                           'passes': passes, 'cut': cut})


def _width_vertex(half, d, S, P, n_pix, n_core, noise_sigma, cfg, d_min, d_max):
    """Vertex of the half-chord² parabola through rows at offsets ``d`` (px).

    Returns ``(d0, var_d0, quad)`` (vertex offset, its variance, parabola coefficients
    lowest power first) or None when the rows show no significant downward curvature or
    the vertex falls outside ``[d_min, d_max]``.
    """
    y = half * half
    # relative error of the half-chord: noise on the sum and on the plateau
    rel = noise_sigma * (np.sqrt(n_pix) / S + 1.0 / (P * np.sqrt(n_core)))
    var_y = ((2.0 * y * rel) ** 2 + (2.0 * cfg.systematic_px * half) ** 2
             + (cfg.width_floor_fraction * y.max()) ** 2)
    quad, cov_q, _ = _wls(d, y, 1.0 / var_y, 2)
    # a width profile with no significant curvature (a Gaussian spot) has no vertex
    if not (quad[2] < -3.0 * np.sqrt(cov_q[2, 2]) and d[-1] - d[0] > 2.0):
        return None
    d0 = -quad[1] / (2.0 * quad[2])
    # the vertex must lie within the rows that carry signal
    if not d_min <= d0 <= d_max:
        return None
    g = np.array([0.0, -1.0 / (2 * quad[2]), quad[1] / (2 * quad[2] ** 2)])
    return float(d0), float(g @ cov_q @ g), quad


def _wls(x, y, weights, degree):
    """Weighted least-squares polynomial ``y ≈ Σ c_j x^j`` (j ≤ degree 1 or 2) by the
    normal equations.

    Returns the coefficients (lowest power first), their covariance (scaled by the
    residual χ² per degree of freedom when that exceeds 1) and the RMS residual.
    """
    # the normal matrix from the weighted moments, inverted in closed form (numpy's
    # general solvers cost more in call overhead than these few rows in arithmetic)
    wx = weights * x
    s0, s1, s2 = float(weights.sum()), float(wx.sum()), float(wx @ x)
    t0, t1 = float(weights @ y), float(wx @ y)
    if degree == 1:
        N_inv = _inv_sym2(s0, s1, s2)
        c = N_inv @ np.array([t0, t1])
        fit = c[0] + c[1] * x
    elif degree == 2:
        wx2 = wx * x
        s3, s4, t2 = float(wx2 @ x), float(wx2 @ (x * x)), float(wx2 @ y)
        N_inv = _inv_sym3(s0, s1, s2, s3, s4)
        c = N_inv @ np.array([t0, t1, t2])
        fit = c[0] + (c[1] + c[2] * x) * x
    else:
        raise ValueError('degree must be 1 or 2')
    r = y - fit
    rr = r * r
    chi2 = float(weights @ rr) / max(len(y) - degree - 1, 1)
    return c, N_inv * max(chi2, 1.0), float(np.sqrt(float(rr.sum()) / len(rr)))


def _inv_sym2(a, b, c):
    """Inverse of [[a, b], [b, c]] (LinAlgError when singular)."""
    det = a * c - b * b
    if det == 0.0 or not np.isfinite(det):
        raise np.linalg.LinAlgError('Singular matrix')
    return np.array([[c, -b], [-b, a]]) / det


def _inv_sym3(s0, s1, s2, s3, s4):
    """Inverse of the Hankel matrix [[s0, s1, s2], [s1, s2, s3], [s2, s3, s4]]."""
    c00, c01, c02 = s2 * s4 - s3 * s3, s2 * s3 - s1 * s4, s1 * s3 - s2 * s2
    c11, c12, c22 = s0 * s4 - s2 * s2, s1 * s2 - s0 * s3, s0 * s2 - s1 * s1
    det = s0 * c00 + s1 * c01 + s2 * c02
    if det == 0.0 or not np.isfinite(det):
        raise np.linalg.LinAlgError('Singular matrix')
    return np.array([[c00, c01, c02], [c01, c11, c12], [c02, c12, c22]]) / det


def _conic_from_chords(a, k, quad, vbar):
    """Conic of (u − a − k(v − v̄))² − (α + β(v − v̄) + γ(v − v̄)²) = 0 in (u, v)."""
    alpha, beta, gamma = quad
    # in (u, d) with d = v - vbar: u² − 2u(a + k d) + (a + k d)² − α − β d − γ d²
    Qd = np.array([[1.0, -k, -a],
                   [-k, k * k - gamma, a * k - 0.5 * beta],
                   [-a, a * k - 0.5 * beta, a * a - alpha]])
    T = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, -vbar], [0.0, 0.0, 1.0]])   # d = v - vbar
    Q = T.T @ Qd @ T
    return Q / np.abs(Q).max()


def _conic_from_params(cu, cv_, a, b, theta):
    c, s = np.cos(theta), np.sin(theta)
    R = np.array([[c, -s], [s, c]])
    A2 = R @ np.diag([1.0 / a ** 2, 1.0 / b ** 2]) @ R.T
    centre = np.array([cu, cv_])
    Q = np.zeros((3, 3))
    Q[:2, :2] = A2
    Q[:2, 2] = Q[2, :2] = -A2 @ centre
    Q[2, 2] = centre @ A2 @ centre - 1.0
    return Q


def _geometric_residuals(Q, pts):
    """Approximate distance of points to the conic (algebraic value / gradient norm)."""
    x = np.column_stack([pts, np.ones(len(pts))])
    val = np.einsum('ni,ij,nj->n', x, Q, x)
    grad = 2.0 * (x @ Q)[:, :2]
    return val / np.maximum(np.linalg.norm(grad, axis=1), 1e-12)
