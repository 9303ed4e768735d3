"""Find lamp spots in one image and cut a region of interest around each.

The image is thresholded above the dark tunnel background, the rolling-shutter stripes
are joined by a binary closing with a vertical line (paper Fig. 7), and each connected
component becomes one spot. Everything downstream works on the small ROIs, which keeps
a stereo pair well inside the time budget.
"""
from dataclasses import dataclass

import cv2
import numpy as np


@dataclass
class DetectConfig:
    """Spot detection settings.

    threshold_snr: detection threshold above the background, in noise σ.
    min_threshold_dn: lower bound of that threshold above background (DN).
    closing_rows: height of the vertical closing line (rows); must exceed the longest
        dark stripe (3 off chips of the header: 3 / (chip_rate · row_time) rows).
    min_area_px: smaller components are noise.
    pad_px: margin of the ROI around the component (px).
    max_spots: at most this many spots (the brightest by area) per image.
    background_gap_px, background_ring_px: each spot's own background level is measured
        on a ring of this width (px) that starts this far (px) outside its component,
        beyond the optics halo and the dark-stripe tips the threshold misses.
    local_background: False subtracts the frame's background level instead (the method
        before the local level; for comparison).
    background_plane: the local background is a plane fitted to the ring (level and
        gradient); False: the ring's mean level (the method before the plane).
    """

    threshold_snr: float = 6.0
    min_threshold_dn: float = 8.0
    closing_rows: int = 13
    min_area_px: int = 6
    pad_px: int = 3
    max_spots: int = 16
    background_gap_px: int = 16
    background_ring_px: int = 8
    local_background: bool = True
    background_plane: bool = True


@dataclass
class SpotRegion:
    """One detected spot.

    ``u0``, ``v0``: image coordinates of the ROI's pixel (0, 0). ``roi``: raw
    background-subtracted grey levels (float32). ``support``: the closed component
    grown by one pixel (bool). ``row_min``, ``row_max``: image rows covered by the
    component. ``touches_border``: the component reaches the image edge; ``cut_columns``:
    it reaches the left or right edge (its rows are truncated).
    ``background`` (DN): the spot's local background level at the centre of its box and
    ``background_slope`` (DN/px along u, v) its gradient: the plane subtracted from
    ``roi``;
    ``noise_sigma`` (DN) and the ``threshold`` used (DN above the frame's background).
    ``saturated``: ROI pixels at the sensor's full scale (bool). ``edge_rows``: the ROI's
    (first, last) row is the image's.
    """

    u0: int
    v0: int
    roi: np.ndarray
    support: np.ndarray
    row_min: int
    row_max: int
    area_px: int
    touches_border: bool
    background: float
    noise_sigma: float
    threshold: float
    saturated: np.ndarray = None
    cut_columns: bool = False
    background_slope: tuple = (0.0, 0.0)
    edge_rows: tuple = (False, False)


def background_and_noise(image, step=8):
    """Robust background level and noise σ (DN) from a subsampled image (median, MAD)."""
    sample = image[::step, ::step].ravel()
    if sample.dtype == np.uint8:
        # histogram median: far cheaper than a partition sort on every frame; the
        # deviations' histogram is the level histogram folded about the median
        hist = np.bincount(sample, minlength=256)
        half = 0.5 * sample.size
        m = int(np.searchsorted(np.cumsum(hist), half))
        dev = np.zeros(256, hist.dtype)
        dev[:256 - m] = hist[m:]
        dev[1:m + 1] += hist[m - 1::-1] if m > 0 else 0
        med = float(m)
        mad = float(np.searchsorted(np.cumsum(dev), half))
    else:
        sample = sample.astype(np.float32)
        med = float(np.median(sample))
        mad = float(np.median(np.abs(sample - med)))
    # an 8-bit dark frame can have MAD 0; quantisation noise is still 1/sqrt(12) DN
    return med, max(1.4826 * mad, 0.29)


