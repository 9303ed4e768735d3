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


@dataclass
class SpotRegion:
    """One detected spot.

    ``u0``, ``v0``: image coordinates of the ROI's pixel (0, 0). ``roi``: raw
    background-subtracted grey levels (float32). ``support``: the closed component
    grown by one pixel (bool). ``row_min``, ``row_max``: image rows covered by the
    component. ``touches_border``: the component reaches the image edge; ``cut_columns``:
    it reaches the left or right edge (its rows are truncated).
    ``background`` (DN): the spot's local background level, subtracted from ``roi``;
    ``noise_sigma`` (DN) and the ``threshold`` used (DN above the frame's background).
    ``saturated``: ROI pixels at the sensor's full scale (bool).
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


def background_and_noise(image, step=8):
    """Robust background level and noise σ (DN) from a subsampled image (median, MAD)."""
    sample = image[::step, ::step].ravel()
    if sample.dtype == np.uint8:
        # histogram median: far cheaper than a partition sort on every frame
        hist = np.bincount(sample, minlength=256)
        med = float(np.searchsorted(np.cumsum(hist), 0.5 * sample.size))
        dev = np.bincount(np.abs(sample.astype(np.int16) - int(med)).astype(np.uint8),
                          minlength=256)
        mad = float(np.searchsorted(np.cumsum(dev), 0.5 * sample.size))
    else:
        sample = sample.astype(np.float32)
        med = float(np.median(sample))
        mad = float(np.median(np.abs(sample - med)))
    # an 8-bit dark frame can have MAD 0; quantisation noise is still 1/sqrt(12) DN
    return med, max(1.4826 * mad, 0.29)


def local_background(image, box, gap_px, ring_px, frame_background, ceiling):
    """Background level (DN) around one spot: the mean over a ring outside its box.

    Parameters
    ----------
    image : (H, W) the frame.
    box : (x, y, w, h) the spot's bounding box (px).
    gap_px, ring_px : the ring spans ``gap_px`` to ``gap_px + ring_px`` outside the box.
    frame_background : the frame's level (DN), returned when the ring holds too few
        background pixels.
    ceiling : ring pixels above it (DN; the detection threshold) belong to another lamp
        and are left out.

    Notes
    -----
    The tunnel's background is not flat (ambient light, dark current), and a spot's
    width is measured from row sums: an offset of δ DN per pixel changes a row's sum by
    δ times its window's width, which for the rows of a dark stripe (a few % of the lamp
    level) is a large fraction of their signal. The mean, not the median: 8-bit levels
    of a near-black background are integers, and their median is off by up to ½ DN.
    """
    x, y, w, h = box
    H, W = image.shape
    outer = gap_px + ring_px
    r0, r1 = max(y - outer, 0), min(y + h + outer, H)
    c0, c1 = max(x - outer, 0), min(x + w + outer, W)
    i0, i1 = max(y - gap_px, 0), min(y + h + gap_px, H)
    j0, j1 = max(x - gap_px, 0), min(x + w + gap_px, W)
    ring = np.concatenate([image[r0:i0, c0:c1].ravel(), image[i1:r1, c0:c1].ravel(),
                           image[i0:i1, c0:j0].ravel(), image[i0:i1, j1:c1].ravel()])
    kept = ring[ring <= ceiling]
    return float(kept.mean()) if kept.size >= 16 else float(frame_background)


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
    if img.dtype == np.uint8:
        _, binary = cv2.threshold(img, min(bg + thr, 255.0), 1, cv2.THRESH_BINARY)
    else:
        binary = (img > bg + thr).astype(np.uint8)
    contours, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    boxes = [cv2.boundingRect(c) for c in contours]
    h, w = img.shape
    out = []
    n = max(cfg.closing_rows, 1)
    kernel = np.ones((n, 1), np.uint8)
    grow = np.ones((3, 3), np.uint8)
    for x, y, bw, bh in _group_fragments(boxes, n):
        u0, v0 = max(x - cfg.pad_px, 0), max(y - cfg.pad_px, 0)
        u1, v1 = min(x + bw + cfg.pad_px, w), min(y + bh + cfg.pad_px, h)
        padded = np.pad(binary[v0:v1, u0:u1], ((n, n), (0, 0)))
        closed = cv2.morphologyEx(padded, cv2.MORPH_CLOSE, kernel)[n:-n]
        area = int(np.count_nonzero(closed))
        if area < cfg.min_area_px:
            continue
        support = cv2.dilate(closed, grow).astype(bool)
        raw = img[v0:v1, u0:u1]
        local_bg = (local_background(img, (x, y, bw, bh), cfg.background_gap_px,
                                     cfg.background_ring_px, bg, bg + thr)
                    if cfg.local_background else bg)
        roi = raw.astype(np.float32) - local_bg
        cut_columns = x == 0 or x + bw == w
        touches = cut_columns or y == 0 or y + bh == h
        out.append(SpotRegion(int(u0), int(v0), roi, support, int(y), int(y + bh - 1),
                              area, bool(touches), local_bg, sigma, thr, raw >= full_scale,
                              bool(cut_columns)))
    out.sort(key=lambda spot: -spot.area_px)
    return out[:cfg.max_spots]


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
