"""Lamp spots in a mono8 image and their envelope-normalised row profiles.

Detection (why not the paper's chain by default): the paper thresholds the whole
median-filtered image with Otsu's method. In a dark tunnel frame the lamp spots are a
few hundred of ~900 000 pixels and Otsu's split follows whatever the histogram holds:
with no lamp in view it splits the background itself (threshold ≈ background, the whole
lit lower wall becomes one "spot"), with a lamp in view it jumps to half the lamp's level
(``decoder_benchmark`` counts the spurious spots of both chains). A threshold referenced to
the measured background level and noise (``background + k·σ``, never below a fixed
contrast) keeps the same false-alarm rate in every frame. Spots are found from row and
column maxima of the thresholded image (no full-frame filtering or labelling), which
keeps detection well under a millisecond per image. The dark stripes split a spot into pieces;
pieces are merged when their columns overlap and the dark gap between them is no longer
than the longest off run the protocol allows. Both chains are selectable (``use_otsu``,
``median_filter``).

Angle correction: the stripes of a rolling-shutter camera are the sensor rows by
construction, so the profile is read along rows whatever the spot's tilt; the paper's
correction has nothing to undo here.
"""
from dataclasses import dataclass, field
import functools

import cv2
import numpy as np


@dataclass
class Spot:
    """One lamp spot in one image (pixel coordinates, rows v, columns u)."""

    row0: int                 # first row of the spot's region (inclusive)
    row1: int                 # last row + 1
    col0: int
    col1: int
    u: float = np.nan         # centre column of the fitted envelope
    v: float = np.nan         # centre row of the fitted envelope
    peak_dn: float = 0.0
    cut: bool = False         # touches the left or right image border
    rows: np.ndarray = field(default=None, repr=False)     # (R,) image rows
    level: np.ndarray = field(default=None, repr=False)    # (R,) normalised 0 off..1 on
    weight: np.ndarray = field(default=None, repr=False)   # (R,) row weight 0..1
    height_px: float = 0.0
    width_px: float = 0.0

    @property
    def bbox(self):
        """(u_min, v_min, u_max, v_max) in pixels, inclusive."""
        return (self.col0, self.row0, self.col1 - 1, self.row1 - 1)


def background_level(image, step=8):
    """Median and robust σ (1.4826·MAD) of a sparse pixel sample of a mono8 image, DN.

    Computed from the sample's histogram: a lamp covers a tiny part of the frame, so the
    median and the MAD are the dark background's.
    """
    hist = np.bincount(image[::step, ::step].ravel(), minlength=256)
    cum = np.cumsum(hist)
    half = 0.5 * cum[-1]
    med = int(np.searchsorted(cum, half))
    # histogram of |x − med|: fold the bins around the median
    values = np.arange(256)
    dev = np.bincount(np.abs(values - med), weights=hist, minlength=256)
    mad = int(np.searchsorted(np.cumsum(dev), half))
    return float(med), max(1.4826 * mad, 0.5)