def local_background(image, box, gap_px, ring_px, frame_background, ceiling, plane=True):
    """Background around one spot: a plane fitted to a ring outside its box.

    Parameters
    ----------
    image : (H, W) the frame.
    box : (x, y, w, h) the spot's bounding box (px).
    gap_px, ring_px : the ring spans ``gap_px`` to ``gap_px + ring_px`` outside the box.
    frame_background : the frame's level (DN), returned (flat) when the ring holds too
        few background pixels.
    ceiling : ring pixels above it (DN; the detection threshold) belong to another lamp
        and are left out.
    plane : fit a plane (level and slopes); False: the ring's mean, flat.

    Returns
    -------
    (level, slope_u, slope_v): the background at the box centre (DN) and its gradient
    (DN/px along u and v); ``level + slope_u (u − uc) + slope_v (v − vc)`` at image pixel
    (u, v), with (uc, vc) = (x + (w − 1)/2, y + (h − 1)/2).

    Notes
    -----
    The tunnel's background is not flat (ambient light, dark current), and a spot's
    width is measured from row sums: an offset of δ DN per pixel changes a row's sum by
    δ times its window's width, which for the rows of a dark stripe (a few % of the lamp
    level) is a large fraction of their signal. A gradient g (DN/px) along a row moves
    that row's first moment by g w²/(3 P) (half-chord w, plateau P): 0.03 px for the
    rig's nearest lamp (w ≈ 47 px) at the rig's 0.002 DN/px, after the flat field; and
    where the image edge cuts the ring on one side, the level at the far rows is an
    extrapolation that only a plane gets right. The mean, not a median: 8-bit levels of
    a near-black background are integers, and their median is off by up to ½ DN.
    """
    x, y, w, h = box
    H, W = image.shape
    outer = gap_px + ring_px
    r0, r1 = max(y - outer, 0), min(y + h + outer, H)
    c0, c1 = max(x - outer, 0), min(x + w + outer, W)
    i0, i1 = max(y - gap_px, 0), min(y + h + gap_px, H)
    j0, j1 = max(x - gap_px, 0), min(x + w + gap_px, W)
    uc, vc = x + 0.5 * (w - 1), y + 0.5 * (h - 1)
    # moments of the kept ring pixels about (uc, vc): n, Σu, Σv, Σu², Σuv, Σv², Σz, Σuz, Σvz
    block = image[r0:r1, c0:c1]
    keep = block <= ceiling
    keep[i0 - r0:i1 - r0, j0 - c0:j1 - c0] = False          # the spot's side of the ring
    keep = keep.astype(np.float32)
    z = block * keep
    u = np.arange(c0 - uc, c1 - uc)
    v = np.arange(r0 - vc, r1 - vc)
    k_col, k_row = keep.sum(axis=0), keep.sum(axis=1)
    z_col, z_row = z.sum(axis=0), z.sum(axis=1)
    n = float(k_col.sum())
    if n < 16:
        return float(frame_background), 0.0, 0.0
    mean = float(z_col.sum()) / n
    if not plane:
        return mean, 0.0, 0.0
    # least-squares plane in closed form, about the ring pixels' own mean position
    ub, vb = float(k_col @ u) / n, float(k_row @ v) / n
    cuu = float(k_col @ (u * u)) - n * ub * ub
    cvv = float(k_row @ (v * v)) - n * vb * vb
    cuv = float(v @ (keep @ u)) - n * ub * vb
    czu = float(z_col @ u) - n * mean * ub
    czv = float(z_row @ v) - n * mean * vb
    det = cuu * cvv - cuv * cuv
    # a ring cut to one strip by the image corner has no slope across that strip
    if not det > 1e-6 * cuu * cvv:
        return mean, 0.0, 0.0
    slope_u = (cvv * czu - cuv * czv) / det
    slope_v = (cuu * czv - cuv * czu) / det
    level = mean - slope_u * ub - slope_v * vb
    return float(level), float(slope_u), float(slope_v)


