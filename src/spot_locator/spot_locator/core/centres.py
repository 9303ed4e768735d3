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
    A2 = Q[:2, :2]
    try:
        c = np.linalg.solve(A2, -Q[:2, 2])
    except np.linalg.LinAlgError:
        return None
    k = float(c @ A2 @ c - Q[2, 2])
    lam = np.linalg.eigvalsh(A2)
    if k == 0.0 or np.any(lam * k <= 0.0):
        return None
    axes = np.sqrt(k / lam)
    return float(axes.max()), float(axes.min())


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
    """

    min_row_snr: float = 8.0
    min_chord_px: float = 2.0
    systematic_px: float = 0.02
    width_floor_fraction: float = 0.01


def chord_fit(roi, support, noise_sigma=1.0, config=None, saturated=None):
    """Row-chord ellipse fit of a striped spot (ROI coordinates).

    Parameters
    ----------
    roi : (h, w) float, background-subtracted, NOT closed (raw stripes).
    support : (h, w) bool, the spot's pixels (a generous mask; each row's chord is taken
        between its first and last support pixel).
    noise_sigma : image noise (DN, 1σ).
    config : :class:`ChordConfig`.
    saturated : (h, w) bool, clipped pixels, or None. A clipped row's plateau is
        unknown, so its half-chord is not measured (its midpoint still is: clipping is
        symmetric about it).

    Returns
    -------
    CentreEstimate with ``conic`` (the fitted ellipse, None when the centre row could not
    come from the chord widths) and ``info`` holding the midpoint line (``a``, ``k``,
    ``vbar``, ``cov_line``), the centre row's variance ``var_v`` and ``v_from_width``.

    Notes
    -----
    Row r has gain g_r (the lamp's mean output over that row's exposure window) and
    chord ``[m_r - w_r, m_r + w_r]``. Its grey-level first moment is m_r whatever g_r,
    and its sum over its plateau level is 2 w_r. An ellipse gives m(v) = a + k v
    (midpoints of parallel chords lie on a diameter) and w(v)² = α + β v + γ v²
    (γ < 0), the vertex v0 = −β / 2γ being the centre row; u0 = a + k v0.
    """
    cfg = config or ChordConfig()
    roi = np.asarray(roi, float)
    h, w = roi.shape
    cols = np.arange(w, dtype=float)
    has = support.any(axis=1)
    if has.sum() < 3:
        return CentreEstimate()
    # One pixel beyond the support on each side: in a dim stripe row the threshold
    # misses the chord's faint ends, which would shorten it.
    first = np.where(has, support.argmax(axis=1), w) - 1
    last = np.where(has, w - 1 - support[:, ::-1].argmax(axis=1), -1) + 1
    inrow = has[:, None] & (cols[None, :] >= first[:, None]) & (cols[None, :] <= last[:, None])
    p = np.where(inrow, roi, 0.0)
    n_pix = inrow.sum(axis=1)
    S = p.sum(axis=1)
    P = np.where(has, np.where(inrow, roi, -np.inf).max(axis=1), 0.0)
    lit = has & (S > cfg.min_row_snr * noise_sigma * np.sqrt(np.maximum(n_pix, 1)))
    rows = np.nonzero(lit)[0]
    if len(rows) < 3:
        return CentreEstimate()
    clipped = (np.zeros(len(rows), bool) if saturated is None
               else (saturated & inrow).any(axis=1)[rows])
    S, P, n_pix = S[rows], P[rows], n_pix[rows]
    M = (p[rows] * cols).sum(axis=1) / S
    spread2 = np.where(inrow[rows], (cols[None, :] - M[:, None]) ** 2, 0.0).sum(axis=1)
    v = rows.astype(float)
    vbar = v.mean()
    dv = v - vbar

    # midpoint line m = a + k (v - vbar): noise variance of each row's first moment
    var_m = noise_sigma ** 2 * spread2 / S ** 2 + cfg.systematic_px ** 2
    line, cov_line, res_line = _wls(np.column_stack([np.ones_like(dv), dv]), M, 1.0 / var_m)
    a, k = line

    # half-chord² parabola from rows whose chord holds a fully covered pixel
    half = 0.5 * S / P
    use = (half >= 0.5 * cfg.min_chord_px) & (P > cfg.min_row_snr * noise_sigma)
    if use.sum() >= 3:
        use[np.nonzero(use)[0][[0, -1]]] = False   # outermost rows straddle the tip
    if (use & ~clipped).sum() >= 4:
        use &= ~clipped
    v_from_width = False
    quad = None
    if use.sum() >= 4:
        y = half[use] ** 2
        # relative error of the half-chord: noise on the sum and on the plateau
        rel = noise_sigma * np.sqrt(n_pix[use]) / S[use] + noise_sigma / P[use]
        var_y = ((2.0 * y * rel) ** 2 + (2.0 * half[use] * cfg.systematic_px) ** 2
                 + (cfg.width_floor_fraction * y.max()) ** 2)
        A = np.column_stack([np.ones(use.sum()), dv[use], dv[use] ** 2])
        quad, cov_q, _ = _wls(A, y, 1.0 / var_y)
        span = dv[use].max() - dv[use].min()
        # a width profile with no significant curvature (a Gaussian spot) has no vertex
        if quad[2] < -3.0 * np.sqrt(cov_q[2, 2]) and span > 2.0:
            d0 = -quad[1] / (2.0 * quad[2])
            # the vertex must lie within the rows that carry signal
            if dv.min() - 1.0 <= d0 <= dv.max() + 1.0:
                g = np.array([0.0, -1.0 / (2 * quad[2]), quad[1] / (2 * quad[2] ** 2)])
                var_d0 = float(g @ cov_q @ g)
                v_from_width = True
    if not v_from_width:
        # no usable width profile (Gaussian or tiny spot): signal-weighted centre row
        d0 = float((S * dv).sum() / S.sum())
        var_d0 = float(noise_sigma ** 2 * np.sum(n_pix * (dv - d0) ** 2) / S.sum() ** 2
                       + np.sum(S * (dv - d0) ** 2) / S.sum() / len(rows))
    jac = np.array([1.0, d0])
    var_u = float(jac @ cov_line @ jac) + k ** 2 * var_d0
    conic = _conic_from_chords(a, k, quad, vbar) if v_from_width else None
    return CentreEstimate(float(a + k * d0), float(vbar + d0), float(np.sqrt(var_u)),
                          float(np.sqrt(var_d0)), True, conic,
                          {'a': float(a), 'k': float(k), 'vbar': float(vbar),
                           'cov_line': cov_line, 'var_v': var_d0,
                           'v_from_width': v_from_width, 'line_rms_px': res_line})


def _wls(A, y, weights):
    """Weighted least squares by the normal equations (A has 2–3 columns).

    Returns the solution, its covariance (scaled by the residual χ² per degree of
    freedom when that exceeds 1) and the RMS residual.
    """
    Aw = A * weights[:, None]
    N = Aw.T @ A
    x = np.linalg.solve(N, Aw.T @ y)
    r = y - A @ x
    dof = max(len(y) - A.shape[1], 1)
    chi2 = float(weights @ (r * r)) / dof
    cov = np.linalg.inv(N) * max(chi2, 1.0)
    return x, cov, float(np.sqrt(np.mean(r * r)))


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