def detection_threshold(image, cfg):
    """Threshold, background level and background noise σ of ``image``, DN."""
    background, sigma = background_level(image)
    if cfg.use_otsu:
        src = cv2.medianBlur(image, 3) if cfg.median_filter else image
        otsu, _ = cv2.threshold(src, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        return float(otsu), background, sigma
    return (background + max(cfg.detect_threshold_sigma * sigma, cfg.detect_min_contrast),
            background, sigma)


def _runs(mask):
    """Half-open (start, end) index pairs of the True runs of a 1-D bool array."""
    edges = np.diff(np.concatenate([[0], mask.view(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))


def _bridge(runs, max_gap):
    """Join (start, end) runs separated by at most ``max_gap``."""
    out = []
    for start, end in runs:
        if out and start - out[-1][1] <= max_gap:
            out[-1][1] = end
        else:
            out.append([start, end])
    return out


def _merge_pieces(boxes, max_gap_rows, col_slack):
    """Union of boxes (r0, r1, c0, c1) whose columns overlap and rows nearly touch."""
    n = len(boxes)
    if n < 2:
        return [tuple(int(v) for v in b) for b in boxes]
    b = np.asarray(boxes)
    # pairwise tests at once (a striped spot gives one piece per bright stripe)
    cols = (np.minimum(b[:, None, 3], b[None, :, 3]) - np.maximum(b[:, None, 2], b[None, :, 2])
            + col_slack > 0)
    gap = np.maximum(b[:, None, 0], b[None, :, 0]) - np.minimum(b[:, None, 1], b[None, :, 1])
    linked = np.triu(cols & (gap <= max_gap_rows), 1)
    parent = np.arange(n)

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, j in zip(*np.nonzero(linked)):
        parent[find(i)] = find(j)
    roots = np.array([find(i) for i in range(n)])
    merged = []
    for root in np.unique(roots):
        arr = b[roots == root]
        merged.append((int(arr[:, 0].min()), int(arr[:, 1].max()), int(arr[:, 2].min()),
                       int(arr[:, 3].max())))
    return merged


def find_spots(image, cfg):
    """Regions of lamp spots in a mono8 image.

    Bright rows are found from the image's row maxima, bright columns within each band
    of bright rows from the band's column maxima: every piece of a striped spot is a
    block of rows and columns above the threshold. Pieces whose columns overlap and
    whose dark gap is no longer than the protocol's longest off run form one spot.

    Returns a list of (row0, row1, col0, col1) boxes (half-open) of the bright cores,
    the background level, its noise σ and the threshold used (DN).
    """
    threshold, background, noise = detection_threshold(image, cfg)
    src = cv2.medianBlur(image, 3) if cfg.median_filter else image
    level = int(min(np.floor(threshold), 254))
    # (numpy's uint8 max reductions are SIMD; OpenCV's cv2.reduce is ~50x slower here)
    row_max = src.max(axis=1)
    gap = cfg.max_dark_gap_rows
    pieces = []
    # bands of bright rows, bridged across gaps no longer than a spot's dark stripes, so
    # that a striped spot is one band rather than one per bright stripe
    for r0, r1 in _bridge(_runs(row_max > level), gap):
        band = src[r0:r1]
        col_max = band.max(axis=0)
        for c0, c1 in _runs(col_max > level):
            on_rows = band[:, c0:c1].max(axis=1) > level
            for a0, a1 in _bridge(_runs(on_rows), gap):
                pieces.append((r0 + a0, r0 + a1, int(c0), int(c1)))
        if len(pieces) > 16 * cfg.max_spots:
            break
    if len(pieces) > 16 * cfg.max_spots:
        # a lit scene rather than lamps in the dark: keep the largest pieces only
        pieces.sort(key=lambda b: -(b[1] - b[0]) * (b[3] - b[2]))
        pieces = pieces[:16 * cfg.max_spots]
    merged = _merge_pieces(pieces, cfg.max_dark_gap_rows, col_slack=1)
    spots = []
    for (a0, a1, b0, b1) in merged:
        on = src[a0:a1, b0:b1] > level
        if np.count_nonzero(on) < cfg.detect_min_area_px:
            continue
        cols = np.flatnonzero(on.any(axis=0))
        spots.append((a0, a1, b0 + int(cols[0]), b0 + int(cols[-1]) + 1))
    spots.sort(key=lambda b: -(b[1] - b[0]) * (b[3] - b[2]))
    return spots[:cfg.max_spots], background, noise, threshold


# Rows whose chord is below CAP_LO of the widest are not read and rows above CAP_HI
# count fully: at the caps the envelope is least certain (optical blur, the threshold
# that finds the extent), and a wrong envelope there reads a lit row as dark. The ellipse
# is drawn SHRINK_ROWS inside the rows found lit, whose extent the blur widens. Chosen
# on synthetic spots 20-90 rows tall (fewest wrong chip reads for the most chips read)
# and checked on the rig: reading the caps harder confirms fewer lamps, through
# conflicting reads.
CAP_LO, CAP_HI, SHRINK_ROWS = 0.25, 0.65, 0.5
# the "off" level per unit chord is taken at this percentile of the spot's rows (and
# kept between the protocol's off level and OFF_CEILING of "on"), so a saturated "on",
# which lifts the relative "off" level, is still normalised to 0..1
OFF_PERCENTILE, ON_PERCENTILE, OFF_CEILING = 10, 85, 0.3
HALO_FRACTION = 0.025
# rows read at least this high in the first pass are taken as fully inside an "on" chip
ON_ROW_LEVEL = 0.85
# refits of the envelope: each reads the rows under the latest fit, so "on" cap rows
# that a too short first envelope inflated, or a too long one dimmed, are sorted out
ENVELOPE_ITERATIONS = 2


def _ellipse_shape(rows, top, bottom, blur_rows=0.0, sub=8):
    """Fraction of the widest chord that an ellipse spanning rows ``top..bottom``
    (inclusive, edges half a row beyond) covers in each of the contiguous ``rows``,
    averaged over the row, after a vertical Gaussian blur of ``blur_rows`` (σ, rows).

    The lens spreads each instant's light before the row integrates it (the stripes stay
    sharp, the envelope does not), so the disc's edge rows receive less than their chord
    and the rows just outside some: without the blur the edge rows read too dark.
    """
    centre = 0.5 * (top + bottom)
    semi = max(0.5 * (bottom - top + 1), 0.5)
    pad = int(np.ceil(3.0 * blur_rows * sub))
    n = len(rows)
    y = rows[0] - 0.5 + (np.arange(n * sub + 2 * pad) - pad + 0.5) / sub
    z = (y - centre) / semi
    chord = 1.0 - z * z
    np.sqrt(np.maximum(chord, 0.0, out=chord), out=chord)
    if pad:
        chord = np.convolve(chord, _psf_kernel(pad, blur_rows, sub), mode='same')
    # the mean over each row's sub-rows (a sum and one division: what .mean does)
    return chord[pad:pad + n * sub].reshape(n, sub).sum(axis=1) / sub


@functools.lru_cache(maxsize=16)
def _psf_kernel(pad, blur_rows, sub):
    """The normalised Gaussian of :func:`_ellipse_shape` (the same for every spot)."""
    kernel = np.exp(-0.5 * (np.arange(-pad, pad + 1) / (blur_rows * sub)) ** 2)
    kernel = kernel / kernel.sum()
    kernel.flags.writeable = False
    return kernel


def _normalise(s, shape, cfg):
    """Levels (0 off, 1 on) of row sums ``s`` under the envelope ``shape``.

    Returns (level, on, off) or None: "on" and "off" per unit chord are percentiles of
    the body rows, so a saturated "on" is still normalised to 0..1.
    """
    body = shape >= 0.5 * shape.max()
    if not body.any():
        return None
    ratio = np.sort(s[body] / shape[body])
    # percentiles by linear interpolation (np.percentile's default), without its overhead
    pos = np.array([ON_PERCENTILE, OFF_PERCENTILE]) * 0.01 * (len(ratio) - 1)
    lo = np.floor(pos).astype(int)
    hi = np.minimum(lo + 1, len(ratio) - 1)
    a_on, a_off = ratio[lo] + (pos - lo) * (ratio[hi] - ratio[lo])
    if a_on <= 0:
        return None
    a_off = float(min(max(a_off, cfg.off_level * a_on), OFF_CEILING * a_on))
    level = np.divide(s, shape, out=np.full(len(s), a_off), where=shape > 0)
    return (level - a_off) / (a_on - a_off), a_on, a_off


def _fit_ellipse_rows(idx, s, level, reference):
    """Centre and semi-axis (rows) of the disc from the row sums of its "on" rows.

    A row fully inside an "on" chip sums to ``A·chord(r)`` and an ellipse's squared
    chord is a parabola in r, so a least-squares parabola through the squared sums of
    the rows read "on" gives the disc's vertical extent independently of the
    stripes at its caps (the lit extent ends early when a cap chip is off and late when
    the optics spill an "on" cap). ``reference``: (centre, semi-axis) of the lit extent,
    patch rows; a fit far from it is rejected. Returns (centre, semi-axis) in patch rows,
    or None when the "on" rows do not pin them down.
    """
    on = level > ON_ROW_LEVEL
    if np.count_nonzero(on) < 4:
        return None
    r = idx[on].astype(float)
    span = r[-1] - r[0]
    if span < 0.4 * len(idx):
        return None
    mid = 0.5 * (r[0] + r[-1])
    x = r - mid
    q = s[on] ** 2
    # least squares q ≈ c0 + c1·x + c2·x² by its normal equations (3×3)
    x2 = x * x
    p1, p2, p3, p4 = x.sum(), x2.sum(), x2 @ x, x2 @ x2
    m = np.array([[len(x), p1, p2], [p1, p2, p3], [p2, p3, p4]])
    rhs = np.array([q.sum(), q @ x, q @ x2])
    try:
        c0, c1, c2 = np.linalg.solve(m, rhs)
    except np.linalg.LinAlgError:
        return None
    if c2 >= 0:
        return None
    centre = -c1 / (2 * c2)
    top_value = c0 - c1 * c1 / (4 * c2)
    if top_value <= 0:
        return None
    semi = float(np.sqrt(-top_value / c2))
    ref_centre, ref_semi = reference
    if not (abs(centre + mid - ref_centre) < 0.25 * ref_semi
            and 0.75 * ref_semi < semi < 1.25 * ref_semi):
        return None
    return centre + mid, semi


def _lit_extent(lit, core0, core1):
    """First and last row (patch indices) of the contiguous run of ``lit`` rows around
    the bright core: the spot including its dim "off" rows.
    """
    top = core0
    while top > 0 and lit[top - 1]:
        top -= 1
    bottom = core1 - 1
    while bottom < len(lit) - 1 and lit[bottom + 1]:
        bottom += 1
    return top, bottom


def spot_profile(image, box, background, noise_dn, cfg):
    """Envelope-normalised row profile of one spot.

    Each row's level is its background-subtracted sum divided by the sum the row would
    have with the lamp on, ``A·shape(r)``. The shape is the chord of the spot's ellipse,
    whose vertical extent is where the row sums stand above the noise (the lamp's "off"
    level, 5 % of "on", still lights the disc, so the extent does not depend on the
    stripes); ``A`` is the lit level of the widest row, taken from the brightest rows.
    This keeps the short rows at the top and bottom of the spot from reading as "off"
    (they are dim because they are short, not because the lamp is off), and rows beyond
    the disc are never read. For a spot cut by the left or right image border the chord
    is measured row by row instead (row sum over row peak on the lit rows, interpolated
    across the dark ones). Otherwise the ellipse is then refitted on the rows read "on"
    (:func:`_fit_ellipse_rows`), which the stripes at the caps do not bias, and blurred
    by the lens PSF (``psf_sigma_px``). Rows are weighted by their chord, so the caps
    count less.

    Parameters
    ----------
    image : (H, W) uint8; box : (row0, row1, col0, col1) bright core of the spot
    background, noise_dn : background level and pixel noise σ, DN

    Returns a :class:`Spot` (``level`` 0 = the lamp's off level, 1 = on) or None.
    """
    h, w = image.shape
    r0, r1, c0, c1 = box
    pad = int(np.ceil(cfg.max_dark_gap_rows))
    a0, a1 = max(r0 - pad, 0), min(r1 + pad, h)
    b0, b1 = max(c0 - 2, 0), min(c1 + 2, w)
    patch = image[a0:a1, b0:b1].astype(np.float32) - background
    np.maximum(patch, 0, out=patch)
    s_all = patch.sum(axis=1)
    n_cols = patch.shape[1]
    # mean of each row's two largest values (a row sort is several times faster than a
    # partition on these small patches; the same two values)
    p_all = (np.sort(patch, axis=1)[:, -2:].mean(axis=1) if n_cols >= 2 else patch[:, 0])
    peak = float(p_all.max()) if len(p_all) else 0.0
    if peak <= 0:
        return None
    # the clipped background noise adds ~0.4σ per pixel to a row sum
    floor = 0.4 * noise_dn * n_cols
    # a disc row is lit at least at the lamp's off level (5 % of on); the optics' faint
    # wide halo around a bright spot stays below HALO_FRACTION of the peak per pixel
    lit = (s_all > floor + 3.0 * noise_dn * np.sqrt(n_cols)) & (p_all > HALO_FRACTION * peak)
    top, bottom = _lit_extent(lit, r0 - a0, r1 - a0)
    idx = np.arange(top, bottom + 1)
    s = np.maximum(s_all[idx] - floor, 0.0)
    p = p_all[idx]
    rows = a0 + idx
    cut = b0 <= cfg.border_margin_px or b1 >= w - cfg.border_margin_px
    # a spot cut by the top or bottom border has no visible end there: the ellipse
    # through its lit extent would be wrong, so its chord is measured row by row too
    clipped = cut or a0 + top <= 0 or a0 + bottom >= h - 1
    lit = p > 0.35 * peak
    if clipped and np.count_nonzero(lit) >= 2:
        width = s[lit] / p[lit]
        # between lit rows the chord is interpolated; beyond them it is unknown
        shape = np.where((idx >= idx[lit][0]) & (idx <= idx[lit][-1]),
                         np.interp(idx, idx[lit], width), 0.0)
    else:
        shape = _ellipse_shape(idx, top + SHRINK_ROWS, bottom - SHRINK_ROWS, cfg.psf_sigma_px)
    levels = _normalise(s, shape, cfg)
    if levels is None:
        return None
    level = levels[0]
    v_centre, height = 0.5 * (top + bottom), float(bottom - top + 1)
    reference = (v_centre, 0.5 * height)
    previous = (np.nan, np.nan)
    for _ in range(0 if clipped else ENVELOPE_ITERATIONS):
        fit = _fit_ellipse_rows(idx, s, level, reference)
        if fit is None or max(abs(fit[0] - previous[0]), abs(fit[1] - previous[1])) < 0.05:
            break
        previous = v_centre, semi = fit
        height = 2.0 * semi
        idx = np.arange(max(int(np.ceil(v_centre - semi - 0.5)), 0),
                        min(int(np.floor(v_centre + semi + 0.5)), len(s_all) - 1) + 1)
        s = np.maximum(s_all[idx] - floor, 0.0)
        p = p_all[idx]
        rows = a0 + idx
        shape = _ellipse_shape(idx, v_centre - semi + 0.5, v_centre + semi - 0.5,
                               cfg.psf_sigma_px)
        levels = _normalise(s, shape, cfg)
        if levels is None:
            return None
        level = levels[0]
        lit = p > 0.35 * peak
    shape_max = float(shape.max())
    keep = shape > 0.05 * shape_max
    if not keep.any():
        return None
    rows, s, shape, level = rows[keep], s[keep], shape[keep], level[keep]
    weight = np.minimum(np.maximum((shape / shape_max - CAP_LO) / (CAP_HI - CAP_LO), 0.0), 1.0)
    cols = np.arange(b0, b1)
    col_profile = patch[idx].sum(axis=0)
    u = float((col_profile * cols).sum() / max(col_profile.sum(), 1e-6))
    widths = np.sort(s[lit[keep]] / np.maximum(p[keep][lit[keep]], 1e-6))
    width_px = float(widths[int(0.9 * (len(widths) - 1))]) if len(widths) else 0.0
    return Spot(row0=int(rows[0]), row1=int(rows[-1]) + 1, col0=int(b0), col1=int(b1),
                u=u, v=a0 + v_centre, peak_dn=peak, cut=bool(cut),
                rows=rows, level=level.astype(float), weight=weight.astype(float),
                height_px=height, width_px=width_px)


def detect(image, cfg):
    """All lamp spots of a mono8 image with their row profiles."""
    boxes, background, noise, _ = find_spots(image, cfg)
    spots = []
    for box in boxes:
        spot = spot_profile(image, box, background, noise, cfg)
        if spot is not None:
            spots.append(spot)
    return spots