def detect_spots(image, config=None):
    """Detect lamp spots in a mono image (H, W) uint8/uint16/float.

    Returns a list of :class:`SpotRegion`, largest first.

    Notes
    -----
    Closing the whole frame and labelling it costs milliseconds; instead the stripe
    fragments' outer contours are found on the thresholded frame, fragments that overlap
    in columns and are separated by fewer than ``closing_rows`` dark rows are grouped,
    and the closing is applied inside each group's ROI only.
    """
    cfg = config or DetectConfig()
    img = np.asarray(image)
    if img.ndim != 2 or img.size == 0:
        raise ValueError(f'expected a non-empty 2-D mono image, got shape {img.shape}')
    bg, sigma = background_and_noise(img)
    thr = max(cfg.threshold_snr * sigma, cfg.min_threshold_dn)
    full_scale = np.iinfo(img.dtype).max if img.dtype.kind in 'ui' else np.inf
    # lit: img > level (for 8 bits as cv2.threshold at min(bg + thr, 255) binarises)
    level = min(bg + thr, 255.0) if img.dtype == np.uint8 else bg + thr
    boxes = _fragment_boxes(img, level)
    h, w = img.shape
    out = []
    n = max(cfg.closing_rows, 1)
    kernel = _vertical_line(n)
    for x, y, bw, bh in _group_fragments(boxes, n):
        u0, v0 = max(x - cfg.pad_px, 0), max(y - cfg.pad_px, 0)
        u1, v1 = min(x + bw + cfg.pad_px, w), min(y + bh + cfg.pad_px, h)
        raw = img[v0:v1, u0:u1]
        # the ROI's binary, padded with n dark rows above and below (the closing's
        # erosion must not eat the spot's top and bottom rows at the ROI edge)
        padded = np.zeros((v1 - v0 + 2 * n, u1 - u0), np.uint8)
        np.greater(raw, level, out=padded[n:-n], casting='unsafe')
        closed = cv2.morphologyEx(padded, cv2.MORPH_CLOSE, kernel)[n:-n]
        area = cv2.countNonZero(closed)
        if area < cfg.min_area_px:
            continue
        support = cv2.dilate(closed, _GROW).view(bool)
        if cfg.local_background:
            local_bg, slope_u, slope_v = local_background(
                img, (x, y, bw, bh), cfg.background_gap_px, cfg.background_ring_px, bg,
                bg + thr, cfg.background_plane)
        else:
            local_bg, slope_u, slope_v = bg, 0.0, 0.0
        roi = raw.astype(np.float32)
        roi -= np.float32(local_bg)
        if slope_u or slope_v:
            # the plane about the box centre, in the ROI's pixel grid
            cu, cv_ = x + 0.5 * (bw - 1) - u0, y + 0.5 * (bh - 1) - v0
            roi -= (slope_u * (np.arange(u1 - u0) - cu)[None, :]
                    + slope_v * (np.arange(v1 - v0) - cv_)[:, None]).astype(np.float32)
        cut_columns = x == 0 or x + bw == w
        touches = cut_columns or y == 0 or y + bh == h
        out.append(SpotRegion(int(u0), int(v0), roi, support, int(y), int(y + bh - 1),
                              int(area), bool(touches), local_bg, sigma, thr,
                              raw >= full_scale, bool(cut_columns), (slope_u, slope_v),
                              (v0 == 0, v1 == h)))
    out.sort(key=lambda spot: -spot.area_px)
    return out[:cfg.max_spots]


_GROW = np.ones((3, 3), np.uint8)
_LINES = {}


def _vertical_line(n):
    """The (n, 1) structuring element of the stripe closing (cached)."""
    if n not in _LINES:
        _LINES[n] = np.ones((n, 1), np.uint8)
    return _LINES[n]


# rows per block of the coarse pass of _fragment_boxes; more cells than this: full frame
_BLOCK_ROWS = 8
_MAX_CELLS = 64


def _fragment_boxes(img, level):
    """Bounding boxes (x, y, w, h) of the 8-connected components of ``img > level``.

    The same boxes, in the same order, as ``cv2.findContours`` (external contours) on the
    whole thresholded frame, without thresholding and tracing the whole frame: one pass
    takes the maximum of every block of 8 rows per column; each band of consecutive
    blocks holding a lit pixel is split into runs of columns lit in it, and the contours
    are traced in each such (band × columns) cell only. A component lies inside one
    cell: cells are separated by whole unlit rows or columns, which 8-connectivity does
    not cross. A frame with many lit cells (noise) is traced whole.
    """
    H, W = img.shape
    nb = -(-H // _BLOCK_ROWS)
    if img.dtype.kind not in 'ui' or nb < 2:
        return _frame_boxes(img, level)
    full = H // _BLOCK_ROWS
    blocks = np.empty((nb, W), img.dtype)
    img[:full * _BLOCK_ROWS].reshape(full, _BLOCK_ROWS, W).max(axis=1, out=blocks[:full])
    if full < nb:
        img[full * _BLOCK_ROWS:].max(axis=0, out=blocks[full])
    cells = []
    for b0, b1 in _runs(blocks.max(axis=1) > level):
        for c0, c1 in _runs(blocks[b0:b1].max(axis=0) > level):
            cells.append((b0 * _BLOCK_ROWS, min(b1 * _BLOCK_ROWS, H), c0, c1))
        if len(cells) > _MAX_CELLS:
            return _frame_boxes(img, level)
    found = []
    sort = False
    for i, (r0, r1, c0, c1) in enumerate(cells):
        sort = sort or (i > 0 and r0 == cells[i - 1][0])     # cells side by side
        # one dark pixel around the cell (the tracer's own border)
        cell = np.zeros((r1 - r0 + 2, c1 - c0 + 2), np.uint8)
        np.greater(img[r0:r1, c0:c1], level, out=cell[1:-1, 1:-1], casting='unsafe')
        contours, _ = cv2.findContours(cell, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE,
                                       offset=(c0 - 1, r0 - 1))
        found[:0] = contours
    # findContours lists the contours in reverse raster order of their first point: so
    # does a cell, and the bands are in raster order; cells side by side interleave
    if sort:
        found.sort(key=lambda c: c[0, 0, ::-1].tolist(), reverse=True)
    return [cv2.boundingRect(c) for c in found]


def _frame_boxes(img, level):
    """:func:`_fragment_boxes` by thresholding and tracing the whole frame."""
    if img.dtype == np.uint8:
        _, binary = cv2.threshold(img, level, 1, cv2.THRESH_BINARY)
    else:
        binary = (img > level).astype(np.uint8)
    contours, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    return [cv2.boundingRect(c) for c in contours]


def _runs(mask):
    """(start, stop) of each run of True in a 1-D bool array."""
    edges = np.flatnonzero(mask[1:] != mask[:-1]) + 1
    if mask[0]:
        edges = np.concatenate(([0], edges))
    if mask[-1]:
        edges = np.concatenate((edges, [len(mask)]))
    return edges.reshape(-1, 2).tolist()


def _group_fragments(boxes, max_gap_rows):
    """Merge (x, y, w, h) boxes that share columns and lie ≤ ``max_gap_rows`` apart."""
    groups = [list(b) for b in boxes]
    merged = True
    while merged and len(groups) > 1:
        merged = False
        groups.sort(key=lambda g: g[1])
        out = []
        for g in groups:
            for o in out:
                cols_overlap = g[0] <= o[0] + o[2] and o[0] <= g[0] + g[2]
                gap = max(g[1] - (o[1] + o[3]), o[1] - (g[1] + g[3]))
                if cols_overlap and gap <= max_gap_rows:
                    x0, y0 = min(o[0], g[0]), min(o[1], g[1])
                    x1 = max(o[0] + o[2], g[0] + g[2])
                    y1 = max(o[1] + o[3], g[1] + g[3])
                    o[:] = [x0, y0, x1 - x0, y1 - y0]
                    merged = True
                    break
            else:
                out.append(g)
        groups = out
    return [tuple(g) for g in groups]
